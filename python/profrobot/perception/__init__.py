"""Perception: what the cameras say about the world.

- :mod:`.layouts`: a family's layout δ estimated from calibrated depth images;
- :mod:`.clouds`: depth images → a point-cloud obstacle (the robot's own points removed).
"""

from __future__ import annotations

from .clouds import CloudBuild, cloud_from_depth
from .layouts import LayoutEstimate, estimate_layout

__all__ = ["estimate_layout", "LayoutEstimate", "cloud_from_depth", "CloudBuild"]
