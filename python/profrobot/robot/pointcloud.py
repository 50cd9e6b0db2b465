"""Point-cloud obstacles: clutter nobody modelled, as a depth camera sees it.

A :class:`PointCloud` is the union of balls (centre, radius) fixed in the world frame: points in
metres, each with the sensor's resolution as its radius. :meth:`profrobot.Robot.with_points` (or a
``PointCloud`` in :meth:`~profrobot.Robot.with_obstacles`) makes it an obstacle of the scene, labelled
exactly in the Rust core (``rust/geometry/cloud.rs``: the balls in a tree, each robot geom's exact signed
distance to them), so :func:`~profrobot.label_poses`, :func:`~profrobot.collides`,
:func:`~profrobot.certify_poses`, :func:`~profrobot.certify_motions`, :func:`~profrobot.plan_path`,
:func:`~profrobot.nearest_free` and ``resolve(sdf=None)`` all see it. A robot–ball pair is in
contact when its signed distance is below the ball's margin (the robot's :attr:`~profrobot.Robot.
margin`) plus the robot geom's, as for any MuJoCo geom.

The MuJoCo reference places the same balls as sphere geoms on the world body
(:func:`reference_model`), so :func:`~profrobot.crosscheck` checks our labels against
``mj_collision`` on the ball-cloud scene.

What a cloud covers: what the sensor saw. A path certified against it keeps clear of every ball,
so of every surface point the cameras saw (within the balls' radii); space no camera saw is free
to it. From depth images: :func:`profrobot.perception.clouds.cloud_from_depth` (back-projection, the robot's
own points removed, conservative voxel downsampling).
"""

from __future__ import annotations

import hashlib
import math
from typing import Protocol

import mujoco
import numpy as np
import numpy.typing as npt

from .._core import voxel_downsample
from ..errors import ImmutableError, InputError, InputTypeError

__all__ = ["PointCloud", "reference_model", "cloud_geom_ids", "robot_geom_ids", "CLOUD_GEOM_ID"]

#: the MuJoCo geom id a point cloud has in ``Robot.pair_geoms`` (it is not one MuJoCo geom)
CLOUD_GEOM_ID = -1


class CloudScene(Protocol):
    """What :func:`reference_model` and its id maps read of a :class:`~profrobot.Robot` (this
    module sits below ``Robot``, which builds on it)."""

    @property
    def name(self) -> str: ...
    @property
    def margin(self) -> float: ...
    @property
    def cloud(self) -> "PointCloud | None": ...
    @property
    def mj_model(self) -> mujoco.MjModel: ...
    @property
    def spec(self) -> mujoco.MjSpec | None: ...


