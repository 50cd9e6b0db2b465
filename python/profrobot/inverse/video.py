"""Joint trajectories from multi-view video (paper supplement, "actions from video"):

1. per frame, ``iterations_per_frame`` Adam steps on the image loss, warm-started from the previous
   frames' answers extrapolated at constant velocity (the first frame from ``init``, with
   ``first_frame_iterations`` steps: it has no history to start from);
2. all frames jointly: image loss + ``w_tv`` TV (mean ‖θ_{t+1} − θ_t‖₁), ``joint_iterations`` steps;
3. with a field: the same joint refinement with ``beta`` ReLU(g − l_thres) on every frame; then
   the exact labeller on every frame and, continuously, every segment (every pose proven). Frames
   it finds colliding are resolved (:func:`profrobot.resolve`), and segments still colliding are
   optimised on the field with the free frames as fixed ends (``plan_trajectory``'s penalty
   loop). What still collides is reported in the result, never returned as free.
"""

from __future__ import annotations

import time

import numpy as np
import numpy.typing as npt
import torch

from ..errors import InputError
from ..kinematics.limits import Limits
from ..field.identity import Field
from ..render.cameras import Cameras
from ..robot.gate import Layout, finite, positive
from ..exact.certification import certify_poses, check_path
from ..optim.paths import PenaltyOptions, penalty_descent, unwrap_path
from ..optim.trajectory import TrajectoryResult
from ..render.targets import ImageTargets
from ..render.gaussians import GaussianRobot, pose_only
from ..robot.robot import Robot
from ..field.layout import field_at_layout
from ..exact.certification import CLEARANCE
from ._common import certified_path, labeller_robot

__all__ = ["actions_from_video"]


