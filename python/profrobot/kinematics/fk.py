"""Differentiable forward kinematics in torch, over the same flat body tree as the Rust core.

One robot description, two back ends: :class:`Kinematics` reads ``Robot.core_arrays()`` (the
arrays ``rust/model/kinematics.rs`` walks) and reproduces MuJoCo's ``mj_kinematics``:

- body ``b`` with parent ``p``:  ``R_b = R_p R_loc``,  ``x_b = x_p + R_p t_loc``;
- then each joint of ``b`` in order, with ``a = q - qpos0``:
  hinge  ``c = x_b + R_b anchor``;  ``R_b <- R_b Rot(axis, a)``;  ``x_b <- c - R_b anchor``;
  slide  ``x_b <- x_b + R_b axis a``.

The tree is evaluated level by level (all bodies at one depth in one batched op), so a
Shadow Hand's five fingers cost what one finger costs. Everything is differentiable in ``q``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from ..errors import InputError
from ..robot.robot import Robot

__all__ = ["Kinematics", "BodyPoses", "quat_to_matrix", "axis_angle_matrix"]


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(..., 4) unit quaternions (w, x, y, z) → (..., 3, 3) rotation matrices."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))


def axis_angle_matrix(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rodrigues: ``I + sin(a) K + (1 - cos(a)) K²`` for unit ``axis`` (..., 3) and ``angle`` (...)
    in radians → (..., 3, 3)."""
    kx, ky, kz = axis.unbind(-1)
    zero = torch.zeros_like(kx)
    k = torch.stack([zero, -kz, ky, kz, zero, -kx, -ky, kx, zero], dim=-1).reshape(axis.shape[:-1] + (3, 3))
    s = torch.sin(angle)[..., None, None]
    c = (1 - torch.cos(angle))[..., None, None]
    eye = torch.eye(3, dtype=axis.dtype, device=axis.device)
    return eye + s * k + c * (k @ k)  # k @ k has no batch dims beyond axis's: cheap


def _rodrigues_np(w: np.ndarray, ang: np.ndarray) -> np.ndarray:
    """Rotations (B, 3, 3) by ``ang`` (B,) radians about unit world axes ``w`` (B, 3): the
    numpy twin of :func:`axis_angle_matrix`, for :meth:`Kinematics.fast`, whose point is to
    avoid a torch op's fixed cost per body."""
    k = np.zeros(w.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    s, c = np.sin(ang)[..., None, None], (1 - np.cos(ang))[..., None, None]
    return np.eye(3) + s * k + c * (k @ k)


class _ClosedFormFK(torch.autograd.Function):
    """FK with the backward written out, for trees with at most one joint (hinge or slide) per
    body. A hinge ``j`` with world axis ``ω`` through anchor ``p`` moves every body ``b`` of its
    subtree by ``∂R_b/∂θ_j = [ω]× R_b``, ``∂x_b/∂θ_j = ω × (x_b - p)``; a slide by
    ``∂x_b/∂θ_j = ω``. So, with ``w_b = Σ_k R_b[:, k] × gR_b[:, k]`` (``<gR, [ω]× R> = ω · w``):

        ∂L/∂θ_j = ω · (Σ_b∈sub(j) (w_b + x_b × g_x_b) - p × Σ_b∈sub(j) g_x_b)      (hinge)
        ∂L/∂θ_j = ω · Σ_b∈sub(j) g_x_b                                              (slide)
    """

    @staticmethod
    def forward(ctx, q, kin):
        R, x, w, p = kin._frames_np(q.detach().to("cpu", torch.float64).numpy())
        ctx.frames, ctx.kin, ctx.meta = (R, x, w, p), kin, (q.dtype, q.device)
        # copies: the outputs must not share memory with the frames the backward reads
        return torch.tensor(R, dtype=q.dtype), torch.tensor(x, dtype=q.dtype)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, gR, gx):
        R, x, w, p = ctx.frames
        a = ctx.kin._np
        gR = np.zeros_like(R) if gR is None else gR.detach().to("cpu", torch.float64).numpy()
        gx = np.zeros_like(x) if gx is None else gx.detach().to("cpu", torch.float64).numpy()
        wb = np.cross(R, gR, axis=-2).sum(-1)                                 # (B, nb, 3): Σ_k R[:, k] × gR[:, k]
        s1 = np.einsum("jb,nbi->nji", a["subtree"], wb + np.cross(x, gx))
        s2 = np.einsum("jb,nbi->nji", a["subtree"], gx)
        hinge = (a["jnt_type"] == 3)[None, :]
        g = np.where(hinge, (w * (s1 - np.cross(p, s2))).sum(-1), (w * s2).sum(-1))
        return torch.from_numpy(g).to(dtype=ctx.meta[0], device=ctx.meta[1]), None


