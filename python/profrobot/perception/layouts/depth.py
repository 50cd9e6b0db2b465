"""Depth images to world points, and what a model expects each pixel to see.

Depth is OpenCV's (and MuJoCo's renderer's): metres along the camera's ``z`` axis, one image per
camera of a :class:`~profrobot.render.Cameras`, 0 or NaN where the sensor saw nothing. A pixel
``(u, v)`` (pixel centres at integers) of depth ``z`` is the camera point

    q = z · ((u − cx) / fx, (v − cy) / fy, 1)

and the world point ``p = Rᵀ (q − t)`` (``world_to_cam = [R | t]``). Cameras with lens distortion
have their depth undistorted first (nearest sampling, :func:`~profrobot.render.distortion.
undistort_images`), so only the pinhole ``K`` is used after that.

:func:`expected_depth` casts every pixel's ray into a MuJoCo model with ``mj_multiRay`` (MuJoCo's
own ray caster, the geoms the renderer draws: ``geomgroup``, alpha > 0): the depth a pixel would
have if the scene were only what the model holds, and which geom it would see. This is how the
robot's pixels are found at its known pose (its rendered mask) and how the modelled static scene
(floor, table) is told from what the model does not place.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt

from ...errors import InputError, InputTypeError
from ...render.cameras import Cameras
from ...render.distortion import undistort_images

__all__ = ["DepthPoints", "check_depth", "backproject", "pixel_rays", "expected_depth", "cast_depth", "DEFAULT_GEOMGROUP"]

#: the geom groups MuJoCo's renderer draws by default (``mjvOption.geomgroup``): what a depth
#: camera sees of a model whose collision geoms sit in group 3
DEFAULT_GEOMGROUP = (1, 1, 1, 0, 0, 0)


@dataclass(frozen=True)
class DepthPoints:
    """Back-projected pixels: ``points`` (N, 3) world metres, ``camera`` (N,) int, ``pixel``
    (N, 2) int ``(u, v)``, ``depth`` (N,) metres along the camera's z axis."""

    points: np.ndarray
    camera: np.ndarray
    pixel: np.ndarray
    depth: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


def check_depth(depth: npt.ArrayLike, cameras: Cameras, who: str = "depth") -> np.ndarray:
    """``depth`` as a new float64 (C, H, W) array for ``cameras`` with NaN for missing pixels (0 or
    NaN given). Refused (:class:`InputError`, naming the entry): a shape other than the
    cameras' (C, H, W), negative or infinite depth, non-numbers."""
    if not isinstance(cameras, Cameras):
        raise InputTypeError(f"cameras must be a profrobot.render.Cameras; got {type(cameras).__name__}")
    try:
        d = np.array(depth, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{who} must be a (C, H, W) array of metres; got {type(depth).__name__} ({e})") from None
    want = (len(cameras), cameras.height, cameras.width)
    if d.shape != want:
        raise InputError(f"{who} must have shape {want} (cameras × height × width, one image per camera of "
                         f"{len(cameras)}); got {d.shape}")
    bad = np.isinf(d) | (d < 0)
    if bad.any():
        c, v, u = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{who}[{c}, {v}, {u}] = {d[c, v, u]}: depth is metres along the camera's z axis, ≥ 0; "
                         f"0 or NaN mark missing pixels ({int(bad.sum())} such entries)")
    d[d == 0] = np.nan
    return d


def undistorted(depth: np.ndarray, cameras: Cameras) -> tuple[np.ndarray, Cameras]:
    """Depth (C, H, W) (NaN missing) of distorted cameras resampled to their pinhole cameras
    (nearest: a depth never blended across an edge)."""
    if cameras.distortion is None:
        return depth, cameras
    filled = np.nan_to_num(depth, nan=0.0)
    out = undistort_images(filled, cameras.K, cameras.distortion, kind="depth")
    out = np.asarray(out, dtype=np.float64)
    out[out == 0] = np.nan
    return out, cameras.undistorted()


