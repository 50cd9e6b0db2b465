"""Joint angles from images: gradient descent on the Gaussian robot's render (paper §4.3).

For B targets, each seen by the same C cameras, with target images ``I*`` (C, H, W, 3) in [0, 1],
depths ``D*`` (metres) and robot masks ``M*``:

    L(theta) = mean_{M*} |I(theta) - I*|^2                (L_RGB on the target's robot mask)
             + w_depth * mean_{M* & alpha > 1/2} |D(theta) - D*|   (L_D, metres; without depth, none)
             + w_mask  * mean |alpha(theta) - M*|          (silhouette)
             + extra(theta)                               (e.g. beta * L_SDF, the collision penalty)

(:mod:`profrobot.render.targets`: pixels outside the mask, a photo's background, never pull).
Adam on joints normalised to [-1, 1] over their
limits (Dr. Robot: lr 0.02), projected back into joint space after each step (limited joints
clamped, continuous hinges wrapped: :class:`profrobot.kinematics.limits.Limits`), learning rate decayed
ten-fold (cosine); restarts perturb the start and keep the best final loss. Inputs are
validated once, at entry: the loop itself makes no host syncs.

Camera refinement (``refine_cameras``): calibrations are never perfect, so a last stage moves
each camera by a small rigid motion in its own frame, ``world_to_cam <- [exp([w]x) | tau] @
world_to_cam`` (``w`` (C, 3) radians, ``tau`` (C, 3) metres, shared by all targets), jointly with
the targets' poses: Adam on (u, w, tau), each with its own rate, decayed as above. What images
pin down is where each camera puts the robot (its reprojection); a rotation about the robot's
centre with the matching translation changes little of that at low resolution, so the refined
pose of a camera can stay off by a fraction of a degree while the robot's poses are right.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from ..kinematics.limits import Limits
from .gaussians import GaussianRobot, pose_only
from .targets import ImageTargets, as_pinhole_targets, pose_loss
from .cameras import Cameras
from ..errors import InputError
from ..executors.progress import progress_bar
from ..robot.gate import positive

__all__ = ["fit_pose", "PoseFit", "pose_loss", "downsample_targets", "ImageTargets", "rigid_motions"]


@dataclass
class PoseFit:
    """``poses`` (B, K) the fitted poses, ``loss`` (B,) their final image loss, ``history``
    (iterations, B) the loss of the kept start per step, ``start`` (B, K) the start that was kept.
    With ``refine_cameras``: ``cameras`` the refined cameras (the given ones, moved) and
    ``camera_motion`` (C, 4, 4) the rigid motion applied to each, in its own frame; ``iterations``
    then counts the refinement's steps too, ``history`` only the stages before it."""

    poses: np.ndarray
    loss: np.ndarray
    history: np.ndarray
    start: np.ndarray
    all_losses: np.ndarray | None = field(default=None)
    iterations: int = 0
    cameras: Cameras | None = None
    camera_motion: np.ndarray | None = None


