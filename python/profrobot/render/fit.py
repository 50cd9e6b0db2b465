"""Fit a :class:`GaussianRobot`'s appearance and geometry to MuJoCo renders.

Loss per step (one training pose, a few of its cameras; images in [0, 1], depth in metres):

    L = 0.8 |I - I*|_1 + 0.2 (1 - SSIM(I, I*))            (3DGS / Dr. Robot)
        + w_depth * mean_{mask*} |D - D*|                  (expected depth on the robot mask)
        + w_mask  * mean |alpha - mask*|                   (silhouette)

Adam with 3DGS-style per-parameter learning rates. Every ``densify_every`` steps, as 3DGS does
at CPU scale: Gaussians whose positions received the largest mean gradient are split (large
ones: two samples from the Gaussian, scales / 1.6) or cloned (small ones), and nearly
transparent ones are pruned. ``torch.optim.Adam`` keeps its moments across each edit, as
gsplat's strategy ops do: surviving Gaussians keep theirs, new ones start from zero.
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch
import torch.nn.functional as F

from ..files import check_robot
from ..kinematics.fk import quat_to_matrix
from .gaussians import GaussianRobot
from .rasterizer import Backend, RenderOut
from .views import Views

__all__ = ["fit_gaussians", "ssim", "image_losses"]


def _gauss_window(size: int = 11, sigma: float = 1.5, dtype=torch.float32, device=None) -> torch.Tensor:
    x = torch.arange(size, dtype=dtype, device=device) - size // 2
    g = torch.exp(-x * x / (2 * sigma * sigma))
    g = g / g.sum()
    return (g[:, None] * g[None, :])[None, None]


def ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of images (C, H, W, 3) in [0, 1] (11x11 Gaussian window, sigma 1.5)."""
    x, y = a.permute(0, 3, 1, 2), b.permute(0, 3, 1, 2)
    w = _gauss_window(dtype=a.dtype, device=a.device).expand(3, 1, 11, 11)
    conv = lambda t: F.conv2d(t, w, padding=5, groups=3)
    mx, my = conv(x), conv(y)
    sxx, syy, sxy = conv(x * x) - mx * mx, conv(y * y) - my * my, conv(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return s.mean()


def image_losses(out: RenderOut, rgb_t: torch.Tensor, depth_t: torch.Tensor, mask_t: torch.Tensor, *,
                 w_ssim: float = 0.2, w_depth: float = 1.0, w_mask: float = 0.5) -> dict[str, torch.Tensor]:
    """The fitting loss terms for a render ``out`` (RenderOut) against targets rgb (C, H, W, 3)
    in [0, 1], depth (C, H, W) metres, mask (C, H, W) bool. Returns the terms and ``total``."""
    l1 = (out.rgb - rgb_t).abs().mean()
    terms = dict(l1=l1)
    total = (1 - w_ssim) * l1
    if w_ssim > 0:
        terms["ssim"] = ssim(out.rgb, rgb_t)
        total = total + w_ssim * (1 - terms["ssim"])
    m = mask_t.to(out.depth.dtype)
    terms["depth"] = ((out.depth - depth_t).abs() * m).sum() / m.sum().clamp_min(1)
    terms["mask"] = (out.alpha - m).abs().mean()
    terms["total"] = total + w_depth * terms["depth"] + w_mask * terms["mask"]
    return terms


_PARAMS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def _optimizer(model: GaussianRobot, lr_scale: float = 1.0) -> torch.optim.Adam:
    # 3DGS's rates, positions in metres for a ~1 m robot; the degree-0 colour term learns faster
    # than the view-dependent ones (3DGS: 1/20)
    groups = [
        dict(params=[model.means], lr=2e-4 * lr_scale),
        dict(params=[model.log_scales], lr=5e-3 * lr_scale),
        dict(params=[model.quats], lr=1e-3 * lr_scale),
        dict(params=[model.opacity_logits], lr=5e-2 * lr_scale),
        dict(params=[model.sh], lr=2.5e-3 * lr_scale),
    ]
    if model.skin_mlp is not None:
        groups.append(dict(params=list(model.skin_mlp.parameters()), lr=1e-3 * lr_scale))
    return torch.optim.Adam(groups, eps=1e-15)


@torch.no_grad()
def _remap_optimizer(opt: torch.optim.Adam, old: dict[str, torch.nn.Parameter], model: GaussianRobot,
                     rows: torch.Tensor) -> None:
    """After densification replaced the per-Gaussian parameters (``old``, by name) with the
    model's new ones, put the new ones in ``opt``'s groups and carry their moments over: row ``i``
    of a new parameter came from row ``rows[i]`` of the old one, or is new where ``rows[i] < 0``
    (zero moments). The step counters are kept (gsplat's ``_update_param_with_optimizer``)."""
    valid = rows >= 0
    src = rows.clamp_min(0)
    for name, p_old in old.items():
        p_new = getattr(model, name)
        for group in opt.param_groups:
            group["params"] = [p_new if p is p_old else p for p in group["params"]]
        state = opt.state.pop(p_old, None)
        if not state:
            continue
        for key, v in state.items():
            if isinstance(v, torch.Tensor) and v.shape == p_old.shape:   # exp_avg, exp_avg_sq (, max_exp_avg_sq)
                moved = v[src]
                moved[~valid] = 0
                state[key] = moved
        opt.state[p_new] = state


@torch.no_grad()
def _densify(model: GaussianRobot, grad_acc: torch.Tensor, top: float, max_n: int, min_opacity: float,
             rng: torch.Generator, contrib: torch.Tensor | None = None,
             min_contrib: float = 0.0) -> tuple[dict, torch.Tensor]:
    """Split/clone the ``top`` fraction by accumulated position gradient; prune transparent ones
    and those whose largest blending weight ``contrib`` (N,) stayed below ``min_contrib``
    (hidden inside the robot: e.g. Gaussians on internal meshes). Returns a summary and, per
    Gaussian after the edit, the index it had before (-1 for new ones)."""
    n0 = model.n
    rows = torch.arange(n0, device=model.means.device)          # where each row comes from; -1: new
    op = torch.sigmoid(model.opacity_logits)
    keep = op >= min_opacity
    if contrib is not None:
        keep &= contrib >= min_contrib
    room = max(0, max_n - int(keep.sum()))
    k = min(int(top * n0), room)
    added = 0
    if k > 0:
        sel = torch.topk(grad_acc * keep, k).indices
        s = torch.exp(model.log_scales[sel])                          # (k, 3)
        big = s.max(-1).values > torch.exp(model.log_scales).max(-1).values.median()
        # split the big: two samples from the Gaussian (in its body frame), scales / 1.6
        R = quat_to_matrix(model.quats[sel])
        eps = torch.randn(k, 3, generator=rng, dtype=s.dtype).to(s.device) * s
        offs = torch.einsum("nij,nj->ni", R, eps)
        new_means = torch.where(big[:, None], model.means[sel] + offs, model.means[sel])
        new_logs = torch.where(big[:, None], model.log_scales[sel] - math.log(1.6), model.log_scales[sel])
        model.log_scales.data[sel] = new_logs
        model.means.data[sel] = torch.where(big[:, None], model.means[sel] - offs, model.means[sel])
        model.append(model.body[sel], new_means, model.quats[sel], new_logs, model.opacity_logits[sel], model.sh[sel])
        keep = torch.cat([keep, torch.ones(k, dtype=torch.bool, device=keep.device)])
        rows = torch.cat([rows, torch.full((k,), -1, dtype=rows.dtype, device=rows.device)])
        added = k
    model.keep(keep)
    return dict(n_before=n0, added=added, pruned=int((~keep).sum()), n_after=model.n), rows[keep]


@torch.no_grad()
def visibility(model: GaussianRobot, views: Views, max_sets: int = 64, seed: int = 0,
               backend: Backend = "auto") -> torch.Tensor:
    """(N,) each Gaussian's largest blending weight over (up to ``max_sets``) training poses,
    each from all of its cameras."""
    rng = np.random.default_rng(seed)
    idx = rng.permutation(len(views))[:max_sets]
    dev = model.means.device
    best = torch.zeros(model.n, device=dev)
    for p in idx:
        out = model.render_views(torch.tensor(views.poses[p:p + 1], dtype=torch.float32, device=dev), views.cameras,
                                 backend=backend)
        if out.contrib is None:                                   # gsplat: no per-Gaussian weights
            return torch.ones(model.n, device=dev)
        best = torch.maximum(best, out.contrib.max(0).values)
    return best


def fit_gaussians(model: GaussianRobot, views: Views, *, iterations: int = 500, cams_per_step: int = 4, w_ssim: float = 0.2,
                  w_depth: float = 1.0, w_mask: float = 0.5, densify_every: int = 100, densify_until: float = 0.7,
                  densify_top: float = 0.05, max_gaussians: int = 30000, min_opacity: float = 0.02,
                  min_contrib: float = 0.02, prune_hidden_first: bool = True, seed: int = 0, progress: bool = True,
                  log_every: int = 50, backend: Backend = "auto") -> list[dict]:
    """Fit ``model`` (in place) to ``views`` (MuJoCo renders of the same robot). Each step draws
    one pose and ``cams_per_step`` of its cameras. Returns the loss history (one dict per log).

    ``prune_hidden_first``: before fitting, drop Gaussians whose blending weight never reaches
    ``min_contrib`` in any training view (initialised on meshes inside the robot's shell, they
    only leak dark blotches through it). ``backend``: the rasterizer (see
    :func:`profrobot.render.rasterize`; "auto" is the Rust kernel on a CPU, gsplat on CUDA)."""
    from ..executors.progress import progress_bar

    check_robot(views.fingerprint or None, model, "the views", made_for=views.robot_name, missing_ok=True, geometry=True)
    rng = np.random.default_rng(seed)
    trng = torch.Generator().manual_seed(seed)
    cams = views.cameras
    dev = model.means.device
    f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=dev)
    vm_all, K_all, bg = f32(cams.world_to_cam), f32(cams.K), f32(views.background)
    history = []
    if prune_hidden_first:
        vis = visibility(model, views, seed=seed, backend=backend)
        n0 = model.n
        model.keep(vis >= min_contrib)
        history.append(dict(step=0, event="prune_hidden", n_before=n0, n_after=model.n))
    opt = _optimizer(model)
    zeros = lambda: torch.zeros(model.n, device=dev)
    grad_acc, seen, contrib = zeros(), zeros(), zeros()
    t0 = time.perf_counter()
    bar = progress_bar(iterable=range(iterations), desc="fit Gaussians", progress=progress)
    for it in bar:
        p = int(rng.integers(len(views)))
        cs = rng.choice(len(cams), size=min(cams_per_step, len(cams)), replace=False)
        rgb_t = f32(views.rgb[p, cs]) / 255.0
        depth_t = f32(views.depth[p, cs])
        mask_t = torch.as_tensor(views.mask[p, cs], device=dev)
        out = model.render(f32(views.poses[p:p + 1]), vm_all[cs], K_all[cs], cams.width, cams.height, background=bg,
                           backend=backend)
        terms = image_losses(out, rgb_t, depth_t, mask_t, w_ssim=w_ssim, w_depth=w_depth, w_mask=w_mask)
        opt.zero_grad()
        terms["total"].backward()
        with torch.no_grad():
            assert model.means.grad is not None   # the loss reads every mean
            gn = model.means.grad.norm(dim=-1)
            grad_acc += gn
            seen += (gn > 0).float()
            if out.contrib is not None:
                contrib = torch.maximum(contrib, out.contrib.max(0).values)
        opt.step()
        with torch.no_grad():
            model.quats.data = model.quats / model.quats.norm(dim=-1, keepdim=True)
            model.log_scales.data.clamp_(max=math.log(0.05))           # no Gaussian wider than 5 cm
        if (it + 1) % densify_every == 0 and it + 1 < densify_until * iterations:
            # contrib over one interval sees few views: only prune what was drawn nowhere at all
            old = {name: getattr(model, name) for name in _PARAMS}
            info, rows = _densify(model, grad_acc / seen.clamp_min(1), densify_top, max_gaussians, min_opacity,
                                  trng, contrib if contrib.any() else None, 1e-6)
            _remap_optimizer(opt, old, model, rows)
            grad_acc, seen, contrib = zeros(), zeros(), zeros()
            history.append(dict(step=it + 1, event="densify", **info))
        if (it + 1) % log_every == 0 or it + 1 == iterations:
            rec: dict[str, object] = {k: float(v.detach()) for k, v in terms.items()}
            rec.update(step=it + 1, n=model.n, seconds=time.perf_counter() - t0)
            history.append(rec)
            bar.set_postfix(loss=f"{rec['total']:.4f}", n=model.n)
    return history
