"""A family's layout δ estimated from calibrated depth images: :func:`estimate_layout`.

The steps, each in its module:

1. **Back-projection** (:mod:`.depth`): every valid pixel of every camera to a world point.
2. **What the model explains** (:func:`.depth.expected_depth`): each pixel's ray is cast into the
   family at the robot's known pose with the movable obstacles hidden. A pixel is the **robot's**
   when its ray meets a robot geom (in a 3 × 3 neighbourhood: the rendered mask, dilated by a
   pixel) and the measured depth is not in front of it by more than the noise gate; ``mask=``
   replaces that test by the user's own mask. It is the **static scene's** (floor, table) when the
   ray meets a static geom within the gate. It is a **candidate obstacle point** when it lies in
   front of whatever the ray meets (or the ray meets nothing), by more than the gate. The gate is
   ``3 σ(z)``, ``σ(z) = a + b z`` (``depth_noise=(a, b)``). Pixels behind the model's surfaces
   are unexplained and left out (a robot pixel seen far behind where the robot should be: the
   pose is not the robot's, or the view is through it).
3. **The fit** (:mod:`.fit`): candidate points, averaged per ``voxel``, fitted obstacle by obstacle
   by robust Gauss–Newton on the exact signed distance (:mod:`.shapes`), from a grid of starts
   over the family's ranges; then each point goes to the obstacle that explains it and each
   obstacle is refined on its own points.
4. **Support and uncertainty:** an obstacle's ``support`` is the number of voxels within
   ``1.5 s`` of its surface (``s = max(2 σ(z̃), 3 mm)``, z̃ the median depth of the valid pixels). Below
   ``min_support`` it is **unsupported**: its scene joints are NaN and it is named in
   ``unsupported`` with the reason, never guessed. Its joints' covariance is Gauss–Newton's
   ``σ̂² (Jᵀ W J)⁻¹``; mapped through the Jacobian of its extreme points, it gives the largest
   1-σ displacement of any point of the obstacle (``displacement``). The suggested ``margin`` is
   ``confidence`` times the largest such σ over the obstacles (default 5), plus a bias term
   ``σ(z̃) / 2`` for what a covariance cannot see (noisy points at an edge or silhouette are not
   spread symmetrically about the surface, so they pull the fit: ``benches/layout.py`` measured
   errors up to 5.3 covariance σ without it), plus ``calibration`` (the cameras' own error,
   metres, which depth alone cannot see), at least 1 mm. It bounds how far any point of any
   obstacle is from where the estimate puts it, under the noise model; it was measured, not
   proven: ``benches/layout_results.md`` gives the largest error / margin seen. An obstacle whose
   margin would exceed :data:`~profrobot.robot.margin.MAX_MARGIN` is unsupported too.

Pass ``margin=estimate.margin`` to certification, planning, ``resolve`` and the inverse problems
(:mod:`profrobot.robot.margin`: what it guarantees, what it assumes), or use :meth:`LayoutEstimate.robot`.
"""

from __future__ import annotations

import copy
import json
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import numpy.typing as npt

from ...errors import InputError, InputTypeError
from ...files import atomic_path
from ...robot.margin import MAX_MARGIN, obstacle_bodies
from ...render.cameras import Cameras
from ...render.distortion import undistort_images
from ...robot.robot import Robot
from ...robot.gate import positive
from .depth import DEFAULT_GEOMGROUP, check_depth, expected_depth, pixel_rays, undistorted
from .kinds import OBSTACLE, ROBOT, STATIC, UNEXPLAINED
from .fit import Placer, covariance, displacement_sigma, distances, fit_obstacle, movable_obstacles, reach_box, refine

if TYPE_CHECKING:   # matplotlib (no profrobot module) loads when a figure is drawn
    from matplotlib.figure import Figure

__all__ = ["estimate_layout", "LayoutEstimate", "ROBOT", "STATIC", "OBSTACLE", "UNEXPLAINED"]

_FORMAT = "profrobot.layout_estimate/1"


