"""A differentiable Gaussian-splat rasterizer in pure PyTorch (CPU or GPU), with gsplat behind the
same interface when CUDA and gsplat are present.

Per camera (OpenCV pinhole ``K``, ``world_to_cam``), for Gaussians with world means ``mu`` and
covariances ``Sigma`` (metres):

1. camera frame  ``p = R mu + t``;  ``Sigma_c = R Sigma R^T``;  pixel ``u = fx x/z + cx``, ``v = fy y/z + cy``;
2. EWA: ``Sigma_2d = J Sigma_c J^T + 0.3 I`` with ``J = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]``
   (x/z, y/z clamped to 1.3x the field of view, as 3DGS does); the 0.3 px^2 is the low-pass filter;
3. per (pixel, Gaussian) pair: ``alpha = min(0.99, o exp(-d^T Sigma_2d^-1 d / 2))``, ``d`` = pixel - (u, v);
4. front to back by ``z``: ``T_i = prod_{j<i} (1 - alpha_j)``, ``w_i = alpha_i T_i``;
   ``rgb = sum w_i c_i + T_end bg``, ``alpha = sum w_i``, ``depth = sum w_i z_i / alpha`` (expected
   depth, metres, 0 where alpha = 0).

Cost: the contributing pairs are *found* without autograd (each Gaussian's tight pixel box
where alpha >= 1/255, then the alpha and transmittance tests of 3DGS: alpha >= 1/255, and a pixel
stops once T would fall below 1e-4), and only those pairs are differentiated.

Backends: ``"rust"`` (the CPU default) runs steps 1–4 and their backward in the Rust core
(``rust/bindings/render.rs``: projection and SH colour, ``rust/render/splat.rs``: a tile rasterizer with
per-tile depth-sorted lists, the same compositing rules, every composited pair recorded for its
exact backward), in float32 for float32 tensors, float64 otherwise, as one
``torch.autograd.Function`` (:class:`_Render`) whose gradients reach the 3D means and
covariances, opacities, colours (or SH coefficients and frames) and cameras; torch carries
them on to poses and Gaussian parameters. ``"torch"`` is the
reference implementation below; ``"gsplat"`` is gsplat's CUDA kernel.

Cutoff: 3DGS drops alpha < 1/255 (``cutoff="hard"``), a jump that finite differences see and
autograd does not (pose gradients come out ~20 % low). The default ``cutoff="soft"`` composites
``max(0, alpha - 1/255)``, which is continuous, so gradients match finite differences.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import numpy.typing as npt
import torch
from ..errors import BackendUnavailableError, InputError, InputTypeError

Cutoff = Literal["soft", "hard"]
Backend = Literal["auto", "torch", "rust", "gsplat"]

__all__ = ["rasterize", "RenderOut", "Cutoff", "Backend", "ALPHA_MIN", "T_MIN"]

ALPHA_MIN = 1.0 / 255.0   # 3DGS: pairs below this alpha do not contribute
T_MIN = 1e-4              # 3DGS: a pixel stops compositing once transmittance would drop below
ALPHA_MAX = 0.99          # 3DGS: keeps 1 - alpha away from 0 (log and division stay finite)
LOWPASS = 0.3             # px^2 added to the 2D covariance (EWA anti-aliasing)
NEAR = 0.01               # metres: Gaussians closer than this to the camera are dropped


@dataclass
class RenderOut:
    """``rgb`` (C, H, W, 3), ``depth`` (C, H, W) metres (expected depth; 0 where nothing was
    drawn), ``alpha`` (C, H, W) accumulated opacity in [0, 1]; ``npairs``: composited pairs;
    ``contrib`` (C, N) each Gaussian's largest blending weight ``alpha T`` in any pixel (no
    gradient; 0 for a Gaussian that is hidden or off-screen), or None (gsplat)."""

    rgb: torch.Tensor
    depth: torch.Tensor
    alpha: torch.Tensor
    npairs: int = 0
    contrib: torch.Tensor | None = None


def _check(name, t, shape_desc, ok):
    if not isinstance(t, torch.Tensor):
        raise InputTypeError(f"rasterize: {name} must be a torch.Tensor; got {type(t).__name__}")
    if not ok:
        raise InputError(f"rasterize: {name} must have shape {shape_desc}; got {tuple(t.shape)}")


def _validate(means, covs, opacities, colors, viewmats, Ks):
    _check("viewmats", viewmats, "(C, 4, 4)", viewmats.ndim == 3 and viewmats.shape[1:] == (4, 4))
    C = viewmats.shape[0]
    _check("Ks", Ks, f"({C}, 3, 3)", Ks.shape == (C, 3, 3))
    _check("means", means, "(N, 3) or (C, N, 3)", means.shape[-1] == 3 and means.ndim in (2, 3))
    N = means.shape[-2]
    _check("covs", covs, f"({N}, 3, 3) or (C, {N}, 3, 3)", covs.shape[-3:] == (N, 3, 3) and covs.ndim in (3, 4))
    _check("opacities", opacities, f"({N},) or (C, {N})", opacities.shape[-1] == N and opacities.ndim in (1, 2))
    _check("colors", colors, f"({N}, 3) or (C, {N}, 3)", colors.shape[-2:] == (N, 3) and colors.ndim in (2, 3))
    if N == 0:
        raise InputError("rasterize: the Gaussian set is empty (means has N = 0 rows)")
    for name, t in (("means", means), ("covs", covs), ("opacities", opacities), ("colors", colors),
                    ("viewmats", viewmats), ("Ks", Ks)):
        if t.dtype not in (torch.float32, torch.float64):
            raise InputTypeError(f"rasterize: {name} must be float32 or float64; got {t.dtype}")
        if not torch.isfinite(t).all():
            raise InputError(f"rasterize: {name} contains NaN or inf")
    return C, N


def project(means, covs, viewmats, Ks, width, height):
    """EWA projection. means (N, 3) or (C, N, 3), covs (N, 3, 3) or (C, N, 3, 3) world →
    pixel centres ``uv`` (C, N, 2), conics (inverse 2D covariances, as ``(a, b, c)`` of
    ``[[a, b], [b, c]]``) (C, N, 3), 2D covariances (C, N, 3) the same way, camera depth ``z``
    (C, N) metres; differentiable.

    Written component by component on (C, N) tensors: a CPU runs these ~100 small elementwise
    ops (and autograd their backward) several times faster than batched 3x3 matmuls or
    broadcast reductions over trailing size-3 axes."""
    mx, my, mz = means.unbind(-1)                                        # (N,) or (C, N)
    Rv, tv = viewmats[:, :3, :3], viewmats[:, :3, 3]
    r = [[Rv[:, i, j, None] for j in range(3)] for i in range(3)]        # (C, 1) each
    x, y, z = (r[i][0] * mx + r[i][1] * my + r[i][2] * mz + tv[:, i, None] for i in range(3))   # (C, N) camera frame
    zs = z.clamp_min(NEAR)
    iz = 1.0 / zs
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    xz, yz = x * iz, y * iz
    uv = torch.stack([fx * xz + cx, fy * yz + cy], -1)
    # the Jacobian is taken at an x/z clamped to the image's extent plus 15 % of its size each side
    # (pixel edges -1/2 and W - 1/2, any principal point): off-screen Gaussians do not get huge footprints
    txz = torch.maximum(torch.minimum(xz, (width - 0.5 - cx + 0.15 * width) / fx), (-0.5 - cx - 0.15 * width) / fx)
    tyz = torch.maximum(torch.minimum(yz, (height - 0.5 - cy + 0.15 * height) / fy), (-0.5 - cy - 0.15 * height) / fy)
    # M = J R (2 x 3 per Gaussian), J = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]:
    # row 0 = fx/z (R_0 - x/z R_2), row 1 = fy/z (R_1 - y/z R_2)
    fxz, fyz = fx * iz, fy * iz
    m0 = [fxz * (r[0][j] - txz * r[2][j]) for j in range(3)]
    m1 = [fyz * (r[1][j] - tyz * r[2][j]) for j in range(3)]
    # Sigma_2d = M Sigma M^T: (i, k) entry = m_i . (Sigma m_k)
    S = [[covs[..., i, j] for j in range(3)] for i in range(3)]         # (N,) or (C, N) each
    Sm0 = [S[i][0] * m0[0] + S[i][1] * m0[1] + S[i][2] * m0[2] for i in range(3)]
    Sm1 = [S[i][0] * m1[0] + S[i][1] * m1[1] + S[i][2] * m1[2] for i in range(3)]
    a = m0[0] * Sm0[0] + m0[1] * Sm0[1] + m0[2] * Sm0[2] + LOWPASS
    b = m0[0] * Sm1[0] + m0[1] * Sm1[1] + m0[2] * Sm1[2]
    c = m1[0] * Sm1[0] + m1[1] * Sm1[1] + m1[2] * Sm1[2] + LOWPASS
    det = (a * c - b * b).clamp_min(1e-12)
    idet = 1.0 / det
    conic = torch.stack([c * idet, -b * idet, a * idet], -1)
    return uv, conic, torch.stack([a, b, c], -1), z


@torch.no_grad()
def _find_pairs(uv, conic, cov2, z, opac, width, height, cutoff, chunks: int = 4):
    """Contributing (pixel, Gaussian) pairs, in compositing order, without autograd.

    Returns ``g`` (M,) flat Gaussian index into C*N, ``pix`` (M,) flat pixel index into C*H*W,
    sorted by pixel then depth, keeping only pairs with alpha >= 1/255 and T above 1e-4.

    Occlusion culling, exact: each camera's Gaussians are taken front to back in ``chunks``
    depth slices; after each slice a pixel whose transmittance fell below 1e-4 is closed (3DGS
    stops there), and a Gaussian of a later slice whose whole box lies on closed pixels (an
    integral image of the open pixels answers that per box) is never enumerated. On the Panda
    most pairs behind the front surfaces go this way. The result equals the unculled search."""
    C, N = z.shape
    dev = z.device
    # Tight box of the ellipse where o exp(-q/2) >= 1/255, i.e. q <= 2 ln(255 o): half-widths
    # sqrt(k Sigma_xx) and sqrt(k Sigma_yy).
    k = 2 * torch.log((opac * 255.0).clamp_min(1.0))
    rx = torch.sqrt(k * cov2[..., 0])
    ry = torch.sqrt(k * cov2[..., 2])
    u, v = uv.unbind(-1)
    x0 = torch.ceil(u - rx).clamp(0, width).long()
    x1 = torch.floor(u + rx).clamp(-1, width - 1).long()
    y0 = torch.ceil(v - ry).clamp(0, height).long()
    y1 = torch.floor(v + ry).clamp(-1, height - 1).long()
    bw = (x1 - x0 + 1).clamp_min(0)
    bh = (y1 - y0 + 1).clamp_min(0)
    live = (z > NEAR) & (k > 0)
    count = torch.where(live, bw * bh, torch.zeros_like(bw))
    box = dict(x0=x0, x1=x1, y0=y0, y1=y1, bw=bw, count=count)
    params = torch.cat([uv, conic, opac[..., None]], -1)            # (C, N, 6)
    # each camera's Gaussians front to back; a stable sort by pixel of pairs enumerated in this
    # order leaves every pixel's pairs in depth order (cheaper than sorting (pixel, depth) keys)
    order = torch.argsort(z, dim=1)                                   # (C, N)
    log_tmin = math.log(T_MIN)
    logT = torch.zeros(C * height * width, dtype=torch.float64, device=dev)   # log T so far, per pixel
    gs, pixs = [], []
    bounds = [round(N * i / chunks) for i in range(chunks + 1)]
    for i in range(chunks):
        ids = order[:, bounds[i]:bounds[i + 1]]                       # (C, n) this depth slice
        if ids.numel() == 0:
            continue
        cam = torch.arange(C, device=dev)[:, None].expand_as(ids)
        take = lambda t, cam=cam, ids=ids: t[cam, ids]   # bound now: used within this slice only
        cnt = take(count)
        if i > 0:                                                     # cull boxes with no open pixel
            open_ = (logT >= log_tmin).reshape(C, height, width).int()
            S = torch.zeros(C, height + 1, width + 1, dtype=torch.int32, device=dev)
            S[:, 1:, 1:] = open_.cumsum(1).cumsum(2)
            bx0, bx1, by0, by1 = take(x0), take(x1) + 1, take(y0), take(y1) + 1
            n_open = S[cam, by1, bx1] - S[cam, by0, bx1] - S[cam, by1, bx0] + S[cam, by0, bx0]
            cnt = torch.where(n_open > 0, cnt, torch.zeros_like(cnt))
        sel = cnt.reshape(-1) > 0
        if not sel.any():
            continue
        flat = (ids + cam * N).reshape(-1)[sel]                        # flat Gaussian ids, depth order
        g, pix, alpha = _candidates(flat, params.reshape(-1, 6), box, cnt.reshape(-1)[sel], N, width, height, cutoff)
        if i > 0:                                                     # pairs on closed pixels
            o = logT[pix] >= log_tmin
            g, pix, alpha = g[o], pix[o], alpha[o]
        srt = torch.sort(pix.int() if C * height * width < 2**31 else pix, stable=True).indices
        g, pix, alpha = g[srt], pix[srt], alpha[srt]
        la = torch.log1p(-alpha.double())
        # transmittance after each pair; a pixel stops at the first pair that would leave T < 1e-4
        keep = logT[pix] + _segment_cumsum(la, pix) >= log_tmin
        logT.index_add_(0, pix, la)
        gs.append(g[keep])
        pixs.append(pix[keep])
    if not gs:
        e = torch.zeros(0, dtype=torch.long, device=dev)
        return e, e
    g, pix = torch.cat(gs), torch.cat(pixs)
    srt = torch.sort(pix.int() if C * height * width < 2**31 else pix, stable=True).indices
    return g[srt], pix[srt]


def _candidates(flat, params, box, cnt, N, width, height, cutoff):
    """Enumerate the box pixels of Gaussians ``flat`` (n,) (flat ids, in depth order, with box
    sizes ``cnt`` (n,)) and keep the pairs with alpha > 0: returns g, pix (flat), alpha (M,)."""
    dev = flat.device
    total = int(cnt.sum())
    cam = torch.div(flat, N, rounding_mode="floor")
    x0, y0 = box["x0"].reshape(-1)[flat], box["y0"].reshape(-1)[flat]
    # per pair: its Gaussian's slot and the offset inside the box, pixel = first + (off // bw) W + off % bw
    slot = torch.repeat_interleave(torch.arange(len(flat), device=dev), cnt)
    off = torch.arange(total, device=dev) - (torch.cumsum(cnt, 0) - cnt)[slot]
    bwg = box["bw"].reshape(-1)[flat][slot]
    oy = torch.div(off, bwg, rounding_mode="floor")
    ox = off - oy * bwg
    pix = ((cam * height + y0) * width + x0)[slot] + oy * width + ox
    pr = params[flat][slot]                                           # (M, 6): u, v, conic, opacity
    dx = (ox + x0[slot]).to(pr.dtype) - pr[:, 0]
    dy = (oy + y0[slot]).to(pr.dtype) - pr[:, 1]
    q = pr[:, 2] * dx * dx + 2 * pr[:, 3] * dx * dy + pr[:, 4] * dy * dy
    alpha = torch.clamp(pr[:, 5] * torch.exp(-0.5 * q), max=ALPHA_MAX)
    alpha = torch.clamp(alpha - ALPHA_MIN, min=0.0) if cutoff == "soft" else torch.where(alpha >= ALPHA_MIN, alpha, 0.0)
    keep = torch.nonzero(alpha > 0).squeeze(1)
    return flat[slot[keep]], pix[keep], alpha[keep]


def _alpha(uv, conic, opac, px, py, cutoff):
    """alpha of each pair (M,): ``min(0.99, o exp(-q/2))``; soft cutoff subtracts 1/255."""
    dx = px.to(uv.dtype) - uv[:, 0]
    dy = py.to(uv.dtype) - uv[:, 1]
    q = conic[:, 0] * dx * dx + 2 * conic[:, 1] * dx * dy + conic[:, 2] * dy * dy
    a = torch.clamp(opac * torch.exp(-0.5 * q), max=ALPHA_MAX)
    if cutoff == "soft":
        return torch.clamp(a - ALPHA_MIN, min=0.0)
    return torch.where(a >= ALPHA_MIN, a, torch.zeros_like(a))


def _segment_cumsum(x, seg):
    """Inclusive cumulative sum of ``x`` (M,) restarting where the sorted ``seg`` (M,) changes.
    float64 on purpose: a global cumsum minus each segment's start must not lose digits."""
    cs = torch.cumsum(x, 0)
    first = torch.ones_like(seg, dtype=torch.bool)
    first[1:] = seg[1:] != seg[:-1]
    seg_id = torch.cumsum(first.long(), 0) - 1
    base = (cs - x)[first]                                       # sum before each segment
    return cs - base[seg_id]