def downsample_targets(targets: dict, factor: int) -> dict:
    """Targets (``rgb`` (B, C, H, W, 3) uint8 or [0, 1], ``depth`` (B, C, H, W) m, ``mask``
    (B, C, H, W) bool; other keys, e.g. ``weights``, kept) at 1/``factor`` resolution: RGB
    averaged over ``factor`` x ``factor`` blocks, the mask where at least half of a block is
    robot, the depth averaged over the block's robot pixels (0 elsewhere). A block's centre is
    where the downsampled camera (:meth:`Cameras.resized`) puts its pixel centre."""
    rgb = np.asarray(targets["rgb"])
    rgb = rgb.astype(np.float32) / 255.0 if rgb.dtype == np.uint8 else rgb.astype(np.float32)
    depth = np.asarray(targets["depth"], dtype=np.float32)
    mask = np.asarray(targets["mask"]).astype(np.float32)
    H, W = mask.shape[-2:]
    if factor < 1 or H % factor or W % factor:
        raise InputError(f"downsample_targets: the image size {W}x{H} is not divisible by factor {factor}")
    blocks = lambda a: a.reshape(*a.shape[:-2], H // factor, factor, W // factor, factor).sum((-3, -1))
    n = float(factor * factor)
    m = blocks(mask)
    rgb_d = np.moveaxis(blocks(np.moveaxis(rgb, -1, -3)), -3, -1) / n
    depth_d = np.where(m > 0, blocks(depth * mask) / np.maximum(m, 1.0), 0.0).astype(np.float32)
    rest = {k: v for k, v in targets.items() if k not in ("rgb", "depth", "mask", "valid")}
    if targets.get("valid") is not None:      # (C, H, W): a block is seen where at least half of it is
        rest["valid"] = blocks(np.asarray(targets["valid"]).astype(np.float32)) >= n / 2
    return dict(rgb=rgb_d.astype(np.float32), depth=depth_d, mask=m >= n / 2, **rest)


_REFINE_DEFAULTS = dict(iterations=100, lr=0.005, lr_rotation=0.002, lr_translation=0.002)


def _refine_options(refine_cameras) -> dict | None:
    if refine_cameras is False or refine_cameras is None:
        return None
    if refine_cameras is True:
        return dict(_REFINE_DEFAULTS)
    if not isinstance(refine_cameras, dict):
        raise InputError(f"fit_pose: refine_cameras must be True, False or a dict of {sorted(_REFINE_DEFAULTS)}; "
                         f"got {type(refine_cameras).__name__}")
    unknown = set(refine_cameras) - set(_REFINE_DEFAULTS)
    if unknown:
        raise InputError(f"fit_pose: unknown refine_cameras options {sorted(unknown)} (known: {sorted(_REFINE_DEFAULTS)})")
    opts = _REFINE_DEFAULTS | refine_cameras
    opts["iterations"] = positive("refine_cameras['iterations']", opts["iterations"], integer=True)
    for k in ("lr", "lr_rotation", "lr_translation"):
        opts[k] = positive(f"refine_cameras[{k!r}]", opts[k])
    return opts


def _check_init(model, init, who: str) -> torch.Tensor:
    init = torch.as_tensor(np.asarray(init, dtype=np.float64), dtype=torch.float32)
    if init.ndim == 1:
        init = init[None]
    K = model.njoint
    if init.ndim != 2 or init.shape[1] != K:
        raise InputError(f"{who}: init must have shape (B, {K}); got {tuple(init.shape)}")
    if not torch.isfinite(init).all():
        raise InputError(f"{who}: init contains NaN or inf")
    return init


def _cosine(lr: float, it: int, iterations: int) -> float:
    """``lr`` decayed ten-fold over ``iterations`` (cosine)."""
    return lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * it / max(iterations, 1))))


def rigid_motions(w: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """(C, 4, 4) rigid motions ``[exp([w]x) | tau]`` of camera frames from rotation vectors ``w``
    (C, 3) radians and translations ``tau`` (C, 3) metres; differentiable
    (``torch.linalg.matrix_exp``)."""
    C = w.shape[0]
    z = torch.zeros(C, dtype=w.dtype, device=w.device)
    wx = torch.stack([z, -w[:, 2], w[:, 1], w[:, 2], z, -w[:, 0], -w[:, 1], w[:, 0], z], -1).reshape(C, 3, 3)
    top = torch.cat([torch.linalg.matrix_exp(wx), tau[:, :, None]], 2)
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=w.dtype, device=w.device).expand(C, 1, 4)
    return torch.cat([top, bottom], 1)


