"""Differentiable robot splat renderer (Dr. Robot-style), pure PyTorch on a CPU, gsplat on CUDA.

- :mod:`.views`: MuJoCo multi-view data (RGB, metric depth, robot mask) and OpenCV cameras;
- :mod:`.gaussians`: :class:`GaussianRobot`, Gaussians attached to the bodies, moved by FK;
- :mod:`.rasterize`: EWA splatting with front-to-back compositing (RGB, depth, alpha);
- :mod:`.fit`: appearance/geometry fit to MuJoCo renders (L1 + SSIM + depth, densification);
- :mod:`.pose`: :func:`fit_pose`, joint angles from images.
"""

from .gaussians import GaussianRobot
from .rasterize import RenderOut, rasterize
from .views import Cameras, Views, make_views, ring_cameras, sphere_cameras

__all__ = ["make_views", "Cameras", "Views", "ring_cameras", "sphere_cameras", "GaussianRobot", "rasterize",
           "RenderOut"]
from .fit import fit_gaussians  # noqa: E402
from .pose import PoseFit, fit_pose  # noqa: E402

__all__ += ["fit_gaussians", "fit_pose", "PoseFit"]