def _rasterize_torch(means, covs, opacities, colors, viewmats, Ks, width, height, background, cutoff):
    C, N = viewmats.shape[0], means.shape[-2]
    uv, conic, cov2, z = project(means, covs, viewmats, Ks, width, height)
    opac = opacities.expand(C, N)
    g, pix = _find_pairs(uv.detach(), conic.detach(), cov2.detach(), z.detach(), opac.detach(), width, height, cutoff)
    # --- differentiable part: only the contributing pairs ---
    W = width
    px = pix % W
    py = torch.div(pix, W, rounding_mode="floor") % height
    alpha = _alpha(uv.reshape(-1, 2)[g], conic.reshape(-1, 3)[g], opac.reshape(-1)[g], px, py, cutoff)
    logT = _segment_cumsum(torch.log1p(-alpha).double(), pix) - torch.log1p(-alpha).double()  # exclusive
    w = alpha * torch.exp(logT).to(alpha.dtype)
    P = C * height * width
    cols = colors.expand(C, N, 3).reshape(-1, 3)[g]
    zz = z.reshape(-1)[g]
    rgb = torch.zeros(P, 3, dtype=w.dtype, device=w.device).index_add(0, pix, w[:, None] * cols)
    acc = torch.zeros(P, dtype=w.dtype, device=w.device).index_add(0, pix, w)
    dsum = torch.zeros(P, dtype=w.dtype, device=w.device).index_add(0, pix, w * zz)
    rgb = rgb.reshape(C, height, width, 3)
    acc = acc.reshape(C, height, width)
    depth = torch.where(acc > 1e-6, dsum.reshape(C, height, width) / acc.clamp_min(1e-6), torch.zeros_like(acc))
    if background is not None:
        rgb = rgb + (1 - acc)[..., None] * background.reshape(-1, 1, 1, 3)
    contrib = torch.zeros(C * N, dtype=w.dtype, device=w.device).scatter_reduce_(0, g, w.detach(), "amax").reshape(C, N)
    return RenderOut(rgb, depth, acc, int(g.numel()), contrib)


