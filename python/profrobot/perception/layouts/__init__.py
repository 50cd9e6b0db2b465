"""Where the obstacles are: a family's layout δ estimated from calibrated depth images, and used
safely.

- :mod:`.depth`: depth images to world points (:func:`backproject`), and what a model expects
  each pixel to see (:func:`expected_depth`, MuJoCo's ray caster);
- :mod:`.shapes`: exact signed distances of the obstacles' shapes;
- :mod:`.fit`: the robust Gauss–Newton fit of each obstacle's scene joints;
- :mod:`.estimate`: :func:`estimate_layout` → :class:`LayoutEstimate` (δ, support, residual, a
  suggested safety ``margin``);
- :mod:`.picture`: the points, the robot's removed points and the fitted obstacles.

Use an estimate with ``margin=estimate.margin`` (:mod:`profrobot.robot.margin`), or
``estimate.robot(family)``.
"""

from __future__ import annotations

from .depth import DepthPoints, backproject, expected_depth
from .estimate import LayoutEstimate, estimate_layout

__all__ = ["estimate_layout", "LayoutEstimate", "backproject", "expected_depth", "DepthPoints"]