def _refine(model, tg: ImageTargets, theta0: torch.Tensor, opts: dict, extra_loss,
            progress: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Poses ``theta0`` (B, K) and the C cameras' rigid motions refined jointly (module docs) →
    (poses (B, K), motions (C, 4, 4))."""
    dev = model.means.device
    limits = Limits.of(model, like=model.means)
    C = tg.cameras
    u = torch.nn.Parameter(limits.normalise(theta0.to(dev)))
    w = torch.nn.Parameter(torch.zeros(C, 3, device=dev))
    tau = torch.nn.Parameter(torch.zeros(C, 3, device=dev))
    rates = (opts["lr"], opts["lr_rotation"], opts["lr_translation"])
    opt = torch.optim.Adam([dict(params=[u], lr=rates[0]), dict(params=[w], lr=rates[1]),
                            dict(params=[tau], lr=rates[2])], eps=1e-8)
    n = opts["iterations"]
    for it in progress_bar(iterable=range(n), desc="fit pose + cameras", unit="step", progress=progress, leave=False):
        for group, lr in zip(opt.param_groups, rates):
            group["lr"] = _cosine(lr, it, n)
        theta = limits.denormalise(u)
        total = tg.losses(model, theta, viewmats=rigid_motions(w, tau) @ tg.viewmats).sum()
        if extra_loss is not None:
            total = total + extra_loss(theta)
        opt.zero_grad()
        total.backward()
        opt.step()
        limits.clamp_or_wrap_normalised_(u)
    with torch.no_grad():
        return limits.denormalise(u), rigid_motions(w, tau)


def _coarse_to_fine(model, targets, cameras, init, coarse, **fine) -> PoseFit:
    coarse = dict(coarse)
    factor = int(coarse.pop("factor", 2))
    H, W = cameras.height, cameras.width
    fine_targets, fine_cameras = targets, cameras
    if factor < 1 or factor > min(H, W):
        raise InputError(f"fit_pose: coarse factor {factor} must be in [1, {min(H, W)}] for {W}x{H} images")
    if H % factor or W % factor:
        # the coarse stage drops the last rows / columns that do not fill a block: cutting the far
        # edges leaves K as it is, the fine stage sees every pixel
        Hc, Wc = H - H % factor, W - W % factor
        targets = {k: (v[..., :Hc, :Wc, :] if k == "rgb" else v[..., :Hc, :Wc]) if k in ("rgb", "depth", "mask", "valid") else v
                   for k, v in targets.items()}
        cameras_c = Cameras.from_opencv(cameras.K, cameras.world_to_cam, Wc, Hc)
    else:
        cameras_c = cameras
        Hc, Wc = H, W
    known = ("iterations", "lr", "restarts", "restart_sigma", "w_depth", "w_mask")
    unknown = set(coarse) - set(known)
    if unknown:
        raise InputError(f"fit_pose: unknown coarse-stage options {sorted(unknown)} in coarse=; "
                         f"known: factor, {', '.join(known)}")
    kw = {k: fine[k] for k in ("lr", "w_depth", "w_mask", "extra_loss", "background", "seed", "progress")} | coarse
    c = _fit(model, downsample_targets(targets, factor), cameras_c.resized(Wc // factor, Hc // factor), init, **kw)
    f = _fit(model, fine_targets, fine_cameras, torch.as_tensor(c.poses, dtype=torch.float32), **fine)
    return PoseFit(poses=f.poses, loss=f.loss, iterations=c.iterations + f.iterations, history=np.concatenate([c.history, f.history]), start=c.start,
                   all_losses=c.all_losses)


@pose_only
def fit_pose(model: GaussianRobot, targets: dict, cameras: Cameras, init: npt.ArrayLike, *, iterations: int = 100,
             lr: float = 0.02, restarts: int = 0, restart_sigma: float = 0.3, w_depth: float = 1.0, w_mask: float = 0.5,
             extra_loss: Callable[[torch.Tensor], torch.Tensor] | None = None, background: npt.ArrayLike | None = None,
             seed: int = 0, coarse: dict | None = None, refine_cameras: bool | dict = False,
             progress: bool = False) -> PoseFit:
    """Recover joint angles from multi-view images.

    ``targets``: dict with ``rgb`` (B, C, H, W, 3) uint8 or [0, 1] floats, and ``mask``
    (B, C, H, W) bool and/or ``depth`` (B, C, H, W) metres (0 off the robot), optionally
    ``weights`` (C,) or (B, C) per view (B may be left out for one target), e.g. from
    :func:`profrobot.render.make_views` or photos with a segmenter's masks
    (:func:`profrobot.render.targets.as_pinhole_targets`: any resolution, lens distortion
    undistorted once). ``cameras``: the C cameras. ``init`` (B, K) or (K,)
    starting poses. ``restarts``: extra starts per target, perturbed by ``restart_sigma`` (radians,
    per joint, clipped to the limits); all starts run as one batch. ``extra_loss``: a callable
    of theta (B*R, K) returning a scalar added to the summed loss (the collision penalty's hook).

    ``coarse``: coarse-to-fine. A dict of keyword arguments for a first stage run on the
    targets and cameras downsampled by ``factor`` (default 2: 128^2 -> 64^2; RGB averaged over
    2x2 blocks, the mask kept where at least half the block is robot, depth averaged over the
    block's robot pixels), e.g. ``dict(iterations=45, lr=0.02, restarts=3)``; the restarts are
    chosen there (a coarse render is ~4x cheaper), and the full-resolution stage starts from
    the best coarse pose with this call's ``iterations``, ``lr`` and weights (``restarts`` given
    here are used in the coarse stage unless ``coarse`` names its own). ``history`` then holds
    both stages.

    ``refine_cameras``: True, or a dict of ``iterations`` (100), ``lr`` (0.005, normalised
    joints), ``lr_rotation`` (0.002 rad) and ``lr_translation`` (0.002 m): a last stage that
    refines every camera's pose (shared across the targets) jointly with the poses (module
    docs); the result's ``cameras`` are the refined ones. Use several targets: one pose seen
    by few cameras leaves a camera's motion and the robot's poorly separated.

    ``progress``: a progress bar per stage (off by default: this is often an inner loop).

    Settings: the defaults (lr 0.02, 100 iterations, depth weight 1) are the paper's and suit
    targets with or without depth. For targets with depth, ``iterations=50, lr=0.04,
    w_depth=5.0`` in one stage (no ``coarse``) measured better and twice as fast on the Panda
    from 4 views at 128^2 (median joint error 0.0054 rad, 0.93 s per target on two cores;
    ``benches/render_results.md``); without depth that rate is too high (0.023 rad against
    0.0093 with the defaults).
    """
    init = _check_init(model, init, "fit_pose")
    refine = _refine_options(refine_cameras)
    given = cameras
    targets, cameras = as_pinhole_targets(targets, cameras, init.shape[0], "fit_pose")
    kw: dict[str, Any] = dict(iterations=iterations, lr=lr, restarts=restarts, restart_sigma=restart_sigma,
                              w_depth=w_depth, w_mask=w_mask, extra_loss=extra_loss, background=background, seed=seed,
                              progress=progress)
    if coarse is not None:
        # the restarts are chosen in the cheap coarse stage; the fine stage starts from its best
        coarse = {"restarts": restarts, "restart_sigma": restart_sigma} | dict(coarse)
        kw["restarts"] = 0
        fit = _coarse_to_fine(model, targets, cameras, init, coarse, **kw)
    else:
        fit = _fit(model, targets, cameras, init, **kw)
    if refine is None:
        return fit
    tg = ImageTargets.from_images(targets, cameras, init.shape[0], device=model.means.device, background=background,
                                  w_depth=w_depth, w_mask=w_mask, who="fit_pose")
    theta, motion_t = _refine(model, tg, torch.as_tensor(fit.poses, dtype=torch.float32), refine, extra_loss, progress)
    if not bool(torch.isfinite(theta).all()) or not bool(torch.isfinite(motion_t).all()):
        raise FloatingPointError("fit_pose: the camera refinement diverged; lower its rates (refine_cameras=dict(...))")
    motion = motion_t.cpu().double().numpy()
    refined = given.moved(motion)
    with torch.no_grad():
        loss = tg.losses(model, theta, viewmats=torch.as_tensor(motion, dtype=torch.float32,
                                                                 device=tg.viewmats.device) @ tg.viewmats)
    limits = Limits.of(model)
    return PoseFit(poses=limits.numpy(theta.cpu().numpy()), loss=loss.cpu().numpy(), history=fit.history, start=fit.start,
                   all_losses=fit.all_losses, iterations=fit.iterations + refine["iterations"], cameras=refined,
                   camera_motion=motion)


def _fit(model: GaussianRobot, targets: dict, cameras: Cameras, init: torch.Tensor, *, iterations: int, lr: float,
         restarts: int = 0, restart_sigma: float = 0.3, w_depth: float, w_mask: float, extra_loss, background,
         seed: int, progress: bool = False) -> PoseFit:
    """One stage of :func:`fit_pose` on pinhole targets (:func:`as_pinhole_targets`)."""
    dev = model.means.device
    K = model.njoint
    B = init.shape[0]
    tg = ImageTargets.from_images(targets, cameras, B, device=dev, background=background, w_depth=w_depth,
                                  w_mask=w_mask, who="fit_pose")
    # everything the loop renders from is checked here, once (the loop then makes no host syncs)
    for name, p in model.named_parameters():
        if not torch.isfinite(p).all():
            raise InputError(f"fit_pose: model.{name} contains NaN or inf")

    limits = Limits.of(model)                                          # CPU, float32
    R = restarts + 1
    gen = torch.Generator().manual_seed(seed)
    starts = init[:, None].repeat(1, R, 1)
    if restarts:
        starts[:, 1:] += restart_sigma * torch.randn(B, restarts, K, generator=gen)
    starts = limits.clamp_or_wrap(starts).reshape(B * R, K)
    # the optimisation lives on the model's device (CPU, or a GPU after model.to("cuda"))
    limits = Limits.of(model, like=model.means)
    u = torch.nn.Parameter(limits.normalise(starts.to(dev)))          # normalised joints in [-1, 1]
    opt = torch.optim.Adam([u], lr=lr, eps=1e-8)
    tr = tg.take(torch.arange(B, device=dev).repeat_interleave(R))  # (B·R) targets: one per start
    hist = []
    bar = progress_bar(iterable=range(iterations), desc=f"fit pose {cameras.width}x{cameras.height}", unit="step",
                       progress=progress, leave=False)
    for it in bar:
        opt.param_groups[0]["lr"] = _cosine(lr, it, iterations)       # to lr/10
        theta = limits.denormalise(u)
        per = tr.losses(model, theta)
        total = per.sum()
        if extra_loss is not None:
            total = total + extra_loss(theta)
        opt.zero_grad()
        total.backward()
        opt.step()
        limits.clamp_or_wrap_normalised_(u)                           # limits clamped, continuous wrapped
        hist.append(per.detach().reshape(B, R))
    with torch.no_grad():
        theta = limits.denormalise(u)
        final = tr.losses(model, theta).reshape(B, R)
    if not bool(torch.isfinite(theta).all()):
        raise FloatingPointError("fit_pose: the optimisation diverged (NaN or inf joints); lower lr or check "
                                 "extra_loss")
    theta, final = theta.cpu(), final.cpu()
    best = final.argmin(1)
    ar = torch.arange(B)
    history = torch.stack(hist).cpu().numpy() if hist else np.zeros((0, B, R))
    return PoseFit(iterations=iterations, poses=limits.numpy(theta.reshape(B, R, K)[ar, best].numpy()), loss=final[ar, best].numpy(),
                   history=history[:, np.arange(B), best.numpy()] if len(history) else np.zeros((0, B)),
                   start=starts.reshape(B, R, K)[ar, best].numpy().astype(np.float64), all_losses=final.numpy())