class _Render(torch.autograd.Function):
    """The native renderer (``rust/bindings/render.rs``) as one autograd node: EWA projection, colour
    (SH or given), tile rasterization, and the fused backward of all three.

    forward(spec, *tensors): ``spec = (names, views, width, height, cutoff, threads, finish,
    background)`` names
    the tensors (the keywords of ``_core.render_forward``: ``opacities`` [N] or [V, N],
    ``viewmats`` [C, 4, 4], ``Ks`` [C, 3, 3]; the Gaussians either in the world, ``means``
    [P, N, 3], ``covs`` [P, N, 3, 3] and optionally ``frames`` [P, N, 3, 3], or rigidly on
    bodies, ``body_rot`` [P, nb, 3, 3], ``body_pos`` [P, nb, 3], ``body`` [N] int64,
    ``local_means`` [N, 3], ``local_rots`` [N, 3, 3] or ``local_quats`` [N, 4] (w, x, y, z; any
    nonzero norm), ``scales`` [N, 3]; colours ``sh``
    [N, nsh, 3] or ``colors`` [N, 3] or [V, N, 3]); ``views`` (V, 2) int64 numpy ``(pose,
    camera)``; ``finish``: the images finished in the kernel (``_core.finish_images``), with
    the background ``spec[7]`` ([3] or [V, 3] tensor, or None: black, no gradient). Returns rgb
    [V, H, W, 3] (``Σ w c``, plus ``(1 - Σ w) background`` when finished), alpha [V, H, W]
    (``Σ w``), dsum [V, H, W] (``Σ w z``; finished: the expected depth ``Σ w z / Σ w``, 0
    where ``Σ w <= 1e-6``), contrib [V, N] (no gradient), npairs (0-d int64, no gradient).

    Computes in float32 when every float input is float32, else in float64 (gradient checks);
    outputs and gradients take each input's dtype and device."""

    @staticmethod
    def forward(ctx, spec, *tensors):
        from .._core import finish_images, render_forward

        names, views, width, height, cutoff, threads, finish, background = spec
        floats = [t for k, t in zip(names, tensors) if k != "body"]
        dt = torch.float32 if all(t.dtype == torch.float32 for t in floats) else torch.float64
        arrays = {k: t.detach().to(device="cpu", dtype=torch.int64 if k == "body" else dt).contiguous().numpy()
                  for k, t in zip(names, tensors)}
        rgb, alpha, dsum, contrib, npairs, state = render_forward(
            arrays.pop("opacities"), arrays.pop("viewmats"), arrays.pop("Ks"), views, width, height, cutoff=cutoff,
            threads=threads, **arrays)
        bg = None
        if finish:
            # background and expected depth in one pass over the frame (dsum becomes the depth)
            # (a copy: the caller's background may change before the backward)
            bg = None if background is None else background.detach().to(device="cpu", dtype=dt).numpy().copy()
            finish_images(rgb, alpha, dsum, background=bg, threads=threads)
        ctx.state, ctx.threads, ctx.compute_dtype, ctx.names, ctx.finish, ctx.background = (
            state, threads, dt, names, finish, bg)
        ctx.meta = [(t.dtype, t.device) for t in tensors]
        ctx.out_shape = alpha.shape
        ctx.set_materialize_grads(False)         # an unused output's gradient arrives as None, not zeros
        odt, dev = floats[0].dtype, floats[0].device
        out = [torch.from_numpy(a).to(device=dev, dtype=odt) for a in (rgb, alpha, dsum, contrib)]
        ctx.finished = None
        if finish and dev.type == "cpu" and odt == dt:
            ctx.save_for_backward(out[1], out[2])   # alpha and depth: the outputs themselves (edits are caught)
        elif finish:
            ctx.finished = (alpha, dsum)            # the kernel's own arrays (the outputs are copies)
        npairs_t = torch.tensor(npairs, dtype=torch.int64)
        ctx.mark_non_differentiable(out[3], npairs_t)
        return (*out, npairs_t)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, g_rgb, g_alpha, g_dsum, _g_contrib, _g_npairs):
        from .._core import finish_images_backward, render_backward

        V, H, W = ctx.out_shape
        dt = ctx.compute_dtype

        def arr(t, shape):
            # a broadcast constant (a plain sum's gradient; zeros for an unused output) goes as a
            # stride-0 view, which the kernel fills in its own memory instead of torch
            # materialising it in fresh pages
            if t is None:
                return np.broadcast_to(np.zeros((), dtype=np.float32 if dt == torch.float32 else np.float64), shape)
            t = t.detach().to(device="cpu", dtype=dt)
            return (t if t.numel() and all(s == 0 for s in t.stride()) else t.contiguous()).numpy()

        g_rgb, g_alpha, g_dsum = arr(g_rgb, (V, H, W, 3)), arr(g_alpha, (V, H, W)), arr(g_dsum, (V, H, W))
        if ctx.finish:      # back through the background and the expected depth
            alpha, depth = ctx.finished or [t.detach().numpy() for t in ctx.saved_tensors]
            g_alpha, g_dsum = finish_images_backward(g_rgb, g_alpha, g_dsum, alpha, depth,
                                                           background=ctx.background, threads=ctx.threads)
        # only the gradients autograd asks for (a pose fit's model and cameras are constants)
        needs = [k for k, need in zip(ctx.names, ctx.needs_input_grad[1:]) if need]
        grads = render_backward(ctx.state, g_rgb, g_alpha, g_dsum, needs=needs, threads=ctx.threads)
        out = [None if k not in grads else torch.from_numpy(grads[k]).to(device=dev, dtype=t)
               for k, (t, dev) in zip(ctx.names, ctx.meta)]
        return (None, *out)


