"""Validation shared by the optimisers: which robot a field belongs to, poses as tensors, and
option checks. Each failure is a clear Python exception naming the problem."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch

from ..files import check_robot
from ..labels import as_poses
from ..robot import Robot
from ..errors import InputError


def check_field(sdf) -> None:
    """``sdf`` must be a torch module with the PoseSDF interface (njoint, joint_limits, fingerprint)."""
    if not isinstance(sdf, torch.nn.Module) or not all(hasattr(sdf, a) for a in ("njoint", "joint_limits", "fingerprint")):
        raise TypeError(f"expected a profrobot.PoseSDF (or a module with its interface); got {type(sdf).__name__}")


@lru_cache(maxsize=8)
def _bundled(name: str) -> Robot:
    from .. import scenes

    return scenes.load(name)


def field_robot(sdf, robot: Robot | None) -> Robot:
    """The robot the exact labeller certifies against: ``robot`` if given (it must be the one the
    field was trained for), else the field's own robot (``sdf.robot``, set by ``train_sdf`` and
    ``load_sdf``), else the bundled scene named by ``sdf.robot_name``."""
    check_field(sdf)
    if robot is None:
        robot = getattr(sdf, "robot", None)
    if robot is None:
        from .. import scenes

        name = getattr(sdf, "robot_name", None)
        if name not in scenes.names():
            raise InputError(f"the field's robot {name!r} is not a bundled scene; pass robot= so that "
                             "results can be certified by the exact labeller")
        robot = _bundled(name)
    if not isinstance(robot, Robot):
        raise TypeError(f"robot must be a profrobot.Robot; got {type(robot).__name__}")
    check_robot(sdf.fingerprint, robot, "the field", made_for=getattr(sdf, "robot_name", None))
    return robot


def poses_array(robot: Robot, poses, name: str = "poses") -> np.ndarray:
    """(B, K) float64 poses within the joint limits, or a ValueError/TypeError naming the problem."""
    return as_poses(robot, poses, name=name, check_limits=True, atol=1e-6)


def positive(name: str, value, *, integer: bool = False, allow_zero: bool = False) -> float | int:
    bad = isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating))
    if integer and not bad:
        bad = not float(value).is_integer()
    if bad or not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        kind = "integer" if integer else "number"
        raise InputError(f"{name} must be a {'non-negative' if allow_zero else 'positive'} {kind}; got {value!r}")
    return int(value) if integer else float(value)


def finite(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
        raise InputError(f"{name} must be a finite number; got {value!r}")
    return float(value)