@dataclass
class LayoutEstimate:
    """What :func:`estimate_layout` found (module docs).

    Attributes:
        scene: (D,) the layout δ in ``scene_joints`` order (radians / metres); NaN for the joints
            of an unsupported obstacle.
        scene_joints: the family's scene-joint names.
        obstacles: the movable obstacles' names (their scene bodies).
        support: {obstacle: voxels of points explained}.
        residual: {obstacle: RMS signed distance (m) of its supporting points}.
        displacement: {obstacle: largest 1-σ displacement (m) of any of its points}.
        margin: the suggested safety margin (m) to pass as ``margin=``.
        unsupported: {obstacle: why it was not estimated}.
        empty_views: cameras whose every pixel was missing (reported, not fitted).
        seconds: wall time of the estimate.
        points: (N, 3) float32 world points of every valid pixel; ``kind`` (N,) int8 (:data:`ROBOT`,
            :data:`STATIC`, :data:`OBSTACLE`, :data:`UNEXPLAINED`); ``owner`` (N,) int16, the
            obstacle an OBSTACLE point was given to (-1 for candidates no obstacle explains);
            ``camera`` (N,) int16 and ``pixel`` (N, 2) int16 ``(u, v)``: for pictures.
        cameras: the (undistorted) cameras; ``pose``: the robot's θ; ``family``: its name and
            ``family_fingerprint``.
    """

    layout: np.ndarray
    scene_joints: tuple
    obstacles: tuple
    support: dict
    residual: dict
    displacement: dict
    margin: float
    unsupported: dict
    empty_views: tuple
    seconds: float
    points: np.ndarray = field(repr=False)
    kind: np.ndarray = field(repr=False)
    owner: np.ndarray = field(repr=False)
    camera: np.ndarray = field(repr=False)
    pixel: np.ndarray = field(repr=False)
    cameras: Cameras = field(repr=False)
    pose: np.ndarray = field(repr=False)
    family: str = ""
    family_fingerprint: str = ""

    @property
    def ok(self) -> bool:
        """Every obstacle estimated (none unsupported)."""
        return not self.unsupported

    def robot(self, family: Robot) -> Robot:
        """``family`` at the estimated layout with the suggested safety margin:
        ``family.at(scene).with_margin(margin)``. :class:`InputError` naming the obstacles that
        were not estimated, or for another family than the one estimated."""
        if getattr(family, "geometry_fingerprint", None) != self.family_fingerprint:
            raise InputError(f"this layout was estimated for family {self.family!r}; got {getattr(family, 'name', family)!r}")
        if not self.ok:
            raise InputError("no layout to use: " + "; ".join(f"{k}: {v}" for k, v in self.unsupported.items()))
        return family.at(self.layout).with_margin(self.margin)

    def summary(self) -> str:
        lines = [f"layout of {self.family} in {self.seconds:.2f} s, margin {self.margin * 1000:.1f} mm"]
        for name in self.obstacles:
            if name in self.unsupported:
                lines.append(f"  {name}: not estimated ({self.unsupported[name]})")
            else:
                lines.append(f"  {name}: {self.support[name]} voxels, residual {self.residual[name] * 1000:.1f} mm, "
                             f"σ {self.displacement[name] * 1000:.2f} mm")
        if self.empty_views:
            lines.append(f"  cameras with no depth at all: {list(self.empty_views)}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-ready: format, family, scene (dict by joint; null where not estimated), support,
        residual, displacement, margin, unsupported, empty_views, seconds, pose."""
        return dict(format=_FORMAT, family=self.family, family_fingerprint=self.family_fingerprint,
                    layout={n: (None if not math.isfinite(v) else float(v)) for n, v in zip(self.scene_joints, self.layout)},
                    support={k: int(v) for k, v in self.support.items()},
                    residual={k: float(v) for k, v in self.residual.items()},
                    displacement={k: float(v) for k, v in self.displacement.items()},
                    margin=float(self.margin), unsupported=dict(self.unsupported), empty_views=list(self.empty_views),
                    seconds=float(self.seconds), pose=[float(v) for v in self.pose])

    def save(self, path: str | os.PathLike) -> Path:
        """The :meth:`to_dict` JSON, written atomically."""
        path = Path(path)
        with atomic_path(path) as tmp:
            Path(tmp).write_text(json.dumps(self.to_dict(), indent=1))
        return path

    def picture(self, family: Robot, path: str | os.PathLike | None = None, *, camera: int = 0) -> Figure:
        """The depth points, the robot's removed points and the fitted obstacles, from camera
        ``camera``'s view and from above (:func:`profrobot.perception.layouts.picture.layout_picture`)."""
        from .picture import layout_picture

        return layout_picture(self, family, path, camera=camera)


def _theta(family: Robot, pose) -> np.ndarray:
    K = len(family.robot_index)
    try:
        th = np.array(pose, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"pose must be {K} numbers (the robot joints of {family.name}); got {pose!r}") from None
    if th.shape != (K,):
        raise InputError(f"pose must have {K} values, the robot joints of {family.name} "
                         f"({', '.join(family.joint_names[i] for i in family.robot_index)}); got {th.size}")
    lim = family.joint_limits[family.robot_index]
    for i, (v, (lo, hi)) in enumerate(zip(th, lim)):
        name = family.joint_names[family.robot_index[i]]
        if not math.isfinite(v):
            raise InputError(f"pose[{i}] ({name}) is {v}")
        if not family.continuous[family.robot_index[i]] and not lo - 1e-9 <= v <= hi + 1e-9:
            raise InputError(f"pose[{i}] ({name}) = {v:.6g} is outside its limits [{lo:.6g}, {hi:.6g}]")
    return th


def _noise(depth_noise) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in depth_noise)
    except (TypeError, ValueError):
        raise InputError(f"depth_noise must be (a, b): σ = a + b·z, metres and a fraction; got {depth_noise!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and a >= 0 and b >= 0 and a + b > 0):
        raise InputError(f"depth_noise must be two finite numbers ≥ 0, not both 0; got {depth_noise!r}")
    return a, b


def _min3(img: np.ndarray) -> np.ndarray:
    """3 × 3 minimum filter of (H, W), edges padded with inf."""
    p = np.pad(img, 1, constant_values=np.inf)
    H, W = img.shape
    return np.min([p[i:i + H, j:j + W] for i in range(3) for j in range(3)], axis=0)


def _others(near: dict, j: int) -> np.ndarray:
    """(M,) bool: the voxels an obstacle other than ``j`` explains (``near``: obstacle → (M,) bool)."""
    return np.logical_or.reduce([v for k, v in near.items() if k != j] + [np.zeros_like(near[j])])


def _voxels(P: np.ndarray, voxel: float) -> np.ndarray:
    """The mean point of each occupied ``voxel`` cube (M, 3), in a fixed order."""
    if len(P) == 0:
        return P
    key = np.floor(P / voxel).astype(np.int64)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    out = np.zeros((len(counts), 3))
    np.add.at(out, inv, P)
    return out / counts[:, None]


def estimate_layout(family: Robot, depth: npt.ArrayLike, cameras: Cameras, *, pose: npt.ArrayLike,
                    mask: npt.ArrayLike | None = None, depth_noise: tuple[float, float] = (0.002, 0.005),
                    voxel: float = 0.01, min_support: int = 30, confidence: float = 5.0, calibration: float = 0.0,
                    geomgroup: Sequence[int] | np.ndarray = DEFAULT_GEOMGROUP) -> LayoutEstimate:
    """The layout δ of ``family`` (a Robot with scene joints) seen in ``depth`` (module docs).

    Args:
        depth: (C, H, W) metres along each camera's z axis, 0 or NaN for missing pixels.
        cameras: the C calibrated cameras (:class:`~profrobot.render.Cameras`; distortion is
            undone as for images).
        pose: the robot's joint pose θ (K − D,), known (e.g. from its encoders); its own pixels
            are removed by casting the pixels' rays at it, or by ``mask``.
        mask: optional (C, H, W) bool, True on the robot's pixels (replaces the rendered mask).
        depth_noise: ``(a, b)``: the sensor's depth noise σ = a + b·z (metres, fraction of depth).
        voxel: metres; candidate points are averaged per voxel before the fit.
        min_support: voxels an obstacle needs to be estimated.
        confidence: how many σ of displacement the suggested margin covers.
        calibration: metres added to the margin for the cameras' own calibration error.
        geomgroup: the geom groups the depth camera sees (MuJoCo's renderer draws 0, 1, 2).

    Returns a :class:`LayoutEstimate`. Deterministic (no random draws).
    """
    t0 = time.perf_counter()
    if not isinstance(family, Robot):
        raise InputTypeError(f"family must be a profrobot.Robot with scene joints; got {type(family).__name__}")
    if not family.is_family:
        raise InputError(f"{family.name} is not a family of scenes (no scene joints): there is no layout to estimate; "
                         "build one with Box(..., moves=Moves(...)) or Robot.with_scene_joints")
    d = check_depth(depth, cameras)
    theta = _theta(family, pose)
    a, b = _noise(depth_noise)
    voxel = positive("voxel", voxel)
    min_support = positive("min_support", min_support, integer=True)
    confidence = positive("confidence", confidence)
    calibration = positive("calibration", calibration, allow_zero=True)
    gg = np.asarray(geomgroup, dtype=np.uint8).reshape(-1)
    if gg.shape != (6,):
        raise InputError(f"geomgroup must be 6 flags (MuJoCo's geom groups 0..5); got {geomgroup!r}")
    C, H, W = d.shape
    user_mask = None
    if mask is not None:
        mk = np.asarray(mask)
        if mk.shape != (C, H, W):
            raise InputError(f"mask must have the depth's shape {(C, H, W)}; got {mk.shape}")
        if not (mk.dtype == np.bool_ or np.issubdtype(mk.dtype, np.number)):
            raise InputError(f"mask must be bool (True on the robot's pixels); got dtype {mk.dtype}")
        user_mask = mk != 0
        if cameras.distortion is not None:
            user_mask = undistort_images(user_mask, cameras.K, cameras.distortion, kind="mask")
    d, cams = undistorted(d, cameras)

    m0 = family.mj_model
    obstacles = movable_obstacles(family, gg)
    qpos = m0.qpos0.copy()
    qpos[family.qpos_adr[family.robot_index]] = theta
    mid = family.joint_limits[family.scene_index].mean(axis=1)
    qpos[family.qpos_adr[family.scene_index]] = mid

    # --- what the model explains: rays at the robot's pose, movable obstacles hidden -----------
    seen = copy.deepcopy(m0)
    robot_body = ~obstacle_bodies(m0, family.scene_joints)
    for ob in obstacles:
        seen.geom_rgba[np.isin(seen.geom_bodyid, ob.bodies), 3] = 0.0
    if user_mask is not None:  # the user's mask is the robot: the rays see past it
        seen.geom_rgba[robot_body[seen.geom_bodyid], 3] = 0.0
    data = mujoco.MjData(seen)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(seen, data)

    pts, kinds, cams_of, pix = [], [], [], []
    empty = []
    for c in range(C):
        z = d[c].ravel()
        valid = np.isfinite(z)
        if not valid.any():
            empty.append(c)
            continue
        centre, dirs, length = pixel_rays(cams, c)
        z_exp, gid = expected_depth(seen, data, cams, c, gg)
        hit = gid >= 0
        hit_robot = hit & robot_body[seen.geom_bodyid[np.where(hit, gid, 0)]]
        gate = 3.0 * (a + b * np.nan_to_num(z, nan=0.0))
        with np.errstate(invalid="ignore"):
            if user_mask is None:
                # the robot's rendered depth, dilated by a pixel (its silhouette's edge pixels):
                # a pixel is the robot's where the measured depth is that depth within the gate
                zr = _min3(np.where(hit_robot, z_exp, np.inf).reshape(H, W)).ravel()
                robot = valid & (np.abs(z - zr) < gate)
            else:
                robot = valid & user_mask[c].ravel()
            static = valid & ~robot & hit & ~hit_robot & (np.abs(z - z_exp) < gate)
            cand = valid & ~robot & ~static & (z < z_exp - gate)
        kind = np.full(H * W, UNEXPLAINED, dtype=np.int8)
        kind[robot], kind[static], kind[cand] = ROBOT, STATIC, OBSTACLE
        idx = np.flatnonzero(valid)
        pts.append(centre + dirs[idx] * (z[idx] * length[idx])[:, None])
        kinds.append(kind[idx])
        cams_of.append(np.full(len(idx), c, dtype=np.int16))
        pix.append(np.stack([idx % W, idx // W], axis=1).astype(np.int16))
    if pts:
        P_all, kind_all = np.concatenate(pts), np.concatenate(kinds)
        cam_all, pix_all = np.concatenate(cams_of), np.concatenate(pix)
    else:
        P_all, kind_all = np.zeros((0, 3)), np.zeros(0, np.int8)
        cam_all, pix_all = np.zeros(0, np.int16), np.zeros((0, 2), np.int16)

    # --- the fit ---------------------------------------------------------------------------------
    cand_pts = P_all[kind_all == OBSTACLE]
    z_valid = d[np.isfinite(d)]
    z_med = float(np.median(z_valid)) if len(z_valid) else 1.0
    s_final = max(2.0 * (a + b * z_med), 0.003)
    bias = 0.5 * (a + b * z_med)  # what the covariance cannot see: noise at edges is not symmetric about the surface
    scales = tuple(s for s in (0.04, 0.015) if s > s_final) + (s_final,)
    P = _voxels(cand_pts, voxel)
    placer = Placer(m0, qpos)
    D = len(family.scene_joints)
    layout = np.full(D, np.nan)
    fitted: dict[int, np.ndarray] = {}
    unsupported: dict[str, str] = {}
    boxes = {}
    for j, ob in enumerate(obstacles):
        lo, hi = reach_box(placer, ob, pad=0.03)
        boxes[j] = ((P >= lo) & (P <= hi)).all(axis=1)
        Pj = P[boxes[j]]
        if len(Pj) < min_support:
            unsupported[ob.name] = (f"{len(Pj)} voxels of unexplained points where it can be (needs {min_support})"
                                    + ("; no camera saw anything" if len(empty) == C else ""))
            continue
        fitted[j], _ = fit_obstacle(placer, ob, Pj, scales)
    # an obstacle whose fit sits on points another obstacle explains (two obstacles whose ranges
    # meet) is fitted again from its starts without those points, most entangled first
    for _round in range(2):
        keys = sorted(fitted)
        near = {j: np.abs(distances(placer, obstacles[j], fitted[j], P)) < 1.5 * s_final for j in keys}
        overlap = {j: float((near[j] & _others(near, j)).sum()) / max(int(near[j].sum()), 1) for j in keys}
        redo = [j for j in sorted(keys, key=lambda j: -overlap[j]) if overlap[j] > 0.1]
        if not redo:
            break
        for j in redo:
            Pj = P[boxes[j] & ~_others(near, j)]
            if len(Pj) >= min_support:
                fitted[j], _ = fit_obstacle(placer, obstacles[j], Pj, scales)
                near[j] = np.abs(distances(placer, obstacles[j], fitted[j], P)) < 1.5 * s_final

    support, residual, displacement = {}, {}, {}
    worst = 0.0
    owner = np.full(len(P), -1)
    if fitted:
        keys = sorted(fitted)
        for _round in range(2):  # each point to the obstacle that explains it, then each refined on its own
            R = np.stack([distances(placer, obstacles[j], fitted[j], P) for j in keys])
            best = np.argmin(R, axis=0)
            rbest = R[best, np.arange(len(P))]
            owner = np.where(np.abs(rbest) < 3 * s_final, np.asarray(keys)[best], -1)
            for j in keys:
                Pj = P[owner == j]
                if len(Pj) >= min_support:
                    fitted[j], _ = refine(placer, obstacles[j], fitted[j], Pj, (s_final,), iterations=8)
        R = np.stack([distances(placer, obstacles[j], fitted[j], P) for j in keys])
        best = np.argmin(R, axis=0)
        rbest = R[best, np.arange(len(P))]
        owner = np.where(np.abs(rbest) < 3 * s_final, np.asarray(keys)[best], -1)
        for j in keys:
            ob = obstacles[j]
            on = (owner == j) & (np.abs(rbest) < 1.5 * s_final)
            n = int(on.sum())
            if n < min_support:
                unsupported[ob.name] = f"only {n} voxels lie on it (needs {min_support}): too little of it is seen"
                continue
            cov, _ = covariance(placer, ob, fitted[j], P[owner == j], s_final)
            sig = displacement_sigma(placer, ob, fitted[j], cov)
            if not math.isfinite(sig) or confidence * sig + bias + calibration > MAX_MARGIN:
                unsupported[ob.name] = (f"its position is too uncertain (1-σ displacement {sig:.3g} m): "
                                        "too little of it is seen")
                continue
            support[ob.name] = n
            residual[ob.name] = float(np.sqrt(np.mean(rbest[on] ** 2)))
            displacement[ob.name] = sig
            worst = max(worst, sig)
            layout[ob.joints] = fitted[j]
    margin = max(confidence * worst + bias + calibration, 1e-3)

    # per-pixel owners for the picture: every candidate pixel to the obstacle that explains it
    owner_all = np.full(len(P_all), -1, dtype=np.int16)
    ok_obs = [j for j, ob in enumerate(obstacles) if ob.name in support]
    if ok_obs and (kind_all == OBSTACLE).any():
        ci = np.flatnonzero(kind_all == OBSTACLE)
        R = np.stack([distances(placer, obstacles[j], fitted[j], P_all[ci]) for j in ok_obs])
        bi = np.argmin(R, axis=0)
        near = np.abs(R[bi, np.arange(len(ci))]) < 3 * s_final
        owner_all[ci[near]] = np.asarray(ok_obs)[bi[near]]
    return LayoutEstimate(layout=layout, scene_joints=tuple(family.scene_joints), obstacles=tuple(o.name for o in obstacles),
                          support=support, residual=residual, displacement=displacement, margin=float(margin),
                          unsupported=unsupported, empty_views=tuple(empty), seconds=time.perf_counter() - t0,
                          points=P_all.astype(np.float32), kind=kind_all, owner=owner_all, camera=cam_all, pixel=pix_all,
                          cameras=cams, pose=theta, family=family.name, family_fingerprint=family.geometry_fingerprint)