def render_native(views, width, height, *, background=None, cutoff: Cutoff = "soft", threads=None,
                  **tensors) -> RenderOut:
    """The native renderer (:class:`_Render`) with expected depth and the background added:
    ``views`` (V, 2) ``(pose, camera)`` pairs; ``tensors`` by name (see :class:`_Render`;
    None values are left out)."""
    views = np.ascontiguousarray(np.asarray(views, dtype=np.int64).reshape(-1, 2))
    named = {k: v for k, v in tensors.items() if v is not None}
    cam_bg = None
    if background is not None:
        first = next(t for k, t in named.items() if k != "body")       # a float input: the compute's dtype
        cam_bg = torch.as_tensor(background, dtype=first.dtype, device=first.device).reshape(-1, 3)
        if cam_bg.shape[0] not in (1, len(views)):          # one background per camera
            cam_bg = cam_bg[torch.as_tensor(views[:, 1], device=cam_bg.device)]
        elif cam_bg.shape[0] == 1:                          # one for every view: (3,)
            cam_bg = cam_bg[0]
    # the background and expected depth are finished in the kernel, unless the background
    # itself needs a gradient (then in torch, below)
    finish = cam_bg is None or not cam_bg.requires_grad
    if finish and "body_rot" in named and len(views) > GROUP_VIEWS:
        rgb, acc, dsum, contrib, npairs = _render_groups(views, int(width), int(height), cutoff, threads, cam_bg, named)
    else:
        spec = (tuple(named), views, int(width), int(height), cutoff, threads, finish, cam_bg if finish else None)
        rgb, acc, dsum, contrib, npairs = _Render.apply(spec, *named.values())
    if finish:
        return RenderOut(rgb, dsum, acc, int(npairs), contrib)
    assert cam_bg is not None   # finished in the kernel when there is no background
    depth = torch.where(acc > 1e-6, dsum / acc.clamp_min(1e-6), torch.zeros_like(acc))
    rgb = rgb + (1 - acc)[..., None] * cam_bg.to(rgb.dtype).reshape(-1, 1, 1, 3)
    return RenderOut(rgb, depth, acc, int(npairs), contrib)