def _radius_value(radius, n: int) -> np.ndarray:
    try:
        r = np.array(radius, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputTypeError(f"radius must be a number of metres or an array of shape ({n},); got "
                             f"{type(radius).__name__}") from None
    if r.ndim == 0:
        r = np.full(n, float(r))
    elif r.shape != (n,):
        raise InputError(f"radius must be a number of metres or an array of shape ({n},); got shape {r.shape}")
    bad = np.flatnonzero(~np.isfinite(r) | (r < 0))
    if len(bad):
        i = int(bad[0])
        raise InputError(f"radius[{i}] is {float(r[i])}; radii must be finite and >= 0 metres")
    return r


class PointCloud:
    """Balls fixed in the world: ``points`` (N, 3) float64 metres, ``radius`` (N,) float64 metres.

    ``radius`` is one number (the sensor's resolution, for every point) or one per point. Refused
    with :class:`~profrobot.errors.InputError` naming the entry: NaN or infinite points
    (``points[3, 1] is nan``), negative radii, a shape other than (N, 3). An empty cloud is free
    space. Immutable (its arrays are read-only); pickles; ``len(cloud)`` is N.
    """

    __slots__ = ("points", "radius", "_fingerprint")
    points: np.ndarray
    radius: np.ndarray
    _fingerprint: str | None

    def __init__(self, points: npt.ArrayLike, radius: npt.ArrayLike = 0.005):
        try:
            p = np.array(points, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputTypeError(f"points must be an (N, 3) array of metres; got {type(points).__name__}") from None
        if p.size == 0:
            p = p.reshape(0, 3)
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"points must have shape (N, 3) (metres, world frame); got {p.shape}")
        bad = np.argwhere(~np.isfinite(p))
        if len(bad):
            i, j = (int(v) for v in bad[0])
            raise InputError(f"points[{i}, {j}] is {float(p[i, j])}; cloud points must be finite")
        r = _radius_value(radius, len(p))
        p.setflags(write=False)
        r.setflags(write=False)
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "radius", r)
        object.__setattr__(self, "_fingerprint", None)

    def __setattr__(self, name, value):
        raise ImmutableError("a PointCloud is immutable; make a new one")

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        if not len(self):
            return "PointCloud(empty)"
        return (f"PointCloud({len(self)} balls, radius {self.radius.min():.3g}–{self.radius.max():.3g} m, "
                f"within {np.round(self.points.min(0), 3).tolist()}–{np.round(self.points.max(0), 3).tolist()})")

    def __getstate__(self):
        return {"points": np.array(self.points), "radius": np.array(self.radius)}

    def __setstate__(self, state):
        PointCloud.__init__(self, state["points"], state["radius"])

    def __eq__(self, other) -> bool:
        return (isinstance(other, PointCloud) and self.points.shape == other.points.shape
                and bool(np.array_equal(self.points, other.points)) and bool(np.array_equal(self.radius, other.radius)))

    def __hash__(self) -> int:
        return hash(self.fingerprint)

    @property
    def fingerprint(self) -> str:
        """sha256 of the balls (exact bytes), 32 hex digits."""
        fingerprint = self._fingerprint
        if fingerprint is None:
            h = hashlib.sha256(np.ascontiguousarray(self.points).tobytes())
            h.update(np.ascontiguousarray(self.radius).tobytes())
            fingerprint = h.hexdigest()[:32]
            object.__setattr__(self, "_fingerprint", fingerprint)
        return fingerprint

    def __add__(self, other: "PointCloud") -> "PointCloud":
        """The union of two clouds (this one's balls first)."""
        if not isinstance(other, PointCloud):
            return NotImplemented
        return PointCloud(np.concatenate([self.points, other.points]), np.concatenate([self.radius, other.radius]))

    def downsample(self, voxel: float) -> "PointCloud":
        """Conservative voxel downsampling: the balls grouped by the cube of side ``voxel``
        (metres) their centre lies in, each group replaced by one ball about its mean centre that
        reaches every ball of the group (radius ``max |c_i − mean| + r_i``), so every removed ball
        lies inside a kept one: a pose free of the result is free of this cloud. Groups keep the
        order of their first ball (deterministic). ``rust/geometry/cloud.rs``."""
        v = float(voxel) if isinstance(voxel, (int, float)) and not isinstance(voxel, bool) else float("nan")
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"voxel must be a positive number of metres; got {voxel!r}")
        if not len(self):
            return self
        p, r = voxel_downsample(np.ascontiguousarray(self.points), np.ascontiguousarray(self.radius), v)
        return PointCloud(p, r)

    def core_arrays(self, margin: float = 0.0) -> dict:
        """The ``cloud_*`` entries of a robot's core arrays (``rust/model/desc.rs``: ``CloudDesc``): the
        balls, their geom ``margin`` and MuJoCo's default contact filter (contype = conaffinity = 1)."""
        return dict(cloud_points=np.ascontiguousarray(self.points), cloud_radius=np.ascontiguousarray(self.radius),
                    cloud_margin=float(margin), cloud_contype=1, cloud_conaffinity=1)

    def add_to(self, spec: mujoco.MjSpec, margin: float = 0.0, prefix: str = "profrobot_cloud") -> None:
        """The balls as MuJoCo sphere geoms on the world body of ``spec`` (named ``profrobot_cloud_<i>``,
        contype = conaffinity = 1, geom margin ``margin``): the reference the cross-check labels
        with. A ball of radius 0 becomes a sphere of 1e-9 m (MuJoCo refuses size 0)."""
        body = spec.worldbody
        for i, (p, r) in enumerate(zip(self.points, self.radius)):
            body.add_geom(name=f"{prefix}_{i}", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[max(float(r), 1e-9), 0, 0],
                          pos=p.tolist(), contype=1, conaffinity=1, margin=float(margin), group=1,
                          rgba=[0.9, 0.5, 0.1, 1.0])


def reference_model(robot: CloudScene) -> mujoco.MjModel:
    """The MuJoCo model the labels of ``robot`` are checked against: its own, plus its point
    cloud's balls as sphere geoms (:meth:`PointCloud.add_to`) when it has one. Compiled once per
    robot (kept off its pickles); the geoms ``profrobot_cloud_<i>`` are what :func:`cloud_geom_ids` names."""
    cloud = getattr(robot, "cloud", None)
    if cloud is None or not len(cloud):
        return robot.mj_model
    cached = robot.__dict__.get("_reference_model")
    if cached is not None:
        return cached
    spec = robot.spec
    if spec is None:
        raise InputError(f"{robot.name}: a robot built from a compiled MjModel has no spec to place the cloud's "
                         "balls in; build it with from_mjcf / from_urdf / from_spec")
    spec = spec.copy()
    cloud.add_to(spec, margin=robot.margin)
    model = spec.compile()
    balls = np.array([i for i in range(model.ngeom) if (model.geom(i).name or "").startswith("profrobot_cloud_")],
                     dtype=np.int64)
    # MuJoCo lists geoms body by body: the balls follow the world's own geoms, and every geom after
    # them moves up by their number
    n, first = len(cloud), int(balls[0])
    if len(balls) != n or balls[-1] != first + n - 1 or model.ngeom != robot.mj_model.ngeom + n:
        raise InputError(f"{robot.name}: the point cloud's balls did not compile as {n} consecutive world geoms")
    ids = np.arange(model.ngeom, dtype=np.int64)
    ids[first:first + n] = CLOUD_GEOM_ID
    ids[first + n:] -= n
    robot.__dict__["_reference_model"] = model
    robot.__dict__["_reference_ids"] = ids
    return model


def cloud_geom_ids(robot: CloudScene) -> np.ndarray:
    """The MuJoCo geom ids of the cloud's balls in :func:`reference_model` (empty without a cloud)."""
    cloud = getattr(robot, "cloud", None)
    if cloud is None or not len(cloud):
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(robot_geom_ids(robot) == CLOUD_GEOM_ID)


def robot_geom_ids(robot: CloudScene) -> np.ndarray:
    """Per geom of :func:`reference_model`: its id in ``robot.mj_model``, :data:`CLOUD_GEOM_ID` for
    a ball of the cloud (the identity without a cloud)."""
    model = reference_model(robot)
    return robot.__dict__.get("_reference_ids", np.arange(model.ngeom, dtype=np.int64))
