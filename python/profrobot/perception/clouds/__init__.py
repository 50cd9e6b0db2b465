"""From a depth camera to a point-cloud obstacle (:class:`~profrobot.PointCloud`).

- :mod:`.depth`: :func:`cloud_from_depth`: calibrated depth images back-projected (lens distortion
  undone), the robot's own points removed at its known pose (and, by default, the modelled static
  scene's), conservative voxel downsampling; each step timed (:class:`CloudBuild`);
- :mod:`.picture`: the cloud, the robot and a planned path, from above and from a camera.

Use the cloud with :meth:`profrobot.Robot.with_points`; the labeller, certification and planning
then keep clear of it exactly (:mod:`profrobot.robot.pointcloud`).
"""

from __future__ import annotations

from .depth import CloudBuild, cloud_from_depth, self_filter
from .picture import cloud_picture

__all__ = ["cloud_from_depth", "CloudBuild", "self_filter", "cloud_picture"]