#: Views per native call of a large rigid batch: a call's frame (projections, tile lists, the
#: composited pairs) then stays within the caches, where one call of 256 views streams every
#: stage through memory (measured: batch 64 cost 2-5 % more per view than batch 1 in one call).
GROUP_VIEWS = 16


def _render_groups(views, width, height, cutoff, threads, cam_bg, named):
    """:class:`_Render` in calls of at most :data:`GROUP_VIEWS` views (rigid mode: the bodies'
    poses are sliced per call, the Gaussians shared), outputs concatenated in view order. Images
    are the same bits as one call's (each view's pixels depend on that view alone); gradients of
    shared inputs are summed over the calls by autograd."""
    outs = []
    for v0 in range(0, len(views), GROUP_VIEWS):
        vs = views[v0:v0 + GROUP_VIEWS]
        poses, local = np.unique(vs[:, 0], return_inverse=True)
        gviews = np.ascontiguousarray(np.stack([local.reshape(-1), vs[:, 1]], 1).astype(np.int64))
        rows = torch.as_tensor(poses, device=named["body_rot"].device)
        sub = {}
        for k, t in named.items():
            if k in ("body_rot", "body_pos"):
                sub[k] = t.index_select(0, rows)
            elif (k == "opacities" and t.ndim == 2) or (k == "colors" and t.ndim == 3):   # per view
                sub[k] = t[v0:v0 + GROUP_VIEWS]
            else:
                sub[k] = t
        bg = cam_bg[v0:v0 + GROUP_VIEWS] if cam_bg is not None and cam_bg.ndim == 2 else cam_bg
        spec = (tuple(sub), gviews, width, height, cutoff, threads, True, bg)
        outs.append(_Render.apply(spec, *sub.values()))
    cat = [torch.cat([o[i] for o in outs]) for i in range(4)]
    return (*cat, sum(int(o[4]) for o in outs))