def pixel_rays(cameras: Cameras, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera ``c``'s centre (3,), the unit world direction of every pixel's ray (H·W, 3), row
    major, and each ray's length per metre of depth (H·W,): ``|((u − cx)/fx, (v − cy)/fy, 1)|``
    (a pixel of depth z lies ``z`` times that along its ray)."""
    K, T = cameras.K[c], cameras.world_to_cam[c]
    H, W = cameras.height, cameras.width
    v, u = np.mgrid[0:H, 0:W]
    q = np.stack([(u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1], np.ones(H * W)], axis=1)
    length = np.linalg.norm(q, axis=1)
    R = T[:3, :3]
    dirs = (q / length[:, None]) @ R          # rows: Rᵀ q̂
    return cameras.centres()[c], np.ascontiguousarray(dirs), length


def backproject(depth: npt.ArrayLike, cameras: Cameras) -> DepthPoints:
    """World points of every valid pixel of ``depth`` (C, H, W) metres (0 / NaN missing) seen by
    ``cameras`` (distortion undone first; module docs)."""
    d, cams = undistorted(check_depth(depth, cameras), cameras)
    pts, cam, pix, z = [], [], [], []
    for c in range(len(cams)):
        centre, dirs, length = pixel_rays(cams, c)
        zc = d[c].ravel()
        ok = np.isfinite(zc)
        idx = np.flatnonzero(ok)
        pts.append(centre + dirs[idx] * (zc[idx] * length[idx])[:, None])
        cam.append(np.full(len(idx), c, dtype=np.int64))
        pix.append(np.stack([idx % cams.width, idx // cams.width], axis=1))
        z.append(zc[idx])
    return DepthPoints(np.concatenate(pts), np.concatenate(cam), np.concatenate(pix), np.concatenate(z))


def expected_depth(model: mujoco.MjModel, data: mujoco.MjData, cameras: Cameras, c: int,
                   geomgroup: Sequence[int] | np.ndarray = DEFAULT_GEOMGROUP) -> tuple[np.ndarray, np.ndarray]:
    """What camera ``c`` would see of ``model`` at ``data``'s kinematics (call ``mj_kinematics``
    first): the depth (H·W,) metres along the camera's z axis of each pixel's first geom (inf
    where the ray meets none) and that geom's id (-1), by ``mj_multiRay`` over the geoms in
    ``geomgroup`` with alpha > 0 (hide a geom by setting its alpha to 0)."""
    centre, dirs, length = pixel_rays(cameras, c)
    n = len(dirs)
    geomid = np.zeros(n, dtype=np.int32)
    dist = np.zeros(n, dtype=np.float64)
    mujoco.mj_multiRay(model, data, centre, np.ascontiguousarray(dirs.ravel()), np.asarray(geomgroup, dtype=np.uint8),
                       1, -1, geomid, dist, None, n, 1e6)
    z = np.where(geomid >= 0, dist / length, np.inf)
    return z, geomid


def cast_depth(model: mujoco.MjModel, qpos: npt.ArrayLike, cameras: Cameras,
               geomgroup: Sequence[int] | np.ndarray = DEFAULT_GEOMGROUP) -> np.ndarray:
    """Depth images (C, H, W) metres of ``model`` at ``qpos`` (its full ``nq`` vector) from
    ``cameras``, by MuJoCo's ray caster (:func:`expected_depth`, each pixel centre's ray; no
    OpenGL): 0 where a ray meets nothing. A renderer-free stand-in for a depth camera (pinhole)."""
    d = mujoco.MjData(model)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(model, d)
    out = []
    for c in range(len(cameras)):
        z, _ = expected_depth(model, d, cameras, c, geomgroup)
        out.append(np.where(np.isfinite(z), z, 0.0).reshape(cameras.height, cameras.width))
    return np.stack(out)

