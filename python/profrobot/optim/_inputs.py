"""Validation shared by the optimisers: which robot a field belongs to, poses as tensors, and
option checks. Each failure is a clear Python exception naming the problem."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch

from .._io import check_robot
from ..labels import as_poses
from ..robot import Robot


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
            raise ValueError(f"the field's robot {name!r} is not a bundled scene; pass robot= so that "
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
        raise ValueError(f"{name} must be a {'non-negative' if allow_zero else 'positive'} {kind}; got {value!r}")
    return int(value) if integer else float(value)


def finite(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number; got {value!r}")
    return float(value)


class Limits:
    """Keeps poses inside the robot's joint space: limited joints are clamped to their range,
    continuous hinges wrapped to [-pi, pi) (clamping them would block a turn through pi)."""

    def __init__(self, robot: Robot, like: torch.Tensor):
        lim = torch.as_tensor(robot.joint_limits, dtype=like.dtype, device=like.device)
        self.lo, self.hi = lim[:, 0], lim[:, 1]
        self.cont = torch.as_tensor(robot.continuous, device=like.device)
        self.cont_np = np.asarray(robot.continuous, dtype=bool)
        self.lim_np = np.asarray(robot.joint_limits, dtype=np.float64)

    @torch.no_grad()
    def apply_(self, theta: torch.Tensor) -> torch.Tensor:
        """In place on θ (..., K)."""
        wrapped = torch.remainder(theta + math.pi, 2 * math.pi) - math.pi
        theta.copy_(torch.where(self.cont, wrapped, torch.clamp(theta, self.lo, self.hi)))
        return theta

    @torch.no_grad()
    def clamp_(self, theta: torch.Tensor) -> torch.Tensor:
        """In place on θ (..., K): limited joints clamped, continuous hinges left unwrapped (for
        paths, whose continuous joints are unwrapped along the path)."""
        theta.copy_(torch.where(self.cont, theta, torch.clamp(theta, self.lo, self.hi)))
        return theta

    def wrap(self, theta: torch.Tensor) -> torch.Tensor:
        """Differentiable: continuous hinges wrapped to [-pi, pi) (gradient 1), others as they are."""
        return torch.where(self.cont, torch.remainder(theta + math.pi, 2 * math.pi) - math.pi, theta)

    def numpy(self, theta: np.ndarray) -> np.ndarray:
        """float64 copy of θ (..., K) inside the limits. The float32 optimiser can round a clamped
        joint just past a float64 limit; this makes the returned poses exactly in range."""
        q = np.asarray(theta, dtype=np.float64)
        wrapped = np.remainder(q + np.pi, 2 * np.pi) - np.pi
        return np.where(self.cont_np, wrapped, np.clip(q, self.lim_np[:, 0], self.lim_np[:, 1]))

    def diff(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """a − b with continuous joints taken the short way round, (..., K)."""
        d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
        return np.where(self.cont_np, np.remainder(d + np.pi, 2 * np.pi) - np.pi, d)