def _rasterize_rust(means, covs, opacities, colors, viewmats, Ks, width, height, background, cutoff, threads=None):
    """rasterize() on the native renderer: Gaussians shared by every camera (one pose) or
    given per camera (camera c draws pose c)."""
    C, N = viewmats.shape[0], means.shape[-2]
    per_cam = means.ndim == 3 or covs.ndim == 4
    P = C if per_cam else 1
    means, covs = means.expand(P, N, 3), covs.expand(P, N, 3, 3)
    views = [(c if per_cam else 0, c) for c in range(C)]
    return render_native(views, width, height, means=means, covs=covs, opacities=opacities, colors=colors,
                         viewmats=viewmats, Ks=Ks, background=background, cutoff=cutoff, threads=threads)


_warned = False


def _gsplat_available(device) -> bool:
    global _warned
    if device.type != "cuda":
        return False
    try:
        import gsplat  # noqa: F401
        return True
    except ImportError:
        if not _warned:
            warnings.warn("CUDA is present but gsplat is not installed: using the Rust CPU rasterizer", stacklevel=3)
            _warned = True
        return False


def _rasterize_gsplat(means, covs, opacities, colors, viewmats, Ks, width, height, background):
    """gsplat.rasterization, RGB + expected depth: one call for Gaussians shared by the C cameras,
    one per camera where they differ (means (C, N, 3)).

    gsplat evaluates pixel (i, j) at image point (j + 0.5, i + 0.5) of its K; ours puts pixel
    centres at integers (OpenCV's convention), so the principal point moves by +0.5 px in gsplat's
    K and both draw the same image."""
    from gsplat import rasterization

    Ks = Ks + Ks.new_tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0]])   # (C, 3, 3)
    C, N = viewmats.shape[0], means.shape[-2]
    kw = dict(near_plane=NEAR, eps2d=LOWPASS, render_mode="RGB+ED", packed=False)
    if means.ndim == 2 and covs.ndim == 3 and opacities.ndim == 1:
        # one scene seen by C cameras: one call; gsplat takes colors (N, 3) or exactly (C, N, 3)
        if colors.ndim == 3:
            colors = colors.expand(C, N, 3)
        img, alpha, _ = rasterization(means, None, None, opacities, colors, viewmats, Ks, width, height,
                                      covars=covs, **kw)                       # (C, H, W, 4), (C, H, W, 1)
    else:
        means, covs = means.expand(C, N, 3), covs.expand(C, N, 3, 3)
        opac, cols = opacities.expand(C, N), colors.expand(C, N, 3)
        outs = [rasterization(means[c], None, None, opac[c], cols[c], viewmats[c:c + 1], Ks[c:c + 1],
                              width, height, covars=covs[c], **kw)[:2] for c in range(C)]
        img, alpha = torch.cat([o[0] for o in outs]), torch.cat([o[1] for o in outs])
    acc = alpha[..., 0]                                                        # (C, H, W)
    rgb, depth = img[..., :3], img[..., 3] * (acc > 1e-6)
    if background is not None:
        rgb = rgb + (1 - acc)[..., None] * background.reshape(-1, 1, 1, 3)
    return RenderOut(rgb, depth, acc)


