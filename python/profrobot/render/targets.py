"""Target images and the image loss every pose-from-images method descends (paper §4.3).

For a render ``out`` of the Gaussian robot and targets ``I*`` (RGB in [0, 1]), ``D*`` (metres)
and robot masks ``M*``, per image:

    L = mean_{M*} |I - I*|^2                         (L_RGB on the target's robot mask only: pixels
                                                      outside it, a photo's background, never pull)
      + w_depth * mean_{M* & alpha > 1/2} |D - D*|   (L_D, metres; left out without depth)
      + w_mask  * mean |alpha - M*|                  (silhouette: a robot drawn in the wrong place)

and a target's loss is the weighted mean of its C views' (per-view ``weights``, default 1).

Targets as they come from the world (:func:`as_pinhole_targets`): ``rgb`` with a ``mask`` (from a
segmenter) and no depth, or ``depth`` with no mask (the mask is then ``depth > 0``); images at any
resolution (the cameras are rescaled to it, :meth:`Cameras.resized`, keeping pixel edges); lens
distortion undistorted once (:mod:`profrobot.render.distortion`).

:class:`ImageTargets` validates a batch of targets and their cameras once, at entry, and then
evaluates that loss for any rows of poses without host syncs: :func:`profrobot.render.fit_pose`,
:func:`profrobot.inverse.pose_from_images`, ``trajectory_from_images`` and
``actions_from_video`` all go through it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import torch

from ..errors import InputError
from .cameras import Cameras
from .gaussians import GaussianRobot
from .rasterizer import RenderOut
from .distortion import undistort_images, undistort_map

__all__ = ["pose_loss", "ImageTargets", "as_pinhole_targets"]


def _np(t: torch.Tensor) -> np.ndarray:
    """A CPU tensor's values as a contiguous numpy array (no copy when already contiguous)."""
    return t.detach().contiguous().numpy()


class _ImageLoss(torch.autograd.Function):
    """:func:`pose_loss` on CPU tensors in one native pass each way (``rust/bindings/images.rs``; the
    same formula, term for term): forward(rgb [N, H, W, 3], alpha [N, H, W], depth [N, H, W],
    rgb_t, depth_t, mask_t, valid, w_depth, w_mask) -> [N]; gradients reach rgb, alpha and
    depth."""

    @staticmethod
    def forward(ctx, rgb, alpha, depth, rgb_t, depth_t, mask_t, valid, w_depth, w_mask):
        from .._core import image_loss

        dt = rgb.dtype
        rgb_t, depth_t = rgb_t.to(dt), depth_t.to(dt)
        ctx.weights = dict(w_depth=float(w_depth), w_mask=float(w_mask))
        # the targets too: an edit between forward and backward is then caught, not silently used
        ctx.save_for_backward(rgb, alpha, depth, rgb_t, depth_t, mask_t, valid)
        loss = image_loss(_np(rgb), _np(alpha), _np(depth), _np(rgb_t), _np(depth_t), _np(mask_t),
                                valid=None if valid is None else _np(valid), **ctx.weights)
        return torch.from_numpy(loss)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, g_loss):
        from .._core import image_loss_backward

        rgb, alpha, depth, rgb_t, depth_t, mask_t, valid = ctx.saved_tensors
        g_rgb, g_alpha, g_depth = image_loss_backward(_np(g_loss.to(rgb.dtype)), _np(rgb), _np(alpha), _np(depth),
                                                            _np(rgb_t), _np(depth_t), _np(mask_t),
                                                            valid=None if valid is None else _np(valid), **ctx.weights)
        return (torch.from_numpy(g_rgb), torch.from_numpy(g_alpha), torch.from_numpy(g_depth),
                None, None, None, None, None, None)


def _native_loss(out, rgb_t, depth_t, mask_t, valid, w_depth, w_mask) -> bool:
    """Whether :func:`pose_loss` runs natively, where it gives what torch gives: every tensor on
    the CPU; the renders float32 or float64 alike, the targets no wider (torch would promote),
    each of the renders' shape (no broadcasting); the masks bool; the weights plain numbers; no
    gradient wanted for a target."""
    imgs = (out.rgb, out.alpha, out.depth)
    dt = out.rgb.dtype
    if dt not in (torch.float32, torch.float64) or any(t.dtype != dt for t in imgs):
        return False
    if not all(isinstance(w, (int, float)) for w in (w_depth, w_mask)):
        return False
    ts = [t for t in (rgb_t, depth_t, mask_t, valid) if t is not None]
    widest = torch.float64 if dt == torch.float64 else torch.float32
    return (all(t.device.type == "cpu" for t in (*imgs, *ts)) and not any(t.requires_grad for t in ts)
            and rgb_t.shape == out.rgb.shape and all(t.shape == out.alpha.shape for t in ts[1:])
            and all(t.dtype in (torch.float32, widest) for t in (rgb_t, depth_t))
            and all(t.dtype == torch.bool for t in ts[2:]))


