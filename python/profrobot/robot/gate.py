"""The one gate: the argument checks every public entry point passes its robot and poses
through, written once (base layer, no torch).

Every entry point that takes a robot takes the same two keywords and means the same by them:

- ``layout``: a family's layout δ ((D,) radians / metres in ``robot.scene_joints`` order, or
  ``{scene joint: value}``). Entry points that answer on one scene pin the family there
  (:func:`robot_at`: ``robot.at(layout)``, whose poses are the robot's θ); those that answer per
  pose compose θ with it (:func:`with_layout`; there one layout per pose, (B, D), works too). A
  layout given to a robot that is no family is refused, and so is a family without a layout
  where an entry point needs one scene, with one message (:func:`robot_at`).
- ``margin``: metres every answer keeps from every obstacle (:meth:`Robot.with_margin`,
  :mod:`profrobot.robot.margin`); at most :data:`~profrobot.robot.margin.CLEARANCE` (the default)
  is the robot as modelled.

Each check returns the value in its canonical Python type or raises an :class:`~profrobot.errors.InputError`
(a ValueError) or :class:`~profrobot.errors.InputTypeError` (a TypeError) that names the argument and what it got, e.g.
``poses[1, 2] (joint3) is inf; poses must be finite``.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from collections.abc import Sequence
from typing import Any, Literal, overload

import numpy as np
import numpy.typing as npt

from ..errors import InputError, InputTypeError
from .family import Layout
from .margin import CLEARANCE
from .poses import pose_array
from .robot import Robot

__all__ = ["robot_at", "with_layout", "as_poses", "poses_within_limits", "joint_mask", "positive", "finite", "count", "seed",
           "threads", "memory", "available_bytes", "with_margin", "CLEARANCE", "Layout"]


def _is_number(value) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool)


@overload
def positive(name: str, value: Any, *, integer: Literal[True], allow_zero: bool = False) -> int: ...
@overload
def positive(name: str, value: Any, *, integer: Literal[False] = False, allow_zero: bool = False) -> float: ...
@overload
def positive(name: str, value: Any, *, integer: bool, allow_zero: bool = False) -> float | int: ...
def positive(name: str, value: Any, *, integer: bool = False, allow_zero: bool = False) -> float | int:
    """``value`` > 0 (>= 0 with ``allow_zero``), finite, an integer with ``integer``."""
    bad = not _is_number(value)
    if integer and not bad:
        bad = not float(value).is_integer()
    if bad or not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        kind = "integer" if integer else "number"
        raise InputError(f"{name} must be a {'non-negative' if allow_zero else 'positive'} {kind}; got {value!r}")
    return int(value) if integer else float(value)


def finite(name: str, value: Any) -> float:
    """Any finite real number."""
    if not _is_number(value) or not math.isfinite(value):
        raise InputError(f"{name} must be a finite number; got {value!r}")
    return float(value)


def per_joint(robot: "Robot", name: str, value: Any, unit: str) -> np.ndarray:
    """(K,) positive finite limits, one per joint of ``robot`` (a number: every joint), in
    ``unit``; refused by name when missing, negative, zero, NaN or of another length."""
    if value is None:
        raise InputError(f"{name} is required ({unit}, a number or one per joint: {robot.name} carries none)")
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number or {robot.njoint} numbers ({unit}); got {value!r}") from None
    if v.ndim == 0:
        v = np.full(robot.njoint, float(v))
    if v.shape != (robot.njoint,):
        raise InputError(f"{name} must be a number or {robot.njoint} numbers ({unit}), one per joint of "
                         f"{robot.name}; got shape {v.shape}")
    # (on Python floats: K numbers, where three numpy calls would cost more than the test;
    # NaN fails both comparisons)
    for j, x in enumerate(v.tolist()):
        if not 0.0 < x < math.inf:
            raise InputError(f"{name}[{j}] ({robot.joint_names[j]}) must be positive and finite ({unit}); got {v[j]!r}")
    return v


def count(name: str, value: Any, low: int = 1, why: str = "") -> int:
    """An integer (not a bool, not a float) >= ``low``; ``why`` is added to the message."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < low:
        what = "a positive integer" if low == 1 else f"an integer >= {low}"
        raise InputError(f"{name} must be {what}{f' ({why})' if why else ''}; got {value!r}")
    return int(value)


def available_bytes() -> int:
    """Bytes of memory available to allocate (``MemAvailable`` of /proc/meminfo; elsewhere, the
    physical memory, or no limit where neither can be read)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        import os

        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 2**63


#: Bytes allowed without reading /proc/meminfo (a read costs about 30 µs; a machine without
#: 64 MiB to spare has failed before the call). The same rule as the core's (``budget.rs``).
ALWAYS_FITS = 1 << 26


def memory(name: str, *dims: int, itemsize: int = 8) -> None:
    """Refuse, with an :class:`InputError` naming ``name``, an array of shape ``dims`` and
    ``itemsize``-byte items that would not fit in the memory available (an allocation that
    fails in Rust aborts the process; in numpy it is a bare MemoryError)."""
    need = itemsize
    for d in dims:
        need *= int(d)
    if need <= ALWAYS_FITS:
        return
    have = available_bytes()
    if need > have:
        raise InputError(f"{name} is too large: an array of shape {tuple(int(d) for d in dims)} needs "
                         f"{need / 1e9:.3g} GB, and {have / 1e9:.3g} GB of memory is available")


def seed(value: Any, name: str = "seed") -> int:
    """A seed for the Rust samplers: an integer in [0, 2**64)."""
    if isinstance(value, bool) or not isinstance(value, Integral) or not 0 <= int(value) < 2**64:
        raise InputError(f"{name} must be an integer in [0, 2**64); got {value!r}")
    return int(value)


def threads(value: Any) -> int | None:
    """None (every core) or a positive thread count."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, Integral) or value < 1:
        raise InputError(f"threads must be a positive integer or None; got {value!r}")
    return int(value)