def native_backend(backend: Backend, device) -> bool:
    """Whether ``backend`` draws with the native renderer on ``device``: "rust", or "auto"
    without gsplat on CUDA."""
    return backend == "rust" or (backend == "auto" and not _gsplat_available(device))


def rasterize(means: torch.Tensor, covs: torch.Tensor, opacities: torch.Tensor, colors: torch.Tensor,
              viewmats: torch.Tensor, Ks: torch.Tensor, width: int, height: int, *,
              background: npt.ArrayLike | None = None, cutoff: Cutoff = "soft", backend: Backend = "auto",
              threads: int | None = None) -> RenderOut:
    """Render Gaussians from C cameras.

    means (N, 3) or (C, N, 3) world metres; covs (N, 3, 3) or (C, N, 3, 3) world covariances
    (m^2); opacities (N,) or (C, N) in [0, 1]; colors (N, 3) or (C, N, 3); viewmats (C, 4, 4)
    world-to-camera (OpenCV); Ks (C, 3, 3) pixel centres at integers; background (3,) or (C, 3)
    or None (black). ``cutoff``: "soft" (default) or "hard" (3DGS). ``backend``: "auto" (gsplat
    on CUDA when installed, else the Rust kernel, which copies tensors of another device to the
    CPU and its results back),
    "rust", "torch" (the reference) or "gsplat" (gsplat ignores ``cutoff``: its kernel cuts
    hard; and returns no ``contrib``; asked for by name it runs or raises
    :class:`~profrobot.errors.BackendUnavailableError`, never silently falls back). ``threads``: the Rust kernel's thread count (None: every
    core); its results are identical for any count.
    """
    if cutoff not in get_args(Cutoff):
        raise InputError(f"rasterize: cutoff must be 'soft' or 'hard'; got {cutoff!r}")
    if backend not in get_args(Backend):
        raise InputError(f"rasterize: backend must be one of {get_args(Backend)}; got {backend!r}")
    width, height = int(width), int(height)
    if width < 1 or height < 1:
        raise InputError(f"rasterize: image size must be positive; got {width}x{height}")
    _validate(means, covs, opacities, colors, viewmats, Ks)
    return rasterize_unchecked(means, covs, opacities, colors, viewmats, Ks, width, height, background=background,
                               cutoff=cutoff, backend=backend, threads=threads)


