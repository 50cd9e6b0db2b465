"""Joint angles from images: gradient descent on the Gaussian robot's render (paper §4.3).

For B targets, each seen by the same C cameras, with target images ``I*`` (C, H, W, 3) in [0, 1],
depths ``D*`` (metres) and robot masks ``M*``:

    L(theta) = mean_{M} |I(theta) - I*|^2                 (L_RGB on the robot mask)
             + w_depth * mean_{M* & alpha > 1/2} |D(theta) - D*|   (L_D, metres)
             + w_mask  * mean |alpha(theta) - M*|          (silhouette)
             + extra(theta)                               (e.g. beta * L_SDF, the collision penalty)

where ``M = M* | (alpha > 1/2)`` (the target's and the render's robot pixels, so that a robot
drawn in the wrong place is penalised too; :mod:`profrobot.render.targets`). Adam on joints normalised to [-1, 1] over their
limits (Dr. Robot: lr 0.02), projected back into joint space after each step (limited joints
clamped, continuous hinges wrapped: :class:`profrobot.joints.Limits`), learning rate decayed
ten-fold (cosine); restarts perturb the start and keep the best final loss. Inputs are
validated once, at entry: the loop itself makes no host syncs.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from collections.abc import Callable

import numpy as np
import torch

from ..joints import Limits
from .gaussians import GaussianRobot
from .targets import ImageTargets, pose_loss
from .cameras import Cameras
from ..deprecation import deprecated_alias, renamed_arguments
from ..errors import InputError

__all__ = ["fit_pose", "PoseFit", "pose_loss", "downsample_targets", "ImageTargets"]


@dataclass
class PoseFit:
    """``poses`` (B, K) the fitted poses, ``loss`` (B,) their final image loss, ``history``
    (iterations, B) the loss of the kept start per step, ``start`` (B, K) the start that was kept."""

    poses: np.ndarray
    loss: np.ndarray
    history: np.ndarray
    start: np.ndarray
    all_losses: np.ndarray = field(default=None)
    iterations: int = 0

    theta = deprecated_alias("poses")


def downsample_targets(targets: dict, factor: int) -> dict:
    """Targets (``rgb`` (B, C, H, W, 3) uint8 or [0, 1], ``depth`` (B, C, H, W) m, ``mask``
    (B, C, H, W) bool) at 1/``factor`` resolution: RGB averaged over ``factor`` x ``factor``
    blocks, the mask where at least half of a block is robot, the depth averaged over the
    block's robot pixels (0 elsewhere). A block's centre is where the downsampled camera
    (:meth:`Cameras.resized`, same field of view) puts its pixel centre."""
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
    return dict(rgb=rgb_d.astype(np.float32), depth=depth_d, mask=m >= n / 2)


def _coarse_to_fine(model, targets, cameras, init, coarse, **fine) -> PoseFit:
    coarse = dict(coarse)
    factor = int(coarse.pop("factor", 2))
    H, W = cameras.height, cameras.width
    if factor < 1 or H % factor or W % factor:
        raise InputError(f"fit_pose: coarse factor {factor} does not divide the image size {W}x{H}")
    if "iters" in coarse:   # the name of earlier releases
        warnings.warn("fit_pose(coarse=dict(iters=...)) is deprecated; use iterations=...", DeprecationWarning,
                      stacklevel=5)   # _coarse_to_fine < fit_pose < renamed_arguments' wrapper < the caller
        coarse["iterations"] = coarse.pop("iters")
    unknown = set(coarse) - {"iterations", "lr", "restarts", "restart_sigma", "w_depth", "w_mask"}
    if unknown:
        raise InputError(f"fit_pose: unknown coarse-stage options {sorted(unknown)}")
    kw = {k: fine[k] for k in ("lr", "w_depth", "w_mask", "extra_loss", "background", "seed")} | coarse
    c = fit_pose(model, downsample_targets(targets, factor), cameras.resized(W // factor, H // factor), init, **kw)
    f = fit_pose(model, targets, cameras, c.poses, **fine)
    return PoseFit(poses=f.poses, loss=f.loss, iterations=c.iterations + f.iterations, history=np.concatenate([c.history, f.history]), start=c.start,
                   all_losses=c.all_losses)


@renamed_arguments(iters="iterations")
def fit_pose(model: GaussianRobot, targets: dict, cameras: Cameras, init, *, iterations: int = 100, lr: float = 0.02,
             restarts: int = 0, restart_sigma: float = 0.3, w_depth: float = 1.0, w_mask: float = 0.5,
             extra_loss: Callable[[torch.Tensor], torch.Tensor] | None = None, background=None,
             seed: int = 0, coarse: dict | None = None) -> PoseFit:
    """Recover joint angles from multi-view images.

    ``targets``: dict with ``rgb`` (B, C, H, W, 3) uint8 or [0, 1] floats, ``depth`` (B, C, H, W)
    metres and ``mask`` (B, C, H, W) bool (B may be left out for one target), e.g. from
    :func:`profrobot.render.make_views`. ``cameras``: the C cameras. ``init`` (B, K) or (K,)
    starting poses. ``restarts``: extra starts per target, perturbed by ``restart_sigma`` (radians,
    per joint, clipped to the limits); all starts run as one batch. ``extra_loss``: a callable
    of theta (B*R, K) returning a scalar added to the summed loss (the collision penalty's hook).

    ``coarse``: coarse-to-fine. A dict of keyword arguments for a first stage run on the
    targets and cameras downsampled by ``factor`` (default 2: 128^2 -> 64^2; RGB averaged over
    2x2 blocks, the mask kept where at least half the block is robot, depth averaged over the
    block's robot pixels), e.g. ``dict(iterations=45, lr=0.02, restarts=3)``; the restarts are
    chosen there (a coarse render is ~4x cheaper), and the full-resolution stage starts from
    the best coarse pose with this call's ``iterations``, ``lr`` and weights. ``history`` then
    holds both stages.
    """
    if coarse is not None:
        return _coarse_to_fine(model, targets, cameras, init, coarse, iterations=iterations, lr=lr, w_depth=w_depth,
                               w_mask=w_mask, extra_loss=extra_loss, background=background, seed=seed)
    dev = model.means.device
    init = torch.as_tensor(np.asarray(init, dtype=np.float64), dtype=torch.float32)
    if init.ndim == 1:
        init = init[None]
    K = model.njoint
    if init.ndim != 2 or init.shape[1] != K:
        raise InputError(f"fit_pose: init must have shape (B, {K}); got {tuple(init.shape)}")
    if not torch.isfinite(init).all():
        raise InputError("fit_pose: init contains NaN or inf")
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
    for it in range(iterations):
        opt.param_groups[0]["lr"] = lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * it / max(iterations, 1))))  # to lr/10
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