def pose_loss(out: RenderOut, rgb_t: torch.Tensor, depth_t: torch.Tensor, mask_t: torch.Tensor, *, w_depth: float = 1.0,
              w_mask: float = 0.5, valid: torch.Tensor | None = None) -> torch.Tensor:
    """Per-image loss (N,) of renders ``out`` (a :class:`~profrobot.render.RenderOut` of N images)
    against targets ``rgb_t`` (N, H, W, 3) in [0, 1], ``depth_t`` (N, H, W) metres, ``mask_t``
    (N, H, W) bool (module docs); ``valid`` (N, H, W) bool: pixels the photo saw (after
    undistortion, a lens may leave corners unseen), the only ones the silhouette term counts.
    On the CPU one native pass each way (``rust/bindings/images.rs``), elsewhere torch; the same
    formula."""
    if _native_loss(out, rgb_t, depth_t, mask_t, valid, w_depth, w_mask):
        return _ImageLoss.apply(out.rgb, out.alpha, out.depth, rgb_t, depth_t, mask_t, valid, w_depth, w_mask)
    return _pose_loss_torch(out, rgb_t, depth_t, mask_t, w_depth=w_depth, w_mask=w_mask, valid=valid)


def _pose_loss_torch(out, rgb_t, depth_t, mask_t, *, w_depth: float = 1.0, w_mask: float = 0.5, valid=None):
    """:func:`pose_loss` in torch (any device; the reference the native pass is tested on)."""
    mt = mask_t.to(out.rgb.dtype)
    drawn = (out.alpha.detach() > 0.5).to(out.rgb.dtype)
    l_rgb = (((out.rgb - rgb_t) ** 2).sum(-1) * mt).sum((1, 2)) / mt.sum((1, 2)).clamp_min(1)
    if valid is None:
        l_mask = (out.alpha - mt).abs().mean((1, 2))
    else:
        v = valid.to(out.rgb.dtype)
        l_mask = ((out.alpha - mt).abs() * v).sum((1, 2)) / v.sum((1, 2)).clamp_min(1)
    loss = l_rgb + w_mask * l_mask
    if w_depth:
        md = mt * drawn
        loss = loss + w_depth * ((out.depth - depth_t).abs() * md).sum((1, 2)) / md.sum((1, 2)).clamp_min(1)
    return loss


def _shape_of(x, name: str, tail: tuple, B: int, C: int, who: str) -> np.ndarray:
    """``x`` as a (B, C, *tail) array (a leading B may be left out when B == 1); ``tail`` may hold
    None for "any size"."""
    a = np.asarray(x)
    if a.ndim == len(tail) + 1 and B == 1:
        a = a[None]
    ok = a.ndim == len(tail) + 2 and a.shape[:2] == (B, C) and all(t is None or t == n for t, n in zip(tail, a.shape[2:]))
    if not ok:
        want = ", ".join("H" if i == 0 and t is None else "W" if t is None else str(t) for i, t in enumerate(tail))
        raise InputError(f"{who}: {name} must have shape ({B}, {C}, {want}) for {B} target{'s' * (B != 1)} seen by "
                         f"{C} camera{'s' * (C != 1)}; got {a.shape}")
    return a


