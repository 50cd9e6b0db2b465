"""Depth images to a point-cloud obstacle: back-projection, the self-filter, downsampling.

1. **Back-projection** (:func:`profrobot.perception.layouts.backproject`): each valid pixel ``(u, v)`` of depth
   ``z`` (metres along the camera's z axis; 0 / NaN missing) becomes the world point
   ``Rᵀ (z · ((u − cx)/fx, (v − cy)/fy, 1) − t)``; distorted cameras have their depth undistorted
   first (OpenCV's model, nearest sampling). Each point's radius is the sensor's resolution there:
   one pixel's footprint ``z / min(fx, fy)`` (or ``radius=`` metres).
2. **The self-filter** (``rust/collision/filter.rs``): points within ``padding`` metres of the robot's geoms at
   its known ``pose`` are the robot's own and are removed (MoveIt's ``robot_self_filter`` padding,
   computed exactly against the collision geoms); with ``static=`` metres, points that close to the
   modelled static scene (floor, table, modelled obstacles) are removed too: the model already has
   them.
3. **Conservative voxel downsampling** (``rust/geometry/cloud.rs``): the balls grouped by ``voxel``-metre
   cubes, each group replaced by one ball about its mean that reaches every ball of the group: every
   removed point lies inside a kept ball, so a pose free of the result is free of every point.

What the result covers is what the cameras saw: surfaces (within the radii), not the space behind
them nor what no camera saw.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from ...robot import gate
from ...errors import InputError
from ..layouts.depth import backproject
from ...robot.pointcloud import PointCloud
from ...render.cameras import Cameras
from ...robot.family import Layout
from ...robot.robot import Robot

__all__ = ["cloud_from_depth", "CloudBuild", "self_filter"]


@dataclass(frozen=True)
class CloudBuild:
    """What :func:`cloud_from_depth` did: the ``cloud``, how many points each step kept, and each
    step's wall time in seconds (``seconds``: ``backproject``, ``filter``, ``downsample``,
    ``total``)."""

    cloud: PointCloud
    pixels: int            # valid pixels back-projected
    robot_points: int      # removed as the robot's own
    static_points: int     # removed as the modelled static scene's
    kept_points: int       # before downsampling
    seconds: dict = field(default_factory=dict)

    def summary(self) -> str:
        s = self.seconds
        return (f"{self.pixels} pixels → {self.robot_points} robot, {self.static_points} static removed → "
                f"{self.kept_points} points → {len(self.cloud)} balls; "
                + ", ".join(f"{k} {1e3 * v:.1f} ms" for k, v in s.items()))


def self_filter(robot: Robot, pose: npt.ArrayLike, points: npt.ArrayLike, *, layout: Layout | None = None,
                padding: float = 0.02, static: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(robot, static)``: two (N,) bool masks over ``points`` (N, 3, world metres): within
    ``padding`` metres of the robot's collision geoms at ``pose`` (K,), and, with ``static``
    metres, that close to the model's other geoms (floor, table, modelled obstacles; the point
    cloud excepted) and not the robot's. Exact against the geoms (``rust/collision/filter.rs``).
    ``layout``: a family's layout δ, ``pose`` then its θ (:mod:`profrobot.robot.gate`)."""
    robot = gate.robot_at(robot, layout=layout, family=True)
    q = gate.as_poses(robot, pose, name="pose")
    if len(q) != 1:
        raise InputError(f"pose must be one pose of {robot.njoint} joints; got {len(q)}")
    m = gate.positive("padding", padding, allow_zero=True)
    s = None if static is None else gate.positive("static", static, allow_zero=True)
    p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    kind = robot.core.points_near(q, p, m, s)
    return kind == 1, kind == 2


def cloud_from_depth(robot: Robot, depth: npt.ArrayLike, cameras: Cameras, *, pose: npt.ArrayLike,
                     layout: Layout | None = None, radius: float | None = None, voxel: float | None = 0.01, padding: float = 0.02,
                     static: float | None = 0.005, max_depth: float | None = None) -> CloudBuild:
    """The point-cloud obstacle of calibrated depth images (module docs): ``depth`` (C, H, W)
    metres along each camera's z axis (0 / NaN: no reading) from ``cameras``, the robot at ``pose``
    (K,) in them.

    ``layout``: a family's layout δ (:mod:`profrobot.robot.gate`): ``pose`` is then its θ and the
    static scene the family's at δ; a family without one takes a full ``pose`` (θ and δ). No
    ``margin``: ``padding`` is how far around the robot a point counts as its own; a margin for the
    answers about the cloud is given where they are asked (``label_poses(..., margin=)``).
    ``radius``: metres per point (default: each pixel's footprint ``z / f``); ``voxel``: the
    downsampling cube in metres (None: none); ``padding``: the self-filter's padding around the
    robot's geoms, metres; ``static``: that around the modelled static scene (None keeps those
    points); ``max_depth``: readings farther than this (metres) are dropped. Returns a
    :class:`CloudBuild` (``.cloud`` is the :class:`~profrobot.PointCloud`)."""
    t0 = time.perf_counter()
    if max_depth is not None:
        max_depth = gate.positive("max_depth", max_depth)
    if radius is not None:
        radius = gate.positive("radius", radius, allow_zero=True)
    if voxel is not None:
        voxel = gate.positive("voxel", voxel)
    dp = backproject(depth, cameras)
    pts, z, cam = dp.points, dp.depth, dp.camera
    if max_depth is not None:
        keep = z <= max_depth
        pts, z, cam = pts[keep], z[keep], cam[keep]
    t1 = time.perf_counter()
    own, near_static = self_filter(robot, pose, pts, layout=layout, padding=padding, static=static)
    keep = ~(own | near_static)
    t2 = time.perf_counter()
    if radius is None:
        f = np.minimum(cameras.K[:, 0, 0], cameras.K[:, 1, 1])
        r = z[keep] / f[cam[keep]]
    else:
        r = np.full(int(keep.sum()), radius)
    cloud = PointCloud(pts[keep], r)
    if voxel is not None:
        cloud = cloud.downsample(voxel)
    t3 = time.perf_counter()
    return CloudBuild(cloud=cloud, pixels=len(dp), robot_points=int(own.sum()), static_points=int(near_static.sum()),
                      kept_points=int(keep.sum()),
                      seconds=dict(backproject=t1 - t0, filter=t2 - t1, downsample=t3 - t2, total=t3 - t0))
