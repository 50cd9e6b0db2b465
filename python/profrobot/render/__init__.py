"""Differentiable robot splat renderer (Dr. Robot-style): on a CPU one native call each way for
skinning, projection, SH colour and tile rasterization; gsplat on CUDA; a pure-PyTorch reference.

- :mod:`.cameras`: one pinhole camera model (OpenCV K and world_to_cam; calibrated, look-at, MJCF and
  MuJoCo free cameras; JSON) that MuJoCo, both rasterizers, fits and pictures share (:class:`Cameras`);
- :mod:`.distortion`: OpenCV lens distortion (k1, k2, p1, p2, k3), undone once on target images;
- :mod:`.views`: multi-view data (RGB, metric depth, robot mask; :class:`Views`, :func:`make_views`);
- :mod:`.mjviews`: MuJoCo's offscreen renderer and the chunk functions that draw in workers;
- :mod:`.gaussians`: :class:`GaussianRobot`, Gaussians attached to the bodies, moved by FK;
- :mod:`.rasterizer`: EWA splatting with front-to-back compositing (RGB, depth, alpha); backends
  ``rust`` (``rust/bindings/render.rs``, ``rust/render/splat.rs``), ``torch``, ``gsplat``;
- :mod:`.fit`: appearance/geometry fit to MuJoCo renders (L1 + SSIM + depth, densification);
- :mod:`.targets`: target images (photos with masks, depth optional, any resolution) validated once and
  the image loss (:class:`ImageTargets`);
- :mod:`.pose`: :func:`fit_pose`, joint angles from images.

The MuJoCo side (:mod:`.cameras`, :mod:`.views`, :mod:`.mjviews`) needs no torch; the torch side loads
on first use of its names.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from .cameras import Cameras, ring_cameras, sphere_cameras
from .mjviews import robot_visual_model
from .views import Views, make_views, render_depth

if TYPE_CHECKING:  # the torch side's names, for type checkers and the API reference (loaded on first use)
    from .fit import fit_gaussians
    from .gaussians import GaussianRobot, frozen
    from .pose import PoseFit, fit_pose
    from .rasterizer import RenderOut, rasterize
    from .targets import ImageTargets, pose_loss

_LAZY = {"GaussianRobot": ".gaussians", "frozen": ".gaussians", "rasterize": ".rasterizer", "RenderOut": ".rasterizer",
         "fit_gaussians": ".fit", "fit_pose": ".pose", "PoseFit": ".pose", "ImageTargets": ".targets",
         "pose_loss": ".targets"}

__all__ = ["make_views", "render_depth", "Cameras", "Views", "ring_cameras", "sphere_cameras", "robot_visual_model", "GaussianRobot",
           "frozen", "rasterize", "RenderOut", "fit_gaussians", "fit_pose", "PoseFit", "ImageTargets", "pose_loss"]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