def rasterize_unchecked(means, covs, opacities, colors, viewmats, Ks, width: int, height: int, *, background=None,
                        cutoff: Cutoff = "soft", backend: Backend = "auto", threads: int | None = None) -> RenderOut:
    """:func:`rasterize` without its argument checks (shapes, NaN/inf: one host sync each), for
    loops whose inputs were validated once at their entry (``fit_pose``)."""
    width, height = int(width), int(height)
    if background is not None:
        background = torch.as_tensor(background, dtype=means.dtype, device=means.device)
    # gsplat's CUDA kernel always uses the hard cutoff; on a GPU its speed wins over exact gradients.
    # Asked for by name, gsplat runs or raises; only "auto" falls back to the Rust kernel.
    if backend == "gsplat":
        if means.device.type != "cuda":
            raise BackendUnavailableError(f"rasterize(backend='gsplat') needs CUDA tensors; got {means.device} "
                                          "(backend='auto' picks the Rust CPU kernel)")
        try:
            import gsplat  # noqa: F401
        except ImportError as e:
            raise BackendUnavailableError("rasterize(backend='gsplat'): gsplat is not installed "
                                          "(pip install gsplat), or use backend='auto'") from e
        try:
            return _rasterize_gsplat(means, covs, opacities, colors, viewmats, Ks, width, height, background)
        except (AssertionError, TypeError, RuntimeError) as e:   # gsplat checks its shapes with assert
            raise BackendUnavailableError(f"rasterize(backend='gsplat') failed: {type(e).__name__}: {e}") from e
    if backend == "auto" and _gsplat_available(means.device):
        try:
            return _rasterize_gsplat(means, covs, opacities, colors, viewmats, Ks, width, height, background)
        except (ImportError, AssertionError, TypeError, RuntimeError) as e:
            global _warned
            if not _warned:
                warnings.warn(f"gsplat rasterization failed ({e}); using the Rust CPU rasterizer", stacklevel=2)
                _warned = True
    if backend != "torch":                      # "rust", "auto" without gsplat, or gsplat failed
        return _rasterize_rust(means, covs, opacities, colors, viewmats, Ks, width, height, background, cutoff, threads)
    return _rasterize_torch(means, covs, opacities, colors, viewmats, Ks, width, height, background, cutoff)
