"""Poses from images that do not collide (paper §5, Table 7): the differentiable Gaussian robot's
image loss, the pose collision field's penalty, and the exact labeller's certificate.

For B targets seen by C cameras:

1. **image phase** (Dr. Robot, the baseline): :func:`profrobot.render.fit_pose` from ``init`` on
   ``L_img = L_RGB + w_depth L_D + w_mask L_mask`` (masked, see :func:`profrobot.render.pose_loss`);
2. **field phase** (``sdf`` given; the paper's "ours"): from the image-phase result, Adam on
   ``L_img + beta ReLU(g(theta) - l_thres)``, each pose stopping as soon as ``g <= l_thres``
   (the paper's rule), at most ``field_iterations`` steps;
3. **certify and continue**: every returned pose is labelled by the exact labeller (against the
   field's scene: robot *and* obstacles, which the images do not show); a pose that still
   collides goes on with its threshold lowered by ``refine_step``, for up to ``refine_rounds``
   rounds, as :func:`profrobot.resolve` does; poses still colliding then go to
   :func:`profrobot.resolve` itself (the field alone, from the deepest threshold reached: the
   image term no longer pulls them back towards the unseen obstacle). Poses left colliding are
   reported in ``result.failures``, never hidden.

``sdf=None`` is the baseline: the image phase only, certified against ``robot=`` but not corrected
(without ``robot=`` nothing is checked: ``certified`` is None).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import torch

from ..errors import InputError
from ..kinematics.limits import Limits
from ..optim.adam import BatchedAdam
from ..optim.resolution import certify_and_continue
from ..field.identity import Field
from ..robot.gate import Layout, finite, positive
from ..robot.robot import Robot
from ..exact.certification import certified_summary, certify_poses, failures_of
from ..render.pose import fit_pose
from ..render.gaussians import GaussianRobot, pose_only
from ..render.cameras import Cameras
from ..render.targets import ImageTargets, as_pinhole_targets
from ..exact.certification import CLEARANCE
from ._common import check_field_matches_model, labeller_robot
from ..field.layout import field_at_layout

__all__ = ["InverseResult", "pose_from_images", "check_field_matches_model"]


@dataclass
class InverseResult:
    """Outcome of :func:`pose_from_images` for B targets.

    Attributes:
        poses: (B, K) float64 returned poses (radians / metres, within the joint limits).
        image_loss: (B,) the image loss at the returned poses (mean over the C views).
        certified: (B,) bool, the returned pose is certified free (:mod:`profrobot.exact.certification`,
            against the field's scene; the baseline is certified too, not corrected), or None
            when there was no scene to check against (no field and no ``robot=``): never True
            for a pose that was not checked.
        iterations: (B,) int, field-phase Adam steps (0 for the baseline, or a pose the field
            already called free).
        image_iterations: image-phase steps (all poses).
        g: (B,) the field at the returned poses (NaN without a field).
        threshold: (B,) the last threshold each pose was driven to.
        field_free_before_certify: (B,) bool, g <= l_thres when the field phase first stopped
            (the paper's criterion; the certificate is the labeller's).
        certified_before_continue: (B,) bool, the verdict before certify-and-continue (None when
            not checked).
        poses_before_continue: (B, K) the poses it was given (the paper's answers).
        seconds: wall time.
        cameras: the refined :class:`~profrobot.render.Cameras` with ``refine_cameras``, else None.
    """

    poses: np.ndarray
    image_loss: np.ndarray
    certified: np.ndarray | None
    iterations: np.ndarray
    image_iterations: int
    g: np.ndarray
    threshold: np.ndarray
    field_free_before_certify: np.ndarray
    certified_before_continue: np.ndarray | None
    seconds: float
    rounds: int = 0
    poses_before_continue: np.ndarray | None = None
    history: list = field(default_factory=list, repr=False)
    cameras: Cameras | None = None

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def failures(self) -> np.ndarray | None:
        """Indices of returned poses that are not certified free (None when not checked)."""
        return failures_of(self.certified)

    def summary(self) -> str:
        n = len(self)
        before = ("" if self.certified_before_continue is None else
                  f", {self.certified_before_continue.mean():.1%} before certify-and-continue")
        return (f"{n} poses: {certified_summary(self.certified)}{before}; mean image loss "
                f"{self.image_loss.mean():.4f}; mean field steps {self.iterations.mean():.1f}; {self.seconds:.1f} s "
                f"({self.rounds} refinement round{'s' * (self.rounds != 1)})")


@pose_only
def pose_from_images(model: GaussianRobot, targets: dict, cameras: Cameras, *, init: npt.ArrayLike,
                     sdf: Field | None = None, beta: float = 10.0, l_thres: float = -0.1, image_iterations: int = 100,
                     lr: float = 0.02, field_iterations: int = 300, field_lr: float = 0.005, refine_rounds: int = 4,
                     refine_step: float = 0.05, w_depth: float = 1.0, w_mask: float = 0.5,
                     background: npt.ArrayLike | None = None, coarse: dict | None = None, robot: Robot | None = None,
                     seed: int = 0, refine_cameras: bool | dict = False, progress: bool = False,
                     layout: Layout | None = None, margin: float = CLEARANCE) -> InverseResult:
    """Joint angles from multi-view images whose answers do not collide (module docs).

    ``model``: a :class:`~profrobot.render.GaussianRobot`; ``targets``: dict of ``rgb``
    (B, C, H, W, 3) uint8 or [0, 1], ``depth`` (B, C, H, W) metres, ``mask`` (B, C, H, W) bool;
    ``cameras``: the C :class:`~profrobot.render.Cameras`; ``init`` (B, K) starts. ``sdf``: a
    PoseSDF for the same arm (its scene's obstacles are what must not be hit), or None for the
    Dr. Robot baseline. ``beta``, ``l_thres``: the penalty ``beta ReLU(g - l_thres)``;
    ``image_iterations``/``lr``/``coarse``: the image phase (:func:`~profrobot.render.fit_pose`);
    ``field_iterations``/``field_lr``: the field phase (Adam in joint space); ``refine_rounds``,
    ``refine_step``: certify-and-continue. ``robot``: the labeller's scene (default: the field's).
    Without a field and without ``robot`` nothing can be checked: ``result.certified`` is None and
    ``summary()`` says "not checked". ``refine_cameras``: refine the cameras' poses with the image
    phase (:func:`~profrobot.render.fit_pose`); the field phase then uses the refined cameras,
    returned as ``result.cameras``. ``progress``: progress bars for the image phase. ``scene``: for a field of a family of scenes
    (:mod:`profrobot.robot.family`), the layout δ to work at; answers are certified at exactly that layout. ``margin``: metres every certified answer keeps from the obstacles (:mod:`profrobot.robot.margin`).
    """
    t0 = time.perf_counter()
    beta, l_thres = finite("beta", beta), finite("l_thres", l_thres)
    image_iterations = positive("image_iterations", image_iterations, integer=True, allow_zero=True)
    field_iterations = positive("field_iterations", field_iterations, integer=True, allow_zero=True)
    refine_rounds = positive("refine_rounds", refine_rounds, integer=True, allow_zero=True)
    refine_step = positive("refine_step", refine_step)
    field_lr = positive("field_lr", field_lr)
    sdf, robot = field_at_layout(sdf, robot, layout)
    robot = labeller_robot(sdf, model, robot, "pose_from_images", required=False, margin=margin)
    init = np.asarray(init, dtype=np.float64)
    if init.ndim == 1:
        init = init[None]
    if init.ndim != 2 or init.shape[1] != model.njoint:
        raise InputError(f"init must have shape (B, {model.njoint}); got {init.shape}")
    B = init.shape[0]
    dev = model.means.device
    given = cameras
    targets, cameras = as_pinhole_targets(targets, cameras, B, "pose_from_images")   # undistorted, resized: once

    # 1. image phase (restarts, coarse-to-fine and camera refinement as fit_pose)
    fit = fit_pose(model, targets, cameras, init, iterations=image_iterations, lr=lr, w_depth=w_depth, w_mask=w_mask,
                   background=background, coarse=coarse, seed=seed, refine_cameras=refine_cameras, progress=progress)
    theta_img = fit.poses
    refined = None
    if fit.cameras is not None:     # the field phase sees the images through the refined cameras
        assert fit.camera_motion is not None                      # refined cameras come with their motion
        cameras, refined = fit.cameras, given.moved(fit.camera_motion)
    tg = ImageTargets.from_images(targets, cameras, B, device=dev, background=background, w_depth=w_depth,
                                  w_mask=w_mask, who="pose_from_images")
    img_loss = lambda theta, rows: tg.losses(model, theta, rows)     # (len(rows),) weighted mean over the C views

    limits = Limits.of(model, like=model.means)
    theta = torch.as_tensor(theta_img, dtype=torch.float32, device=dev).clone()
    steps_taken = np.zeros(B, dtype=np.int64)
    g = torch.full((B,), float("nan"))
    thresholds = np.full(B, l_thres)
    history: list = []
    rounds = 0

    if sdf is None:
        field_free = np.zeros(B, dtype=bool)
    else:
        sdf_dev = sdf.joint_limits.device
        gfield = lambda th: sdf(th.to(sdf_dev, torch.float32)).to(dev)
        opt = BatchedAdam((B, model.njoint), field_lr, theta)

        def field_phase(rows: np.ndarray, budget: int) -> None:
            """Adam on L_img + beta ReLU(g - thr) for ``rows``, each stopping once g <= its threshold."""
            active = torch.as_tensor(rows, device=dev)
            thr = torch.as_tensor(thresholds, dtype=torch.float32, device=dev)
            for _ in range(budget + 1):
                with torch.no_grad():
                    g[active.cpu()] = gfield(theta[active]).cpu()
                    keep = g[active.cpu()].to(dev) > thr[active]
                active = active[keep]
                if len(active) == 0 or _ == budget:
                    break
                th = theta[active].detach().requires_grad_(True)
                loss = img_loss(th, active) + beta * torch.relu(gfield(th) - thr[active])
                (grad,) = torch.autograd.grad(loss.sum(), th)
                opt.step(theta, active, grad)
                limits.clamp_or_wrap_(theta)
                steps_taken[active.cpu().numpy()] += 1

        field_phase(np.arange(B), field_iterations)
        field_free = (g.numpy() <= thresholds)

    poses = limits.numpy(theta.detach().cpu().numpy().astype(np.float64))
    poses_before = poses.copy()
    if robot is None:  # the baseline with no scene: nothing was checked, so nothing is certified
        certified = before = None
        history.append(dict(round=0, certified=None))
    else:
        certified = certify_poses(robot, poses)
        before = certified.copy()
        history.append(dict(round=0, certified=int(certified.sum())))
    if sdf is not None:
        assert robot is not None and certified is not None   # a field brings its robot (labeller_robot)

        def again(bad: np.ndarray, threshold: float) -> np.ndarray:
            thresholds[bad] = threshold
            opt.reset(torch.as_tensor(bad, device=dev))
            field_phase(bad, field_iterations)
            poses[bad] = limits.numpy(theta[torch.as_tensor(bad, device=dev)].detach().cpu().numpy().astype(np.float64))
            return poses[bad]

        rounds = certify_and_continue(robot, certified, again, l_thres=l_thres, step=refine_step,
                                      rounds=refine_rounds, history=history)
        if not certified.all():
            # last resort: the field alone (no image term pulling back into the obstacle), with
            # resolve's own certify-and-continue from the deepest threshold reached
            from ..optim import resolve

            bad = np.flatnonzero(~certified)
            r = resolve(sdf, poses[bad], l_thres=float(thresholds[bad].min()), robot=robot, refine_step=refine_step)
            poses[bad] = np.where(r.certified[:, None], r.poses, poses[bad])
            certified[bad] = r.certified
            history.append(dict(round="resolve", certified=int(certified.sum())))
    with torch.no_grad():
        final = img_loss(torch.as_tensor(poses, dtype=torch.float32, device=dev), torch.arange(B, device=dev))
    return InverseResult(poses=poses, image_loss=final.cpu().numpy().astype(np.float64), certified=certified,
                         iterations=steps_taken, image_iterations=image_iterations, g=g.numpy().astype(np.float64),
                         threshold=thresholds, field_free_before_certify=field_free,
                         certified_before_continue=before, seconds=time.perf_counter() - t0, rounds=rounds,
                         history=history, poses_before_continue=poses_before, cameras=refined)