def as_poses(robot: "Robot", poses: npt.ArrayLike, *, name: str = "poses", check_limits: bool = False,
             atol: float = 1e-9) -> np.ndarray:
    """``poses`` as a C-contiguous float64 (B, K) array for ``robot``, or a clear exception
    (:func:`profrobot.robot.poses.pose_array`, after the robot's type)."""
    if not isinstance(robot, Robot):
        raise InputTypeError(f"expected a profrobot.Robot; got {type(robot).__name__}")
    return pose_array(robot, poses, name=name, check_limits=check_limits, atol=atol)


def _robot(robot: object) -> Robot:
    if not isinstance(robot, Robot):
        raise InputTypeError(f"robot must be a profrobot.Robot; got {type(robot).__name__}")
    return robot


def _no_family(robot: Robot) -> InputError:
    """The one message for a layout given to a robot with no scene joints."""
    return InputError(f"layout= is a layout of a family of scenes; {robot.name} has no scene joints")


def _family_needs_layout(robot: Robot) -> InputError:
    """The one message for a family where one scene is needed."""
    return InputError(f"{robot.name} is a family of scenes ({len(robot.scene_joints)} scene joints: "
                      f"{', '.join(robot.scene_joints)}): pass layout=δ, the layout to work at, or pin it first, robot.at(δ)")


def robot_at(robot: Robot, *, layout: Layout | None = None, margin: float = CLEARANCE,
             family: bool = False) -> Robot:
    """The robot an entry point answers on: ``robot`` checked, a family pinned at ``layout``
    (``robot.at(layout)``: the poses are then its θ), ``margin`` metres kept from every obstacle.

    ``family``: whether the entry point also takes a family without a layout (its full poses over
    θ and δ); otherwise a family without a layout is refused with one message, the same from
    every entry point. A ``layout`` for a robot with no scene joints is refused."""
    robot = _robot(robot)
    if layout is not None:
        if not robot.is_family:
            raise _no_family(robot)
        robot = robot.at(layout)
    elif robot.is_family and not family:
        raise _family_needs_layout(robot)
    return robot.with_margin(margin)


def with_layout(robot: Robot, poses: npt.ArrayLike, layout: Layout | None,
                name: str = "poses") -> npt.ArrayLike:
    """The labeller's full pose vectors: ``poses`` as given, or, with ``layout=δ`` (a family's
    layout, (D,), a dict, or one per pose (B, D)), robot poses θ (B, K − D) composed with it
    (:meth:`Robot.compose`). A family's θ without ``layout`` is refused naming both ways."""
    robot = _robot(robot)
    if layout is not None:
        if not robot.is_family:
            raise _no_family(robot)
        if hasattr(poses, "detach") and hasattr(poses, "cpu"):
            poses = poses.detach().cpu().numpy()
        theta = np.asarray(poses)
        if theta.dtype.kind in "iu":
            theta = theta.astype(np.float64)
        if theta.dtype.kind != "f":
            raise InputTypeError(f"{name} must be a floating-point array of numbers (radians / metres); got dtype {theta.dtype}")
        return robot.compose(theta, layout)
    if robot.is_family:
        d, k = len(robot.scene_index), robot.njoint
        if np.shape(poses)[-1:] == (k - d,):
            raise InputError(f"{name} has {k - d} columns, the robot joints of the family {robot.name}: pass its "
                             f"layout too, layout=δ ({d} scene joints: {', '.join(robot.scene_joints)}), or full "
                             f"poses robot.compose(θ, δ) of shape (B, {k})")
    return poses


def joint_mask(robot: Robot, names: Sequence[str], name: str) -> list[bool] | None:
    """(K,) True on the joints of ``robot`` named in ``names`` (``locked=``: joints an entry point
    keeps where they are), None for none. An unknown or repeated name, or one string instead of a
    list of names, is refused naming ``name``."""
    if isinstance(names, str):
        raise InputTypeError(f"{name} must be a list of joint names; got the string {names!r} (write [{names!r}])")
    try:
        given = list(names)
    except TypeError:
        raise InputTypeError(f"{name} must be a list of joint names; got {type(names).__name__}") from None
    if not given:
        return None
    mask = [False] * robot.njoint
    for n in given:
        if not isinstance(n, str) or n not in robot.joint_names:
            raise InputError(f"{name}: {n!r} is not a joint of {robot.name} (joints: {', '.join(robot.joint_names)})")
        j = robot.joint_names.index(n)
        if mask[j]:
            raise InputError(f"{name}: {n!r} is named twice")
        mask[j] = True
    return mask


def poses_within_limits(robot: "Robot", poses: npt.ArrayLike, name: str = "poses") -> np.ndarray:
    """:func:`as_poses` with the joint limits checked to 1e-6 (float32 round trips from torch)."""
    return as_poses(robot, poses, name=name, check_limits=True, atol=1e-6)


def with_margin(robot: Robot, margin: float) -> Robot:
    """``robot`` with a safety margin of ``margin`` metres around its obstacles
    (:meth:`Robot.with_margin`, :mod:`profrobot.robot.margin`): what every entry point labels and
    certifies on. ``margin`` at most ``CLEARANCE`` is ``robot`` itself."""
    return _robot(robot).with_margin(margin)
