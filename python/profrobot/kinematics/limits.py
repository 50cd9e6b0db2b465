"""Joint space: one helper for the joint limits, shared by the optimisers (``profrobot.optim``)
and pose fitting (``profrobot.render.pose``).

Limited joints (hinges with a range, slides) are clamped to their range; continuous hinges
(no range) are wrapped to [-pi, pi): clamping them at ±pi would block a turn through pi. The
wrap is :func:`profrobot.robot.angles.wrap` (the Rust core's, bit for bit) on numpy arrays and its
torch twin :func:`_wrap` (the same formula) on tensors: pi goes to -pi.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import torch

from ..robot.angles import wrap
from ..errors import InputError, InputTypeError

__all__ = ["Limits"]


def _wrap(x: torch.Tensor, half: float = math.pi) -> torch.Tensor:
    """x wrapped into [-half, half): :func:`profrobot.robot.angles.wrap`'s formula, written for tensors
    (gradient 1). With ``half = pi`` on float64 it equals ``angles.wrap`` bit for bit (values in
    range unchanged, pi to -pi, fmod with Rust's ``rem_euclid`` correction);
    ``tests/test_wrapping.py`` checks it. In float32 the same steps round in float32."""
    r = torch.fmod(x + half, 2 * half)
    r = torch.where(r < 0, r + 2 * half, r)
    y = r - half
    y = torch.where(y >= half, y - 2 * half, y)
    return torch.where((x >= -half) & (x < half), x, y)


#: radians / metres: how far inside its limits an optimiser keeps a joint it moves. A pose on a
#: limit often touches: the Panda's fingers closed (0 m) press their pads together at clearance
#: 0, which is not a collision and can never be certified (clearance > CLEARANCE is required);
#: 0.1 mm or 0.1 mrad inside, they are apart.
LIMIT_INSET = 1e-4


class Limits:
    """The joint limits of a robot as tensors on one device.

    ``lower``, ``upper`` (K,) radians / metres (continuous hinges: -pi, pi), ``continuous`` (K,)
    bool. Build with :meth:`of` from a :class:`~profrobot.Robot`, a PoseSDF that knows its robot,
    or a :class:`~profrobot.render.GaussianRobot`; ``like`` picks the device and dtype.
    """

    def __init__(self, lower: npt.ArrayLike, upper: npt.ArrayLike, continuous: npt.ArrayLike,
                 like: torch.Tensor | None = None):
        dtype = like.dtype if like is not None else torch.float32
        device = like.device if like is not None else None
        self.lim_np = np.stack([np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)], axis=1)
        self.cont_np = np.asarray(continuous, dtype=bool).reshape(-1)
        if self.lim_np.ndim != 2 or self.lim_np.shape[0] != len(self.cont_np):
            raise InputError(f"lower, upper and continuous must all have shape (K,); got {self.lim_np.shape[0]} "
                             f"limits and {len(self.cont_np)} flags")
        if not np.isfinite(self.lim_np).all() or (self.lim_np[:, 1] < self.lim_np[:, 0]).any():
            raise InputError("joint limits must be finite with lower <= upper")
        self.lower = torch.as_tensor(self.lim_np[:, 0], dtype=dtype, device=device)
        self.upper = torch.as_tensor(self.lim_np[:, 1], dtype=dtype, device=device)
        self.continuous = torch.as_tensor(self.cont_np, device=device)
        self.span = (self.upper - self.lower).clamp_min(1e-9)
        #: the robot's joint equalities (:class:`profrobot.robot.equalities.JointCouplings`) when known:
        #: :meth:`numpy` puts returned poses on them
        self.couplings = None

    @classmethod
    def of(cls, obj: object, like: torch.Tensor | None = None) -> "Limits":
        """Limits of a Robot (``joint_limits``, ``continuous``), of a PoseSDF through the robot
        it was trained for (``sdf.robot``), or of any object with ``joint_limits``/``limits``
        and ``continuous``."""
        src = obj
        robot = None if hasattr(src, "continuous") else getattr(obj, "robot", None)
        if robot is not None:
            src = robot
        cont = getattr(src, "continuous", None)
        lim = getattr(src, "limits_f64", None)          # a GaussianRobot's float64 copy
        if lim is None:
            lim = getattr(src, "joint_limits", None)
        if lim is None:
            lim = getattr(src, "limits", None)
        if cont is None or lim is None:
            raise InputTypeError(f"cannot tell the joint limits of a {type(obj).__name__}: it needs joint_limits and "
                            "continuous (or a robot that has them)")
        lim = lim.detach().cpu().numpy() if isinstance(lim, torch.Tensor) else np.asarray(lim)
        cont = cont.detach().cpu().numpy() if isinstance(cont, torch.Tensor) else np.asarray(cont)
        out = cls(lim[:, 0], lim[:, 1], cont, like)
        couplings = getattr(src, "couplings", None)
        if couplings is not None and hasattr(couplings, "apply") and couplings:
            out.couplings = couplings
        return out

    def __len__(self) -> int:
        return len(self.cont_np)

    # ---- tensors (differentiable unless marked in place) ---------------------------------------
    def bounds(self, inset: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """(lower, upper) (K,) tensors, ``inset`` inside each limit (at most half the range)."""
        if not inset:
            return self.lower, self.upper
        e = torch.clamp(self.span / 2, max=float(inset))
        return self.lower + e, self.upper - e

    def clamp_or_wrap(self, theta: torch.Tensor, inset: float = 0.0) -> torch.Tensor:
        """θ (..., K) with limited joints clamped (``inset`` inside their limits, e.g.
        :data:`LIMIT_INSET`) and continuous hinges wrapped to [-pi, pi)."""
        lo, hi = self.bounds(inset)
        return torch.where(self.continuous, _wrap(theta), torch.clamp(theta, lo, hi))

    @torch.no_grad()
    def clamp_or_wrap_(self, theta: torch.Tensor, inset: float = 0.0) -> torch.Tensor:
        """In place on θ (..., K)."""
        theta.copy_(self.clamp_or_wrap(theta, inset))
        return theta

    @torch.no_grad()
    def clamp_(self, theta: torch.Tensor, inset: float = 0.0) -> torch.Tensor:
        """In place on θ (..., K): limited joints clamped (``inset`` inside), continuous hinges left
        unwrapped (for paths, whose continuous joints are unwrapped along the path)."""
        lo, hi = self.bounds(inset)
        theta.copy_(torch.where(self.continuous, theta, torch.clamp(theta, lo, hi)))
        return theta

    def wrap(self, theta: torch.Tensor) -> torch.Tensor:
        """Continuous hinges wrapped to [-pi, pi) (gradient 1), the others as they are."""
        return torch.where(self.continuous, _wrap(theta), theta)

    def normalise(self, theta: torch.Tensor) -> torch.Tensor:
        """θ → u in [-1, 1] over each joint's range (continuous hinges: u = θ / pi)."""
        return 2 * (theta - self.lower) / self.span - 1

    def denormalise(self, u: torch.Tensor) -> torch.Tensor:
        """u in [-1, 1] → θ."""
        return self.lower + (u + 1) / 2 * self.span

    @torch.no_grad()
    def clamp_or_wrap_normalised_(self, u: torch.Tensor) -> torch.Tensor:
        """In place on normalised joints u (..., K): limited clamped to [-1, 1], continuous
        wrapped to [-1, 1) (the same as :meth:`clamp_or_wrap` on θ)."""
        u.copy_(torch.where(self.continuous, _wrap(u, 1.0), u.clamp(-1, 1)))
        return u

    # ---- numpy (float64) -----------------------------------------------------------------------
    def numpy(self, theta: np.ndarray) -> np.ndarray:
        """float64 copy of θ (..., K) inside the limits, and on the robot's joint equalities where
        they are known (every answer is a pose the robot can take: the optimisers move each joint
        freely, the mechanism does not). A float32 optimiser can round a clamped joint just past a
        float64 limit; this makes returned poses exactly in range. (A dependent joint that its
        coupling puts outside its own limits stays there: certification then refuses the pose.)"""
        q = np.asarray(theta, dtype=np.float64)
        q = np.where(self.cont_np, wrap(q), np.clip(q, self.lim_np[:, 0], self.lim_np[:, 1]))
        if self.couplings is not None and q.size:
            self.couplings.apply(q.reshape(-1, q.shape[-1]))
        return q

    def diff(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """a − b with continuous joints taken the short way round, (..., K)."""
        d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
        return np.where(self.cont_np, wrap(d), d)
