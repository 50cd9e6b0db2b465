"""Poses as the core takes them: a (B, K) float64 array for a robot, or an error naming the
entry (``poses[1, 2] (joint3) is inf``). The gate (:mod:`profrobot.robot.gate`) adds the type check
of the robot; this module imports no ``Robot``, so the robot's own methods can use it."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np
import numpy.typing as npt

from .._core import first_bad_entries
from ..errors import InputError, InputTypeError

__all__ = ["Jointed", "pose_array"]


class Jointed(Protocol):
    """What a pose check reads of a robot (a :class:`~profrobot.Robot` is one)."""

    @property
    def name(self) -> str: ...
    @property
    def njoint(self) -> int: ...
    @property
    def joint_names(self) -> Sequence[str]: ...
    @property
    def joint_limits(self) -> np.ndarray: ...
    @property
    def continuous(self) -> np.ndarray: ...


def limit_bounds(robot: Jointed, atol: float) -> tuple[np.ndarray, np.ndarray]:
    """(K,) lower and upper bounds each limited joint of ``robot`` must keep, its limits widened
    by ``atol`` (±inf for continuous hinges): read once per robot and tolerance, as ``pose_array``
    runs on every call of every entry point (kept in the robot's ``_pose_bounds``, a cache that
    copies and pickles leave out, ``robot/state.py``, and that the scenes put on the robot share,
    :func:`share_bounds`)."""
    cache = _bounds(robot) if hasattr(robot, "__dict__") else {}
    got = cache.get(atol)
    if got is None:
        lim, limited = robot.joint_limits, ~np.asarray(robot.continuous, dtype=bool)
        got = cache[atol] = (np.where(limited, lim[:, 0] - atol, -np.inf), np.where(limited, lim[:, 1] + atol, np.inf))
    return got


def _bounds(robot: Jointed) -> dict:
    """``robot``'s cache of :func:`limit_bounds`, by tolerance."""
    return robot.__dict__.setdefault("_pose_bounds", {})


def share_bounds(robot: Jointed, derived: Jointed) -> None:
    """``derived``, a robot with ``robot``'s joints and limits (a scene put on it,
    ``robot/world.py``), reads its pose bounds from ``robot``'s cache: read once for all."""
    derived.__dict__["_pose_bounds"] = _bounds(robot)


def pose_array(robot: Jointed, poses: npt.ArrayLike, *, name: str = "poses", check_limits: bool = False,
               atol: float = 1e-9) -> np.ndarray:
    """``poses`` as a C-contiguous float64 (B, K) array for ``robot``, or a clear exception.

    Accepts a single pose (K,) as a batch of one, and torch tensors. Rejects non-float dtypes,
    wrong widths, empty batches, NaN/inf, and (with ``check_limits``) limited joints outside
    their limits by more than ``atol``.
    """
    if hasattr(poses, "detach") and hasattr(poses, "cpu"):  # a torch tensor
        poses = poses.detach().cpu().numpy()
    try:
        arr = np.asarray(poses)
    except (ValueError, TypeError) as e:  # ragged nested lists
        raise InputError(f"{name} must be a (B, {robot.njoint}) array of numbers; got {type(poses).__name__} ({e})") from e
    if arr.dtype.kind in "iu":   # whole numbers (a list of ints, an int array) are radians / metres too
        arr = arr.astype(np.float64)
    if arr.dtype.kind not in "f":
        raise InputTypeError(f"{name} must be a floating-point array of numbers (radians / metres); got dtype {arr.dtype}")
    k = robot.njoint
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != k:
        raise InputError(f"{name} must have shape (B, {k}) for {robot.name} ({k} joints); got {np.shape(poses)}")
    if arr.shape[0] == 0:
        raise InputError(f"{name} is empty: at least one pose is needed")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    # One pass in Rust (numpy's comparisons and reductions took 4-12 ms a 200 000-pose batch):
    # the first non-finite entry, and the first limited entry outside its limits by more than atol.
    lo, hi = limit_bounds(robot, atol) if check_limits else (np.full(k, -np.inf), np.full(k, np.inf))
    nonfinite, outside = first_bad_entries(arr, lo, hi) if k else (None, None)
    if nonfinite is not None:
        i, j = divmod(nonfinite, k)
        raise InputError(f"{name}[{i}, {j}] ({robot.joint_names[j]}) is {arr[i, j]}; poses must be finite")
    if outside is not None:
        i, j = divmod(outside, k)
        lim = robot.joint_limits
        raise InputError(f"{name}[{i}, {j}] = {arr[i, j]:.6g} is outside the limits of joint "
                         f"{robot.joint_names[j]!r} [{lim[j, 0]:.6g}, {lim[j, 1]:.6g}]")
    return arr