def as_pinhole_targets(targets: dict, cameras: Cameras, B: int, who: str = "targets") -> tuple[dict, Cameras]:
    """``targets`` and ``cameras`` made ready for the loss: the cameras rescaled to the images'
    size, the images undistorted if the cameras have lens distortion, a mask from ``depth > 0``
    where none is given, a zero depth and ``has_depth=False`` where none is given.

    ``targets``: dict of ``rgb`` (B, C, H, W, 3) uint8 or [0, 1] floats, and ``mask`` (B, C, H, W)
    bool and/or ``depth`` (B, C, H, W) metres (0 off the robot), optionally ``weights`` (C,) or
    (B, C) per-view weights >= 0 (the leading B may be left out when B == 1). Returns
    ``(dict(rgb, depth, mask, weights, has_depth[, valid]), cameras)`` as numpy (B, C, ...)
    arrays; ``valid`` (C, H, W), present when undistortion left pixels no photo pixel covers
    (they count in no term of the loss)."""
    if not isinstance(targets, dict) or "rgb" not in targets:
        raise InputError(f"{who}: targets must be a dict with 'rgb' and at least one of 'mask' and 'depth'")
    if not isinstance(cameras, Cameras):
        raise InputError(f"{who}: cameras must be a profrobot.render.Cameras; got {type(cameras).__name__}")
    unknown = set(targets) - {"rgb", "depth", "mask", "weights", "has_depth", "valid"}
    if unknown:
        raise InputError(f"{who}: unknown target keys {sorted(unknown)} (rgb, mask, depth, weights)")
    C = len(cameras)
    rgb = _shape_of(targets["rgb"], "rgb", (None, None, 3), B, C, who)
    H, W = rgb.shape[2:4]
    depth, mask = targets.get("depth"), targets.get("mask")
    if depth is None and mask is None:
        raise InputError(f"{who}: targets need a 'mask' (the robot's pixels, e.g. from a segmenter) or a 'depth' "
                         "(metres, 0 off the robot): without either the background would pull the pose")
    depth = None if depth is None else _shape_of(depth, "depth", (H, W), B, C, who).astype(np.float32)
    mask = None if mask is None else _shape_of(mask, "mask", (H, W), B, C, who).astype(bool)
    if depth is not None and not np.isfinite(depth).all():
        raise InputError(f"{who}: depth contains NaN or inf")
    if depth is not None and (depth < 0).any():
        raise InputError(f"{who}: depth must be >= 0 metres (0 off the robot)")
    valid = targets.get("valid")
    valid = None if valid is None else np.asarray(valid, dtype=bool)
    weights = targets.get("weights")
    if weights is None:
        weights = np.ones((B, C), np.float32)
    else:
        weights = np.asarray(weights, dtype=np.float32)
        weights = np.broadcast_to(weights, (B, C)).copy() if weights.shape in ((C,), (B, C)) else None
        if weights is None or not np.isfinite(weights).all() or (weights < 0).any() or (weights.sum(1) <= 0).any():
            raise InputError(f"{who}: weights must be finite, >= 0, shape ({C},) or ({B}, {C}), with a positive sum per target")
    if (W, H) != (cameras.width, cameras.height):
        # targets at any resolution: K follows the pixels (pixel edges kept; a free camera's own
        # resizing keeps its fovy and square pixels instead, so it goes through its matrices)
        if cameras.is_free:
            cameras = Cameras.from_opencv(cameras.K, cameras.world_to_cam, cameras.width, cameras.height)
        cameras = cameras.resized(W, H)
    if cameras.distortion is not None:
        K, dist = cameras.K, cameras.distortion
        rgb = undistort_images(rgb, K, dist, kind="rgb")
        mask = None if mask is None else undistort_images(mask, K, dist, kind="mask")
        depth = None if depth is None else undistort_images(depth, K, dist, kind="depth")
        m = np.stack([undistort_map(K[c], dist[c], W, H) for c in range(len(K))])       # (C, H, W, 2)
        valid = (m[..., 0] >= -0.5) & (m[..., 0] <= W - 0.5) & (m[..., 1] >= -0.5) & (m[..., 1] <= H - 0.5)
        cameras = cameras.undistorted()
    has_depth = depth is not None and bool(targets.get("has_depth", True))
    if mask is None:
        assert depth is not None   # a mask or a depth (checked above)
        mask = depth > 0
    if depth is None:
        depth = np.zeros(mask.shape, np.float32)
    out = dict(rgb=rgb, depth=depth, mask=mask, weights=weights, has_depth=has_depth)
    if valid is not None and not valid.all():
        out["valid"] = valid
    return out, cameras


