"""Target images and the image loss every pose-from-images method descends (paper §4.3).

For a render ``out`` of the Gaussian robot and targets ``I*`` (RGB in [0, 1]), ``D*`` (metres)
and robot masks ``M*``, per image:

    L = mean_{M} |I - I*|^2                          (L_RGB on M = M* | alpha > 1/2: a robot drawn
                                                      in the wrong place is penalised too)
      + w_depth * mean_{M* & alpha > 1/2} |D - D*|   (L_D, metres)
      + w_mask  * mean |alpha - M*|                  (silhouette)

:class:`ImageTargets` validates a batch of targets and their cameras once, at entry, and then
evaluates that loss for any rows of poses without host syncs: :func:`profrobot.render.fit_pose`,
:func:`profrobot.inverse.pose_from_images`, ``trajectory_from_images`` and
``actions_from_video`` all go through it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError

__all__ = ["pose_loss", "ImageTargets"]


def pose_loss(out, rgb_t: torch.Tensor, depth_t: torch.Tensor, mask_t: torch.Tensor, *, w_depth: float = 1.0,
              w_mask: float = 0.5) -> torch.Tensor:
    """Per-image loss (N,) of renders ``out`` (a :class:`~profrobot.render.RenderOut` of N images)
    against targets ``rgb_t`` (N, H, W, 3) in [0, 1], ``depth_t`` (N, H, W) metres, ``mask_t``
    (N, H, W) bool (module docs)."""
    mt = mask_t.to(out.rgb.dtype)
    drawn = (out.alpha.detach() > 0.5).to(out.rgb.dtype)
    m = torch.maximum(mt, drawn)
    msum = m.sum((1, 2)).clamp_min(1)
    l_rgb = (((out.rgb - rgb_t) ** 2).sum(-1) * m).sum((1, 2)) / msum
    md = mt * drawn
    l_d = ((out.depth - depth_t).abs() * md).sum((1, 2)) / md.sum((1, 2)).clamp_min(1)
    l_m = (out.alpha - mt).abs().mean((1, 2))
    return l_rgb + w_depth * l_d + w_mask * l_m


def _as_batch(x, name: str, shape_tail: tuple, B: int, C: int, who: str) -> torch.Tensor:
    """``x`` as a (B, C, *shape_tail) tensor (a leading B may be left out when B == 1); uint8
    images become [0, 1] floats."""
    t = torch.as_tensor(np.asarray(x))
    if t.dtype == torch.uint8:
        t = t.to(torch.float32) / 255.0
    if t.ndim == len(shape_tail) + 1 and B == 1:
        t = t[None]
    if t.shape[:2] != (B, C) or tuple(t.shape[2:]) != tuple(shape_tail):
        raise InputError(f"{who}: {name} must have shape ({B}, {C}, {', '.join(map(str, shape_tail))}) for {B} "
                         f"target{'s' * (B != 1)} seen by {C} camera{'s' * (C != 1)}; got {tuple(t.shape)}")
    return t


@dataclass(eq=False)
class ImageTargets:
    """B targets, each seen by the same C cameras, validated once and kept as tensors on one
    device (float32), flattened pose-major so that image ``b * C + c`` is target b, camera c.

    Attributes:
        rgb: (B·C, H, W, 3) in [0, 1]; depth: (B·C, H, W) metres; mask: (B·C, H, W) bool.
        viewmats: (C, 4, 4) world-to-camera (OpenCV); Ks: (C, 3, 3); width, height: pixels.
        background: (3,) RGB in [0, 1] or None (black).
        w_depth, w_mask: the loss weights (module docs).
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

    @classmethod
    def from_images(cls, targets: dict, cameras, B: int, *, device=None, background=None, w_depth: float = 1.0,
                    w_mask: float = 0.5, who: str = "targets") -> "ImageTargets":
        """``targets``: dict of ``rgb`` (B, C, H, W, 3) uint8 or [0, 1], ``depth`` (B, C, H, W)
        metres, ``mask`` (B, C, H, W) bool (the leading B may be left out when B == 1);
        ``cameras``: the C :class:`~profrobot.render.Cameras`. Errors name ``who`` and the entry."""
        if not isinstance(targets, dict) or not {"rgb", "depth", "mask"} <= set(targets):
            raise InputError(f"{who}: targets must be a dict with 'rgb', 'depth' and 'mask'")
        C, H, W = len(cameras), cameras.height, cameras.width
        rgb = _as_batch(targets["rgb"], "rgb", (H, W, 3), B, C, who).float()
        depth = _as_batch(targets["depth"], "depth", (H, W), B, C, who).float()
        mask = _as_batch(targets["mask"], "mask", (H, W), B, C, who).bool()
        if not (torch.isfinite(rgb).all() and torch.isfinite(depth).all()):
            raise InputError(f"{who}: targets contain NaN or inf")
        vm = torch.as_tensor(np.asarray(cameras.world_to_cam), dtype=torch.float32, device=device)
        Ks = torch.as_tensor(np.asarray(cameras.K), dtype=torch.float32, device=device)
        if vm.shape != (C, 4, 4) or Ks.shape != (C, 3, 3):
            raise InputError(f"{who}: cameras need world_to_cam ({C}, 4, 4) and K ({C}, 3, 3); "
                             f"got {tuple(vm.shape)} and {tuple(Ks.shape)}")
        bg = None if background is None else torch.as_tensor(np.asarray(background), dtype=torch.float32,
                                                              device=device)
        for name, t in (("cameras", vm), ("cameras", Ks), ("background", bg)):
            if t is not None and not torch.isfinite(t).all():
                raise InputError(f"{who}: {name} contains NaN or inf")
        flat = lambda t: t.reshape(B * C, *t.shape[2:]).to(device)
        return cls(flat(rgb), flat(depth), flat(mask), vm, Ks, W, H, bg, float(w_depth), float(w_mask))

    @property
    def cameras(self) -> int:
        """C, the number of views per target."""
        return self.viewmats.shape[0]

    def __len__(self) -> int:
        """B, the number of targets."""
        return self.rgb.shape[0] // self.cameras

    def take(self, rows) -> "ImageTargets":
        """The targets ``rows`` (R,) (repeats allowed, e.g. one per restart), gathered once."""
        C = self.cameras
        rows = torch.as_tensor(rows, dtype=torch.long, device=self.rgb.device).reshape(-1)
        sel = (rows[:, None] * C + torch.arange(C, device=rows.device)).reshape(-1)
        return ImageTargets(self.rgb[sel], self.depth[sel], self.mask[sel], self.viewmats, self.Ks, self.width,
                            self.height, self.background, self.w_depth, self.w_mask)

    def render(self, model, theta: torch.Tensor):
        """``model`` (a :class:`~profrobot.render.GaussianRobot`) drawn at ``theta`` (R, K) from
        these cameras: a RenderOut of R·C images, pose-major."""
        return model.render_unchecked(theta, self.viewmats, self.Ks, self.width, self.height,
                                      background=self.background)

    def losses(self, model, theta: torch.Tensor, rows=None) -> torch.Tensor:
        """(R,) image loss of poses ``theta`` (R, K) against targets ``rows`` (R,) (default: all
        B, in order), each the mean over the C views."""
        tg = self if rows is None else self.take(rows)
        if theta.shape[0] != len(tg):
            raise InputError(f"{theta.shape[0]} poses for {len(tg)} targets")
        out = tg.render(model, theta)
        return pose_loss(out, tg.rgb, tg.depth, tg.mask, w_depth=self.w_depth,
                         w_mask=self.w_mask).reshape(-1, self.cameras).mean(1)
