"""A trajectory from images (paper §5, Table 8): from a start pose, optimise one pose against the
end pose's multi-view images; every iterate is a frame. With the field, the penalty joins the
loss, the frames are post-processed on the field (mean ReLU(g − l_thres) + TV, end points
attached), and the result is certified by the exact labeller at every frame and, continuously,
on every segment (every pose of it proven free); a path that still collides is replaced by a certified one
between the same end points (exact planner, then the field's smoothing), never returned as safe.
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
from ..robot.gate import Layout, finite, positive, poses_within_limits
from ..exact.certification import certify_poses, check_path
from ..optim.paths import PenaltyOptions, penalty_descent, unwrap_path
from ..optim.trajectory import TrajectoryResult, plan_trajectory
from ..render.targets import ImageTargets
from ..render.gaussians import GaussianRobot, pose_only
from ..robot.robot import Robot
from ..field.layout import field_at_layout
from ..exact.certification import CLEARANCE
from ._common import certified_path, labeller_robot

__all__ = ["trajectory_from_images"]


@pose_only
def trajectory_from_images(model: GaussianRobot, targets: dict, cameras: Cameras, *, start: npt.ArrayLike | None = None,
                           goal: npt.ArrayLike | None = None, sdf: Field | None = None, steps: int = 100,
                           lr: float = 0.05, w_pull: float = 10.0, beta: float = 5.0, l_thres: float = -0.1,
                           smooth_iterations: int = 1000, smooth_lr: float = 0.1, density: int = 10,
                           w_depth: float = 1.0, w_mask: float = 0.5, background: npt.ArrayLike | None = None,
                           robot: Robot | None = None, layout: Layout | None = None, frame: str | None = None,
                           frame_targets: dict | None = None, margin: float = CLEARANCE) -> TrajectoryResult:
    """A ``steps``-frame trajectory from ``start`` (K,) towards the pose seen in ``targets`` (one
    pose: ``rgb`` (C, H, W, 3), ``depth`` (C, H, W) m, ``mask`` (C, H, W), from ``cameras``).

    Loss per step: the image loss (:func:`profrobot.render.pose_loss`, mean over views) +
    ``w_pull`` |θ − goal|₁ when ``goal`` (K,) is given (the paper's pull to θ_end) + with ``sdf``
    ``beta`` ReLU(g − l_thres). Adam (``lr``), ``steps − 1`` steps; the iterates are the frames.
    With ``sdf``: a final frame the labeller finds colliding is first resolved
    (:func:`profrobot.resolve`), then the interior frames are optimised on mean ReLU(g − l_thres)
    + mean ‖Δθ‖ (Adam ``smooth_lr``, at most ``smooth_iterations`` steps, stopping once the dense
    check passes); a path still colliding is replaced by :func:`profrobot.plan_trajectory` with
    the planner between the same ends. ``robot``: the labeller's scene (default: the field's;
    required without a field). Returns a :class:`~profrobot.TrajectoryResult` whose ``method``
    says which of these produced the path. ``scene``: for a field of a family of scenes
    (:mod:`profrobot.robot.family`), the layout δ to work at; answers are certified at exactly that layout. ``margin``: metres every certified answer keeps from the obstacles (:mod:`profrobot.robot.margin`).

    End-effector terms: ``frame_targets`` ``{frame index: (4, 4) world transform or (3,)
    position}`` of ``frame`` (a site, body or geom): each such frame becomes the certified IK
    pose nearest it that puts the frame on its target (0.1 mm, 1 mrad), and a stretch between
    two fixed frames that is then not certified is re-planned (:func:`profrobot.plan_trajectory`,
    the planner between them); ``method`` gains "+frames".
    """
    t0 = time.perf_counter()
    if start is None:
        raise InputError("trajectory_from_images needs start= (K,), the first frame's pose")
    sdf, robot = field_at_layout(sdf, robot, layout)
    robot = labeller_robot(sdf, model, robot, "trajectory_from_images", margin=margin)
    steps = positive("steps", steps, integer=True)
    if steps < 3:
        raise InputError(f"steps must be >= 3; got {steps}")
    lr, smooth_lr = positive("lr", lr), positive("smooth_lr", smooth_lr)
    w_pull, beta, l_thres = finite("w_pull", w_pull), finite("beta", beta), finite("l_thres", l_thres)
    smooth_iterations = positive("smooth_iterations", smooth_iterations, integer=True, allow_zero=True)
    s = poses_within_limits(robot, np.asarray(start, dtype=np.float64).reshape(1, -1), "start")
    if s.shape[1] != model.njoint:
        raise InputError(f"start must have {model.njoint} joints; got {s.shape[1]}")
    gl = None if goal is None else poses_within_limits(robot, np.asarray(goal, dtype=np.float64).reshape(1, -1), "goal")
    dev = model.means.device
    tg = ImageTargets.from_images(targets, cameras, 1, device=dev, background=background, w_depth=w_depth,
                                  w_mask=w_mask, who="trajectory_from_images")

    limits = Limits.of(model, like=model.means)
    theta = torch.nn.Parameter(torch.as_tensor(s, dtype=torch.float32, device=dev).clone())
    opt = torch.optim.Adam([theta], lr=lr)
    goal_t = None if gl is None else torch.as_tensor(gl, dtype=torch.float32, device=dev)
    sdf_dev = None if sdf is None else sdf.joint_limits.device
    frames = [s[0].copy()]
    for _ in range(steps - 1):
        loss = tg.losses(model, theta).sum()                 # the mean over the C views
        if goal_t is not None:
            loss = loss + w_pull * (theta - goal_t).abs().sum()
        if sdf is not None:
            loss = loss + beta * torch.relu(sdf(theta.to(sdf_dev)) - l_thres).sum().to(dev)
        opt.zero_grad()
        loss.backward()
        opt.step()
        with torch.no_grad():
            limits.clamp_or_wrap_(theta)
        frames.append(theta.detach().cpu().numpy()[0].astype(np.float64))
    lim = Limits.of(robot)
    path = unwrap_path(lim.numpy(np.stack(frames)), lim.cont_np)
    method, iterations = "images", steps - 1

    if sdf is not None:
        from ..optim import resolve

        if not certify_poses(robot, path[-1:])[0]:       # the last iterate collides: free it first
            r = resolve(sdf, lim.numpy(path[-1:]), l_thres=l_thres, robot=robot)
            if r.certified[0]:
                path[-1] = path[-2] + lim.diff(r.poses, path[-2:-1])[0]
        if not check_path(robot, lim.numpy(path), density).certified and smooth_iterations > 0:
            paths = path[None].copy()
            n = penalty_descent(sdf, robot, paths, PenaltyOptions(
                l_thres=l_thres, gamma1=1.0, gamma2=1.0, lr=smooth_lr, iterations=smooth_iterations, density=density,
                midpoints=True))
            path, iterations, method = paths[0], iterations + int(n[0]), "images+field"
        if not check_path(robot, lim.numpy(path), density).certified and certify_poses(robot, lim.numpy(path[[0, -1]])).all():
            plan = plan_trajectory(sdf, lim.numpy(path[0]), lim.numpy(path[-1]), steps, robot=robot, init="planner",
                                   density=density)
            if plan.certified:
                path, method = unwrap_path(plan.path, lim.cont_np), "images+planner"
    if frame_targets is not None or frame is not None:
        path = _through_frames(sdf, robot, path, frame, frame_targets, lim, density)
        method += "+frames"
    return certified_path(robot, sdf, path, density, method, iterations, t0)


def _through_frames(sdf, robot: Robot, path: np.ndarray, frame, frame_targets, lim, density: int) -> np.ndarray:
    """``path`` (S, K, continuous joints unwrapped) with its target frames on their IK poses and
    the stretches around them re-planned where they are not certified."""
    from ..optim.frames import FrameTargets

    if frame is None or frame_targets is None:
        raise InputError("end-effector targets need both frame= (a site, body or geom) and frame_targets= "
                         "({frame index: target})")
    S = len(path)
    ft = FrameTargets(robot, frame, frame_targets, S, "frame_targets")
    snapped, ok = ft.snap(lim.numpy(path))
    rows = ft.index[ok]
    ref = np.where(rows > 0, rows - 1, rows)
    path = path.copy()
    path[rows] = path[ref] + lim.diff(snapped[rows], path[ref])
    anchors = sorted({0, S - 1, *rows.tolist()})
    for a, b in zip(anchors[:-1], anchors[1:]):
        seg = lim.numpy(path[a:b + 1])
        if b - a < 2 or check_path(robot, seg, density).certified or not certify_poses(robot, seg[[0, -1]]).all():
            continue
        sub = plan_trajectory(sdf, seg[0], seg[-1], b - a + 1, robot=robot, init="planner", density=density)
        if sub.certified:
            new = unwrap_path(sub.path, lim.cont_np)
            path[a:b + 1] = new + (path[a] - new[0])         # continuous joints: on from path[a]'s turn
    return path