@dataclass(eq=False)
class ImageTargets:
    """B targets, each seen by the same C cameras, validated once and kept as tensors on one
    device (float32), flattened pose-major so that image ``b * C + c`` is target b, camera c.

    Attributes:
        rgb: (B·C, H, W, 3) in [0, 1]; depth: (B·C, H, W) metres; mask: (B·C, H, W) bool.
        viewmats: (C, 4, 4) world-to-camera (OpenCV); Ks: (C, 3, 3); width, height: pixels.
        background: (3,) RGB in [0, 1] or None (black).
        w_depth, w_mask: the loss weights (module docs); w_depth is 0 for targets without depth.
        weights: (B·C,) per-view weights; valid: (C, H, W) bool, the pixels a photo saw (None: all).
    """

    rgb: torch.Tensor
    depth: torch.Tensor
    mask: torch.Tensor
    viewmats: torch.Tensor
    Ks: torch.Tensor
    width: int
    height: int
    background: torch.Tensor | None
    w_depth: float = 1.0
    w_mask: float = 0.5
    weights: torch.Tensor | None = None
    valid: torch.Tensor | None = None

    @classmethod
    def from_images(cls, targets: dict, cameras: Cameras, B: int, *, device: torch.device | str | None = None,
                    background: npt.ArrayLike | None = None, w_depth: float = 1.0, w_mask: float = 0.5,
                    who: str = "targets") -> "ImageTargets":
        """``targets``: dict of ``rgb`` (B, C, H, W, 3) uint8 or [0, 1], and ``mask`` (B, C, H, W)
        bool and/or ``depth`` (B, C, H, W) metres, optionally ``weights`` (C,) or (B, C) (the
        leading B may be left out when B == 1; :func:`as_pinhole_targets`); ``cameras``: the C
        :class:`~profrobot.render.Cameras`. Errors name ``who`` and the entry."""
        t, cameras = as_pinhole_targets(targets, cameras, B, who)
        C, H, W = len(cameras), cameras.height, cameras.width
        rgb = torch.as_tensor(t["rgb"])
        rgb = rgb.to(torch.float32) / 255.0 if rgb.dtype == torch.uint8 else rgb.float()
        depth, mask = torch.as_tensor(t["depth"]), torch.as_tensor(t["mask"])
        if not torch.isfinite(rgb).all():
            raise InputError(f"{who}: targets contain NaN or inf")
        vm = torch.as_tensor(np.asarray(cameras.world_to_cam), dtype=torch.float32, device=device)
        Ks = torch.as_tensor(np.asarray(cameras.K), dtype=torch.float32, device=device)
        bg = None if background is None else torch.as_tensor(np.asarray(background), dtype=torch.float32,
                                                              device=device)
        if bg is not None and not torch.isfinite(bg).all():
            raise InputError(f"{who}: background contains NaN or inf")
        flat = lambda t: t.reshape(B * C, *t.shape[2:]).to(device)
        wts = torch.as_tensor(t["weights"], dtype=torch.float32).reshape(B * C).to(device)
        valid = None if "valid" not in t else torch.as_tensor(t["valid"]).to(device)       # (C, H, W)
        return cls(flat(rgb), flat(depth), flat(mask), vm, Ks, W, H, bg, float(w_depth) if t["has_depth"] else 0.0,
                   float(w_mask), wts, valid)

    @property
    def cameras(self) -> int:
        """C, the number of views per target."""
        return self.viewmats.shape[0]

    def __len__(self) -> int:
        """B, the number of targets."""
        return self.rgb.shape[0] // self.cameras

    def take(self, rows: npt.ArrayLike) -> "ImageTargets":
        """The targets ``rows`` (R,) (repeats allowed, e.g. one per restart), gathered once."""
        C = self.cameras
        rows = torch.as_tensor(rows, dtype=torch.long, device=self.rgb.device).reshape(-1)
        sel = (rows[:, None] * C + torch.arange(C, device=rows.device)).reshape(-1)
        return ImageTargets(self.rgb[sel], self.depth[sel], self.mask[sel], self.viewmats, self.Ks, self.width,
                            self.height, self.background, self.w_depth, self.w_mask, self.view_weights[sel], self.valid)

    @property
    def view_weights(self) -> torch.Tensor:
        """(B·C,) per-view weights (ones unless given)."""
        return self.weights if self.weights is not None else torch.ones(self.rgb.shape[0], device=self.rgb.device)

    def render(self, model: GaussianRobot, theta: torch.Tensor, viewmats: torch.Tensor | None = None) -> RenderOut:
        """``model`` (a :class:`~profrobot.render.GaussianRobot`) drawn at ``theta`` (R, K) from
        these cameras (or from ``viewmats`` (C, 4, 4), e.g. refined ones, differentiably): a
        RenderOut of R·C images, pose-major."""
        return model.render_unchecked(theta, self.viewmats if viewmats is None else viewmats, self.Ks, self.width,
                                      self.height, background=self.background)

    def losses(self, model: GaussianRobot, theta: torch.Tensor, rows: npt.ArrayLike | None = None,
               viewmats: torch.Tensor | None = None) -> torch.Tensor:
        """(R,) image loss of poses ``theta`` (R, K) against targets ``rows`` (R,) (default: all
        B, in order), each the weighted mean over the C views; ``viewmats`` as in :meth:`render`."""
        tg = self if rows is None else self.take(rows)
        if theta.shape[0] != len(tg):
            raise InputError(f"{theta.shape[0]} poses for {len(tg)} targets")
        out = tg.render(model, theta, viewmats)
        valid = None if tg.valid is None else tg.valid.repeat(len(tg), 1, 1)             # (R·C, H, W)
        per = pose_loss(out, tg.rgb, tg.depth, tg.mask, w_depth=self.w_depth, w_mask=self.w_mask,
                        valid=valid).reshape(-1, self.cameras)
        w = tg.view_weights.reshape(-1, self.cameras)
        return (per * w).sum(1) / w.sum(1)