@pose_only
def actions_from_video(model: GaussianRobot, frames: dict, cameras: Cameras, *, init: npt.ArrayLike,
                       sdf: Field | None = None, iterations_per_frame: int = 5, lr: float = 0.01,
                       first_frame_iterations: int = 50, joint_iterations: int = 50, joint_lr: float = 0.002,
                       w_tv: float = 0.001, beta: float = 10.0, l_thres: float = -0.1, density: int = 10,
                       w_depth: float = 1.0, w_mask: float = 0.5, background: npt.ArrayLike | None = None,
                       robot: Robot | None = None, batch: int = 20, layout: Layout | None = None,
                       frame: str | None = None, frame_targets: dict | None = None, w_frame: float = 100.0,
                       margin: float = CLEARANCE) -> TrajectoryResult:
    """A (T, K) joint trajectory from ``frames`` (``rgb`` (T, C, H, W, 3), ``depth`` (T, C, H, W)
    m, ``mask`` (T, C, H, W)) seen by ``cameras`` (C). ``init`` (K,): the first frame's start.
    ``batch``: frames rendered per forward pass in the joint stages (memory). Returns a
    :class:`~profrobot.TrajectoryResult` (``path`` (T, K), ``certified`` by the continuous check,
    ``method`` "video" or "video+field"). ``scene``: for a field of a family of scenes
    (:mod:`profrobot.robot.family`), the layout δ to work at; answers are certified at exactly that layout. ``margin``: metres every certified answer keeps from the obstacles (:mod:`profrobot.robot.margin`).

    End-effector terms (the paper's real-robot recipe): ``frame_targets`` ``{frame index: (4, 4)
    world transform or (3,) position}`` of ``frame`` (a site, body or geom) mark *operation*
    frames, supervised by the end-effector pose (``w_frame`` ‖·‖², torch FK, in the joint
    stages); the others are *movement* frames, steered by the field. Each operation frame is
    then the certified IK pose nearest its answer that puts the frame on its target (0.1 mm,
    1 mrad: :func:`profrobot.ik`), fixed while the segments around it are freed, and every frame
    and segment certified (``method`` gains "+frames")."""
    t0 = time.perf_counter()
    sdf, robot = field_at_layout(sdf, robot, layout)
    robot = labeller_robot(sdf, model, robot, "actions_from_video", margin=margin)
    if (frame is None) != (frame_targets is None):
        raise InputError("end-effector targets need both frame= (a site, body or geom) and frame_targets= "
                         "({frame index: target})")
    iterations_per_frame = positive("iterations_per_frame", iterations_per_frame, integer=True, allow_zero=True)
    first_frame_iterations = positive("first_frame_iterations", first_frame_iterations, integer=True, allow_zero=True)
    joint_iterations = positive("joint_iterations", joint_iterations, integer=True, allow_zero=True)
    lr, joint_lr = positive("lr", lr), positive("joint_lr", joint_lr)
    w_tv, beta, l_thres = finite("w_tv", w_tv), finite("beta", beta), finite("l_thres", l_thres)
    if not isinstance(frames, dict) or not {"rgb", "depth", "mask"} <= set(frames):
        raise InputError("frames must be a dict with 'rgb', 'depth' and 'mask'")
    T = int(np.asarray(frames["mask"]).shape[0])
    if T < 2:
        raise InputError(f"a video needs at least 2 frames; got {T}")
    dev = model.means.device
    tg = ImageTargets.from_images(frames, cameras, T, device=dev, background=background, w_depth=w_depth,
                                  w_mask=w_mask, who="actions_from_video")
    ft = None
    if frame is not None and frame_targets is not None:   # both or neither (checked above)
        from ..optim.frames import FrameTargets

        ft = FrameTargets(robot, frame, frame_targets, T, "frame_targets")
        w_frame = finite("w_frame", w_frame)
    q0 = np.asarray(init, dtype=np.float64).reshape(-1)
    if q0.shape != (model.njoint,) or not np.isfinite(q0).all():
        raise InputError(f"init must be {model.njoint} finite joint values; got shape {np.asarray(init).shape}")
    limits = Limits.of(model, like=model.means)

    img_loss = lambda theta, idx: tg.losses(model, theta, idx)   # (len(idx),) mean over the C views

    # 1. frame by frame, warm-started at constant velocity
    traj = torch.empty(T, model.njoint, device=dev)
    prev = limits.clamp_or_wrap(torch.as_tensor(q0, dtype=torch.float32, device=dev)[None])
    for t in range(T):
        guess = prev if t < 2 else limits.clamp_or_wrap(2 * traj[t - 1:t] - traj[t - 2:t - 1])
        th = torch.nn.Parameter(guess.clone())
        opt = torch.optim.Adam([th], lr=lr)
        for _ in range(first_frame_iterations if t == 0 else iterations_per_frame):
            loss = img_loss(th, [t]).sum()
            opt.zero_grad()
            loss.backward()
            opt.step()
            with torch.no_grad():
                limits.clamp_or_wrap_(th)
        traj[t] = th.detach()[0]
        prev = th.detach()

    # 2./3. all frames jointly, TV (and the field)
    def joint(iters: int, with_field: bool) -> None:
        th = torch.nn.Parameter(traj.clone())
        opt = torch.optim.Adam([th], lr=joint_lr)
        for _ in range(iters):
            opt.zero_grad()
            for s in range(0, T, batch):                          # gradients accumulate over chunks
                idx = list(range(s, min(T, s + batch)))
                loss = img_loss(th[s:s + batch], idx).sum()
                if with_field:
                    assert sdf is not None                        # with_field: a field was given
                    g = sdf(th[s:s + batch].to(sdf.joint_limits.device)).to(dev)
                    loss = loss + beta * torch.relu(g - l_thres).sum()
                if ft is not None:                                # operation frames: the end effector's pose
                    loss = loss + w_frame * ft.loss(th[s:s + batch], np.asarray(idx))
                loss.backward()
            tv = w_tv * (th[1:] - th[:-1]).abs().sum(1).mean() * T
            tv.backward()
            opt.step()
            with torch.no_grad():
                limits.clamp_or_wrap_(th)
        traj.copy_(th.detach())

    joint(joint_iterations, False)
    method, iterations = "video", (T - 1) * iterations_per_frame + first_frame_iterations + joint_iterations
    lim = Limits.of(robot)
    if sdf is not None:
        joint(joint_iterations, True)
        method, iterations = "video+field", iterations + joint_iterations
    path = unwrap_path(lim.numpy(traj.cpu().numpy().astype(np.float64)), lim.cont_np)
    anchor = np.zeros(T, dtype=bool)
    if ft is not None:                  # operation frames: on their targets exactly, certified, then fixed
        snapped, ok = ft.snap(lim.numpy(path))
        rows = ft.index[ok]
        ref = np.where(rows > 0, rows - 1, rows)
        path[rows] = path[ref] + lim.diff(snapped[rows], path[ref])
        anchor[rows] = True
        method += "+frames"
    if sdf is not None:
        from ..optim import resolve

        bad = np.flatnonzero(~certify_poses(robot, lim.numpy(path)) & ~anchor)
        if len(bad):                                              # colliding frames: resolve them
            r = resolve(sdf, lim.numpy(path[bad]), l_thres=l_thres, robot=robot)
            for i, b in enumerate(bad):
                if r.certified[i]:
                    ref = path[b - 1] if b > 0 else path[b]
                    path[b] = ref + lim.diff(r.poses[i:i + 1], ref[None])[0]
        chk = check_path(robot, lim.numpy(path), density)
        if not chk.certified:                                          # colliding segments between free frames
            free = ~chk.waypoint_uncertified | anchor
            for seg in np.flatnonzero(chk.segment_uncertified):
                a = seg
                while a > 0 and not free[a]:
                    a -= 1
                b = seg + 1
                while b < T - 1 and not free[b]:
                    b += 1
                if b - a < 2:
                    continue                                      # no interior frame to move
                sub = path[a:b + 1][None].copy()
                penalty_descent(sdf, robot, sub, PenaltyOptions(l_thres=l_thres, gamma1=1.0, gamma2=1.0, lr=0.05,
                                                                iterations=300, density=density, midpoints=True))
                path[a:b + 1] = sub[0]
    return certified_path(robot, sdf, path, density, method, iterations, t0)