@dataclass
class BodyPoses:
    """World poses of every body: ``rot`` (B, nbody, 3, 3) and ``pos`` (B, nbody, 3) in metres.
    Body 0 is the world."""

    rot: torch.Tensor
    pos: torch.Tensor

    def transform(self, body: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        """Points (P, 3) given in the frames of bodies ``body`` (P,) → world (B, P, 3)."""
        return torch.einsum("bpij,pj->bpi", self.rot[:, body], points) + self.pos[:, body]


class Kinematics(torch.nn.Module):
    """Batched, differentiable FK for a :class:`profrobot.Robot` (hinge and slide joints).

    ``forward(q)``: q (B, K) in radians / metres, MuJoCo joint order → :class:`BodyPoses`.
    Matches MuJoCo's ``xpos``/``xmat`` (tested to 1e-5 in float32, 1e-10 in float64).
    """

    qpos0: torch.Tensor      # buffers (register_buffer; the per-level ones are in :attr:`levels`)
    _unsort: torch.Tensor

    def __init__(self, arrays: dict, *, dtype: torch.dtype = torch.float32):
        super().__init__()
        parent = np.asarray(arrays["body_parent"], dtype=np.int64)
        nbody = len(parent)
        jnt_body = np.asarray(arrays["jnt_body"], dtype=np.int64)
        njnt = len(jnt_body)
        self.nbody, self.njoint = nbody, njnt
        depth = np.zeros(nbody, dtype=np.int64)
        for b in range(1, nbody):  # MuJoCo orders parents before children
            depth[b] = depth[parent[b]] + 1
        joints_of: list[list[int]] = [[] for _ in range(nbody)]
        for j, b in enumerate(jnt_body):
            joints_of[b].append(j)

        f = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=dtype)
        self.register_buffer("qpos0", f(arrays["jnt_qpos0"]), persistent=False)
        # Per level: body ids, their parents' slots in the previous level, local transforms and
        # a (slots, nbody_at_level) table of joints (-1 = none) with type masks.
        self._level_keys: list[dict[str, str]] = []
        # the same tree as plain float64 arrays, for the closed-form path (:meth:`fast`)
        self._np = dict(parent=parent, body_rot=quat_to_matrix(torch.as_tensor(np.asarray(arrays["body_quat"], dtype=np.float64))).numpy(),
                        body_pos=np.asarray(arrays["body_pos"], dtype=np.float64), jnt_body=jnt_body,
                        jnt_type=np.asarray(arrays["jnt_type"]), jnt_axis=np.asarray(arrays["jnt_axis"], dtype=np.float64),
                        jnt_pos=np.asarray(arrays["jnt_pos"], dtype=np.float64),
                        qpos0=np.asarray(arrays["jnt_qpos0"], dtype=np.float64))
        # one joint per body at most, hinges and slides: the closed-form backward applies
        self._closed_form = bool(np.bincount(jnt_body, minlength=nbody).max(initial=0) <= 1
                                 and np.isin(self._np["jnt_type"], (2, 3)).all())
        # subtree[j, b]: body b moves with joint j (the joint's body and its descendants)
        sub = np.zeros((njnt, nbody))
        for j, b in enumerate(jnt_body):
            for c in range(nbody):
                a = c
                while a > 0 and a != b:
                    a = int(parent[a])
                sub[j, c] = float(a == b and (c == b or c > 0))
        self._np["subtree"] = sub
        slot_in_level = np.zeros(nbody, dtype=np.int64)
        self.body_level = depth
        for d in range(1, int(depth.max()) + 1):
            bodies = np.flatnonzero(depth == d)
            slot_in_level[bodies] = np.arange(len(bodies))
            nslot = max((len(joints_of[b]) for b in bodies), default=0)
            jtab = -np.ones((nslot, len(bodies)), dtype=np.int64)
            for i, body in enumerate(bodies):
                jtab[: len(joints_of[body]), i] = joints_of[body]
            jid = np.maximum(jtab, 0)
            jtype = np.asarray(arrays["jnt_type"])[jid]
            has = jtab >= 0
            lvl = dict(
                bodies=torch.as_tensor(bodies),
                parent_slot=torch.as_tensor(slot_in_level[parent[bodies]] if d > 1 else np.zeros(len(bodies), dtype=np.int64)),
                rot=quat_to_matrix(f(np.asarray(arrays["body_quat"])[bodies])),
                pos=f(np.asarray(arrays["body_pos"])[bodies]),
                joint=torch.as_tensor(jid),
                hinge=torch.as_tensor(has & (jtype == 3)).to(dtype),
                slide=torch.as_tensor(has & (jtype == 2)).to(dtype),
                axis=f(np.asarray(arrays["jnt_axis"])[jid]),
                anchor=f(np.asarray(arrays["jnt_pos"])[jid]) * torch.as_tensor(has, dtype=dtype)[..., None],
            )
            for k, v in lvl.items():  # buffers, so that .to(device, dtype) moves them
                # clone: own storage (numpy-backed empty tensors trip torch.export's packager)
                self.register_buffer(f"_l{d}_{k}", v.clone().contiguous(), persistent=False)
            self._level_keys.append({k: f"_l{d}_{k}" for k in lvl})
        # where each body ends up in the concatenation of levels (world first)
        order = np.concatenate([[0]] + [np.flatnonzero(depth == d) for d in range(1, int(depth.max()) + 1)])
        self.register_buffer("_unsort", torch.as_tensor(np.argsort(order)), persistent=False)
        self.dtype = dtype

    @property
    def levels(self) -> list[dict[str, torch.Tensor]]:
        return [{k: getattr(self, name) for k, name in keys.items()} for keys in self._level_keys]

    def forward(self, q: torch.Tensor) -> BodyPoses:
        if q.ndim != 2 or q.shape[1] != self.njoint:
            raise InputError(f"q must have shape (B, {self.njoint}); got {tuple(q.shape)}")
        B = q.shape[0]
        a = q - self.qpos0
        eye = torch.eye(3, dtype=q.dtype, device=q.device).expand(B, 1, 3, 3)
        rots, poss = [eye], [torch.zeros(B, 1, 3, dtype=q.dtype, device=q.device)]
        R_prev, x_prev = rots[0], poss[0]
        for lv in self.levels:
            Rp = R_prev[:, lv["parent_slot"]]                      # (B, n, 3, 3)
            xp = x_prev[:, lv["parent_slot"]]                      # (B, n, 3)
            # einsum, not broadcasting @: torch turns it into one bmm (5-10x faster on a CPU)
            R = torch.einsum("bnij,njk->bnik", Rp, lv["rot"])
            x = xp + torch.einsum("bnij,nj->bni", Rp, lv["pos"])
            for s in range(lv["joint"].shape[0]):
                ang = a[:, lv["joint"][s]]                          # (B, n)
                anchor = lv["anchor"][s]                            # (n, 3)
                # hinge: rotate about the anchor; a zero angle (slide or no joint) is identity
                c = x + torch.einsum("bnij,nj->bni", R, anchor)
                R = torch.einsum("bnij,bnjk->bnik", R, axis_angle_matrix(lv["axis"][s], ang * lv["hinge"][s]))
                x = c - torch.einsum("bnij,nj->bni", R, anchor)
                # slide: translate along the joint axis in the body frame
                x = x + torch.einsum("bnij,nj->bni", R, lv["axis"][s]) * (ang * lv["slide"][s])[..., None]
            rots.append(R)
            poss.append(x)
            R_prev, x_prev = R, x
        rot = torch.cat(rots, dim=1)[:, self._unsort]
        pos = torch.cat(poss, dim=1)[:, self._unsort]
        return BodyPoses(rot=rot, pos=pos)

    def fast(self, q: torch.Tensor) -> BodyPoses:
        """:meth:`forward` with its backward in closed form (one autograd node instead of a few
        hundred small ones: several times cheaper on a CPU), for robots with at most one joint
        per body; other robots, and CUDA tensors, take :meth:`forward`. Computed in float64,
        returned in ``q``'s dtype. First order only: double backward and forward-mode AD need
        :meth:`forward`."""
        if not self._closed_form or q.device.type != "cpu" or q.ndim != 2 or q.shape[1] != self.njoint:
            return self.forward(q)
        rot, pos = _ClosedFormFK.apply(q, self)
        return BodyPoses(rot=rot, pos=pos)

    def _frames_np(self, q: np.ndarray):
        """Body rotations (B, nb, 3, 3), positions (B, nb, 3) and each joint's world axis and
        anchor (B, K, 3) at poses ``q`` (B, K), float64 (MuJoCo's recursion, one body at a time)."""
        a = self._np
        B, nb = q.shape[0], self.nbody
        R = np.empty((B, nb, 3, 3))
        x = np.empty((B, nb, 3))
        R[:, 0], x[:, 0] = np.eye(3), 0.0
        axis_w = np.zeros((B, self.njoint, 3))
        anchor_w = np.zeros((B, self.njoint, 3))
        joint_of = {int(b): j for j, b in enumerate(a["jnt_body"])}
        ang = q - a["qpos0"]
        for b in range(1, nb):
            p = a["parent"][b]
            R[:, b] = R[:, p] @ a["body_rot"][b]
            x[:, b] = x[:, p] + R[:, p] @ a["body_pos"][b]
            j = joint_of.get(b)
            if j is None:
                continue
            w = R[:, b] @ a["jnt_axis"][j]                                     # (B, 3) world axis
            axis_w[:, j] = w
            if a["jnt_type"][j] == 3:                                          # hinge about the anchor
                c = x[:, b] + R[:, b] @ a["jnt_pos"][j]
                R[:, b] = _rodrigues_np(w, ang[:, j]) @ R[:, b]                # R Rot(axis) = Rot(R axis) R
                x[:, b] = c - R[:, b] @ a["jnt_pos"][j]
                anchor_w[:, j] = c
            else:                                                              # slide along the axis
                x[:, b] = x[:, b] + w * ang[:, j, None]
        return R, x, axis_w, anchor_w

    @classmethod
    def from_robot(cls, robot: Robot, *, dtype: torch.dtype = torch.float32) -> "Kinematics":
        """FK for ``robot`` (a :class:`profrobot.Robot`)."""
        return cls(robot.core_arrays(), dtype=dtype)
