"""End-effector terms where poses are optimised (issue 34): targets for a frame (a site, body or
geom) at chosen indices of a path or video, as the paper's real-robot demo splits its frames:
*movement* frames steered by the collision field, *operation* frames by the end-effector pose.

Two tools, used together:

* :meth:`FrameTargets.loss`: a differentiable term on the chosen rows of θ (torch FK), so that
  their neighbours (through TV) move with them while optimising;
* :meth:`FrameTargets.snap`: exact, by the core's certified IK (:func:`profrobot.ik`) started
  from each chosen row: the frame lands on its target (to 0.1 mm, 1 mrad) in a pose certified
  free, the nearest such pose found.
"""

from __future__ import annotations

import numpy as np
import torch

from ..errors import InputError, InputTypeError
from ..exact.ik import as_targets, frame_of, ik
from ..kinematics.fk import Kinematics, quat_to_matrix
from ..robot.gate import Layout
from ..robot.robot import Robot

__all__ = ["FrameTargets"]

#: metres per radian: how a rotation error weighs against a position error in :meth:`FrameTargets.loss`
LENGTH = 0.3


class FrameTargets:
    """Targets of ``frame`` at path indices: ``targets`` a dict ``{index: (4, 4) world transform
    or (3,) position}`` (metres; all transforms or all positions) for a path of ``n`` rows."""

    def __init__(self, robot: Robot, frame: str, targets: dict, n: int, who: str = "frame_targets"):
        if not isinstance(targets, dict) or not targets:
            raise InputTypeError(f"{who} must be a non-empty dict {{index: (4, 4) transform or (3,) position}}; got "
                                 f"{type(targets).__name__}")
        idx = []
        for i in targets:
            if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not -n <= i < n:
                raise InputError(f"{who}: index {i!r} is not a row of the path (0..{n - 1})")
            idx.append(int(i) % n)
        if len(set(idx)) != len(idx):
            raise InputError(f"{who}: an index appears twice (as i and i - {n})")
        kinds = {np.shape(v) for v in targets.values()}
        if len(kinds) != 1:
            raise InputError(f"{who}: give every target as a (4, 4) transform, or every one as a (3,) position; got "
                             f"shapes {sorted(kinds)}")
        order = np.argsort(idx)
        self.index = np.asarray(idx)[order]
        values = [v for _, v in sorted(zip(idx, targets.values()), key=lambda p: p[0])]
        #: (M, 4, 4) transforms or (M, 3) positions, in index order (checked by ``as_targets``)
        self.targets = np.stack([np.asarray(v, dtype=np.float64) for v in values])
        self.pos, quat = as_targets(self.targets, who)
        self.rot = None if quat is None else self.targets[:, :3, :3]
        self.frame = frame
        self.body, lpos, lquat = frame_of(robot, frame)
        self.local_pos = lpos
        self.local_rot = quat_to_matrix(torch.as_tensor(lquat, dtype=torch.float64)).numpy()
        self._kin: Kinematics | None = None
        self._robot = robot

    def __len__(self) -> int:
        return len(self.index)

    def _frame_torch(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The frame's world position (B, 3) and rotation (B, 3, 3) at poses θ (B, K)."""
        if self._kin is None or self._kin.qpos0.dtype != theta.dtype:
            self._kin = Kinematics.from_robot(self._robot, dtype=theta.dtype).to(theta.device)
        bp = self._kin.fast(theta)
        R = bp.rot[:, self.body]
        lp = torch.as_tensor(self.local_pos, dtype=theta.dtype, device=theta.device)
        lr = torch.as_tensor(self.local_rot, dtype=theta.dtype, device=theta.device)
        return bp.pos[:, self.body] + torch.einsum("bij,j->bi", R, lp), torch.einsum("bij,jk->bik", R, lr)

    def loss(self, theta: torch.Tensor, rows: np.ndarray | None = None) -> torch.Tensor:
        """Σ over the targets among ``rows`` (the path indices of θ's rows, default 0..B−1) of
        ‖p − p*‖² + LENGTH²·½‖R − R*‖²_F (metres²): differentiable in θ (B, K)."""
        rows = np.arange(theta.shape[0]) if rows is None else np.asarray(rows)
        where = {int(r): i for i, r in enumerate(rows)}
        pick = [(where[int(j)], m) for m, j in enumerate(self.index) if int(j) in where]
        if not pick:
            return theta.sum() * 0.0
        r_idx = torch.as_tensor([p[0] for p in pick], device=theta.device)
        m_idx = [p[1] for p in pick]
        p, R = self._frame_torch(theta[r_idx])
        out = ((p - torch.as_tensor(self.pos[m_idx], dtype=theta.dtype, device=theta.device)) ** 2).sum()
        if self.rot is not None:
            Rt = torch.as_tensor(self.rot[m_idx], dtype=theta.dtype, device=theta.device)
            out = out + LENGTH ** 2 * 0.5 * ((R - Rt) ** 2).sum()
        return out

    def snap(self, path: np.ndarray, *, layout: Layout | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``path`` (S, K) with each chosen row replaced by the certified IK pose nearest it that
        reaches its target; returns (path, snapped (M,) bool). A row whose target cannot be
        reached certified free is left as it is (and reported)."""
        path = np.array(path, dtype=np.float64, copy=True)
        res = ik(self._robot, self.targets, frame=self.frame, start=path[self.index], layout=layout)
        ok = res.certified
        path[self.index[ok]] = res.poses[ok]
        return path, ok
