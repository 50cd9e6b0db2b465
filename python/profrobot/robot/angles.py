"""The one angle wrap of the Python side: continuous hinges (SO(2)) are wrapped, and shortest-arc
differences taken, by :func:`wrap`, the twin of the Rust core's ``angles::wrap``
(``rust/joints/angles.rs``) that :func:`profrobot.interpolate` and :func:`profrobot.plan_path` use.
The two agree bit for bit (``tests/test_wrapping.py``).

Semantics (radians, float64):

- ``wrap(x)`` lies in ``[-pi, pi)``; a value already there comes back unchanged, bit for bit
  (tiny values stay tiny, ``wrap(wrap(x)) == wrap(x)``);
- ``pi`` goes to ``-pi``: a difference of exactly half a turn, ``wrap(b - a)``, moves the
  negative way, as the interpolation and the planner move it;
- otherwise ``(x + pi) mod 2 pi - pi`` with the remainder taken as Rust's ``rem_euclid``
  (``fmod``, plus ``2 pi`` when negative); a remainder that rounds up to ``2 pi`` (the float just
  below ``-pi``) gives ``-pi``, never ``pi``;
- NaN and infinities give NaN.

numpy only (a base-layer module: no torch, no profrobot import). The torch twin used by
:class:`profrobot.kinematics.limits.Limits` is the same formula (``joints._wrap``).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

__all__ = ["wrap", "unwrap"]

PI = math.pi  # the same double as Rust's std::f64::consts::PI
TAU = 2 * math.pi  # exact: Rust's TAU


def wrap(x: npt.ArrayLike) -> float | np.ndarray:
    """``x`` (a float or an array of any shape) wrapped into ``[-pi, pi)`` (see the module docs);
    a float for a Python or numpy scalar, a float64 array otherwise."""
    a = np.asarray(x, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        r = np.fmod(a + PI, TAU)
        r = np.where(r < 0, r + TAU, r)
        y = r - PI
        out = np.where((a >= -PI) & (a < PI), a, np.where(y >= PI, -PI, y))
    return float(out) if out.ndim == 0 else out


def unwrap(path: npt.ArrayLike, axis: int = -2) -> np.ndarray:
    """Angles along ``axis`` of ``path`` made continuous: each step becomes its shortest arc,
    ``wrap(step)`` (``numpy.unwrap`` with this module's ``wrap``, so a step of exactly half a turn
    moves the negative way, as :func:`profrobot.interpolate` moves it, where ``numpy.unwrap``
    moves it the positive way). The first entry is kept; each later one is its raw value plus a
    multiple of 2 pi (exactly 0 for steps already in ``[-pi, pi)``). A float64 copy."""
    out = np.array(path, dtype=np.float64)
    if out.shape[axis] < 2:
        return out
    d = np.diff(out, axis=axis)
    later = [slice(None)] * out.ndim
    later[axis] = slice(1, None)
    out[tuple(later)] += np.cumsum(wrap(d) - d, axis=axis)
    return out
