"""Cameras: one pinhole model (OpenCV's) for every renderer, fit and picture in profrobot.

A camera is ``K`` (3, 3) and ``world_to_cam`` (4, 4), OpenCV convention: camera ``x`` right,
``y`` down, ``z`` forward; a world point ``p`` (metres) goes to ``q = R p + t`` and to the pixel

    u = fx q_x / q_z + cx,    v = fy q_y / q_z + cy        (pixel *centres* at integers)

``fx != fy``, an off-centre principal point, any roll and any image size (H != W) are all
expressed; skew is not (``K[0, 1]`` must be 0). Optional lens distortion ``distortion`` (C, 5)
holds OpenCV's ``k1, k2, p1, p2, k3``: images from such a camera are undistorted once, at entry
(:mod:`profrobot.render.distortion`), and everything after sees the pinhole ``K``.

Constructors:
- :meth:`Cameras.from_opencv` (a calibration: per-camera or shared ``K``, ``world_to_cam``);
- :meth:`Cameras.look_at` (eye, target, up);
- :meth:`Cameras.from_mujoco` (named MJCF cameras, fixed or mounted on a body, at a pose);
- :meth:`Cameras.free` / :func:`ring_cameras` / :func:`sphere_cameras` (MuJoCo *free* cameras:
  ``lookat``, ``distance``, ``azimuth``, ``elevation`` in degrees, one vertical ``fovy``; square
  pixels, centred principal point, no roll; ``fx = fy = (H/2) / tan(fovy/2)``, ``cx = W/2 - 1/2``).

MuJoCo draws any of them exactly (:mod:`profrobot.render.mjviews`): a free camera through
MuJoCo's own ``MjvCamera``, any other by setting the scene's GL camera (position, forward, up)
and its frustum from ``K``: at the near plane ``n``, pixel edges ``u = -1/2`` and ``u = W - 1/2``
are ``x = n (-1/2 - cx) / fx`` and ``n (W - 1/2 - cx) / fx`` (likewise ``y`` with ``v``, up being
``-y``), which is :meth:`Cameras.gl_frustum`; :meth:`Cameras.from_gl` is its inverse, and
``tests/test_cameras.py`` checks both against MuJoCo's own renders.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from ..errors import CorruptFileError, InputError
from ..files import atomic_path
from ..robot.robot import Robot
from .distortion import check_K, check_distortion, check_image_size

__all__ = ["Cameras", "ring_cameras", "sphere_cameras", "free_camera"]

_FREE_KEYS = ("lookat", "distance", "azimuth", "elevation")
_FORMAT = "profrobot.cameras/1"


def _free_frames(lookat, distance, azimuth, elevation):
    """Camera centre, forward and up (C, 3) of MuJoCo free cameras, as ``mjv_updateCamera``
    computes them: ``forward = (cos e cos a, cos e sin a, sin e)``, up in the vertical plane."""
    a, e = np.deg2rad(azimuth), np.deg2rad(elevation)
    fwd = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1)
    up = np.stack([-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)], -1)
    return lookat - distance[:, None] * fwd, fwd, up


def _world_to_cam(pos, fwd, up) -> np.ndarray:
    """(C, 4, 4) from camera centres, forward and up (C, 3): R's rows are right, down, forward."""
    R = np.stack([np.cross(fwd, up), -up, fwd], axis=1)
    T = np.zeros((len(pos), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = -np.einsum("cij,cj->ci", R, pos)
    T[:, 3, 3] = 1
    return T


def _fovy_K(fovy: float, width: int, height: int, who: str) -> np.ndarray:
    """(3, 3) intrinsics of MuJoCo's square-pixel camera with vertical field of view ``fovy``
    (degrees) at ``width`` x ``height``: ``fx = fy = (H/2) / tan(fovy/2)``, ``cx = W/2 - 1/2``."""
    if not 0 < fovy < 180:
        raise InputError(f"{who}: fovy must be in (0, 180) degrees; got {fovy}")
    w, h = check_image_size(width, height, who)
    f = (h / 2) / np.tan(np.deg2rad(fovy) / 2)
    return np.array([[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1]])


def _array(x, name: str, tail: tuple, who: str) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{who}: {name} must be numbers of shape {tail} or (C, {', '.join(map(str, tail))}); {e}") from None
    if a.shape == tail:
        a = a[None]
    if a.ndim != len(tail) + 1 or a.shape[1:] != tail:
        raise InputError(f"{who}: {name} must have shape {tail} or (C, {', '.join(map(str, tail))}); got {a.shape}")
    bad = np.argwhere(~np.isfinite(a))
    if len(bad):
        raise InputError(f"{who}: {name}[{', '.join(map(str, bad[0]))}] is {a[tuple(bad[0])]}")
    return a


class Cameras:
    """C pinhole cameras sharing one image size (module docs).

    ``K`` (C, 3, 3) pixels; ``world_to_cam`` (C, 4, 4), rotation orthonormal, metres;
    ``width``, ``height`` pixels; ``distortion`` (C, 5) OpenCV ``k1, k2, p1, p2, k3`` or None.
    Immutable, comparable (:meth:`to_dict` value for value), hashable, picklable, JSON
    round-trips (:meth:`save` / :meth:`load`, :meth:`to_dict` / :meth:`from_dict`).
    """

    __slots__ = ("_K", "_T", "width", "height", "_dist", "_free")

    _K: np.ndarray
    _T: np.ndarray
    width: int
    height: int
    _dist: np.ndarray | None
    _free: dict[str, Any] | None  # lookat, distance, azimuth, elevation: arrays; fovy: float

    @property
    def K(self) -> np.ndarray:
        """(C, 3, 3) intrinsics, pixels (a copy)."""
        return self._K.copy()

    @property
    def world_to_cam(self) -> np.ndarray:
        """(C, 4, 4) world-to-camera rigid transforms, metres (a copy)."""
        return self._T.copy()

    @property
    def distortion(self) -> np.ndarray | None:
        """(C, 5) OpenCV ``k1, k2, p1, p2, k3``, or None (a copy)."""
        return None if self._dist is None else self._dist.copy()

    def __init__(self, *args, **kwargs):
        """``Cameras(K, world_to_cam, width, height, *, distortion=None)``: as :meth:`from_opencv`.
        MuJoCo free cameras (``lookat``, ``distance``, ``azimuth``, ``elevation``) are
        :meth:`Cameras.free`."""
        free = "MuJoCo free cameras are Cameras.free(lookat, distance, azimuth, elevation, width, height, fovy)"
        names = ("K", "world_to_cam", "width", "height")
        if len(args) > 4:
            raise InputError(f"Cameras: at most 4 positional arguments (K, world_to_cam, width, height); got {len(args)}; "
                             f"{free}")
        given = dict(zip(names, args))
        for k, v in kwargs.items():
            if k not in (*names, "distortion") or k in given:
                raise InputError(f"Cameras: unexpected or repeated argument {k!r}"
                                 + (f"; {free}" if k in (*_FREE_KEYS, "fovy") else ""))
            given[k] = v
        missing = [k for k in names if k not in given]
        if missing:
            raise InputError(f"Cameras: missing {missing} (Cameras(K, world_to_cam, width, height))")
        try:
            ndim = np.ndim(given["world_to_cam"])
        except (TypeError, ValueError):
            ndim = None                                     # _init names the argument
        if ndim is not None and ndim < 2:
            raise InputError(f"Cameras: world_to_cam must be (4, 4) or (C, 4, 4); got {ndim} dimension(s); {free}")
        self._init(given["K"], given["world_to_cam"], given["width"], given["height"], given.get("distortion"), None,
                   "Cameras")

    def _init(self, K, world_to_cam, width, height, distortion, free_params, who):
        K = _array(K, "K", (3, 3), who)
        T = _array(world_to_cam, "world_to_cam", (4, 4), who)
        C = max(len(K), len(T))
        if len(K) not in (1, C) or len(T) not in (1, C):
            raise InputError(f"{who}: K has {len(K)} cameras and world_to_cam {len(T)}; give one K for all or one per camera")
        K, T = np.broadcast_to(K, (C, 3, 3)).copy(), np.broadcast_to(T, (C, 4, 4)).copy()
        check_K(K, (C, 3, 3), who)
        for c in range(C):
            R = T[c, :3, :3]
            if (T[c, 3] != [0, 0, 0, 1]).any() or not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
                raise InputError(f"{who}: world_to_cam[{c}] must be a rigid transform [[R, t], [0, 0, 0, 1]] with R a rotation "
                                 f"(orthonormal, det +1, to 1e-3; OpenCV convention x right, y down, z forward)")
            if not np.allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-12):
                # a calibration written with few decimals: the nearest rotation (SVD), so that
                # every later product stays rigid
                U, _, Vt = np.linalg.svd(R)
                T[c, :3, :3] = U @ Vt
        w, h = check_image_size(width, height, who)
        object.__setattr__(self, "_K", K)
        object.__setattr__(self, "_T", T)
        object.__setattr__(self, "width", w)
        object.__setattr__(self, "height", h)
        object.__setattr__(self, "_dist", check_distortion(distortion, C, who))
        object.__setattr__(self, "_free", None if free_params is None else
                           {k: (np.array(v, dtype=np.float64) if k != "fovy" else float(v)) for k, v in free_params.items()})

    def __setattr__(self, name, value):
        raise AttributeError(f"Cameras are immutable; {name} cannot be set (make new ones)")

    def __reduce__(self):
        return (Cameras.from_dict, (self.to_dict(),))

    # ---- constructors ---------------------------------------------------------------------------
    @classmethod
    def from_opencv(cls, K: npt.ArrayLike, world_to_cam: npt.ArrayLike, width: int, height: int, *,
                    distortion: npt.ArrayLike | None = None) -> "Cameras":
        """Cameras from an OpenCV calibration: ``K`` (3, 3) shared or (C, 3, 3), ``world_to_cam``
        (4, 4) or (C, 4, 4) (x right, y down, z forward; metres), the calibrated image size in
        pixels, and optionally ``distortion`` ``(k1, k2, p1, p2[, k3])`` shared or (C, 5)
        (target images are then undistorted once: :mod:`profrobot.render.distortion`)."""
        c = object.__new__(cls)
        c._init(K, world_to_cam, width, height, distortion, None, "Cameras.from_opencv")
        return c

    @classmethod
    def free(cls, lookat: npt.ArrayLike, distance: npt.ArrayLike, azimuth: npt.ArrayLike, elevation: npt.ArrayLike,
             width: int = 128, height: int = 128, fovy: float = 45.0) -> "Cameras":
        """C MuJoCo free cameras: ``lookat`` (C, 3) metres, ``distance`` (C,) metres, ``azimuth``
        and ``elevation`` (C,) degrees (negative elevation looks down), one vertical ``fovy``
        (degrees), ``width`` x ``height`` pixels. MuJoCo draws them with its own ``MjvCamera``."""
        who = "Cameras.free"
        try:
            la = np.array(lookat, dtype=np.float64).reshape(-1, 3)
            n = len(la)
            arrs = {k: np.broadcast_to(np.asarray(v, dtype=np.float64), (n,)).copy()
                    for k, v in (("distance", distance), ("azimuth", azimuth), ("elevation", elevation))}
            width, height, fovy = int(width), int(height), float(fovy)
        except (TypeError, ValueError) as e:
            raise InputError(f"{who}: lookat (C, 3) and distance, azimuth, elevation (C,) or scalars, integer width and "
                             f"height and a number fovy are needed; {e}") from None
        if not np.isfinite(np.concatenate([la.ravel(), *arrs.values(), [fovy]])).all():
            raise InputError(f"{who}: lookat, distance, azimuth, elevation and fovy must be finite")
        if (arrs["distance"] <= 0).any():
            raise InputError(f"{who}: distance must be positive (metres)")
        K = _fovy_K(fovy, width, height, who)
        T = _world_to_cam(*_free_frames(la, arrs["distance"], arrs["azimuth"], arrs["elevation"]))
        params = dict(lookat=la, **arrs, fovy=float(fovy))
        c = object.__new__(cls)
        c._init(K, T, int(width), int(height), None, params, who)
        return c

    @classmethod
    def look_at(cls, eye: npt.ArrayLike, target: npt.ArrayLike, up: npt.ArrayLike = (0.0, 0.0, 1.0), *,
                width: int = 128, height: int = 128, fovy: float = 45.0, K: npt.ArrayLike | None = None) -> "Cameras":
        """Cameras at ``eye`` (C, 3) looking at ``target`` (C, 3) (metres), image ``up`` (3,) or
        (C, 3) (the camera's -y is the part of ``up`` orthogonal to the view direction); ``K``
        (3, 3) or (C, 3, 3), else square pixels with vertical field of view ``fovy`` (degrees)."""
        who = "Cameras.look_at"
        eye, target, up = (_array(x, n, (3,), who) for x, n in ((eye, "eye"), (target, "target"), (up, "up")))
        C = max(len(eye), len(target), len(up))
        eye, target, up = (np.broadcast_to(x, (C, 3)) for x in (eye, target, up))
        fwd = target - eye
        dist = np.linalg.norm(fwd, axis=1)
        if (dist < 1e-9).any():
            raise InputError(f"{who}: eye and target coincide for camera {int(np.argmax(dist < 1e-9))}")
        fwd = fwd / dist[:, None]
        u = up - np.sum(up * fwd, 1, keepdims=True) * fwd
        un = np.linalg.norm(u, axis=1)
        if (un < 1e-9).any():
            raise InputError(f"{who}: up is parallel to the view direction for camera {int(np.argmax(un < 1e-9))}")
        if K is None:
            K = _fovy_K(fovy, width, height, who)
        c = object.__new__(cls)
        c._init(K, _world_to_cam(eye, fwd, u / un[:, None]), width, height, None, None, who)
        return c

    @classmethod
    def from_gl(cls, pos: npt.ArrayLike, forward: npt.ArrayLike, up: npt.ArrayLike, frustum: tuple, width: int,
                height: int) -> "Cameras":
        """The inverse of :meth:`gl_frustum`: a camera from a MuJoCo GL camera (``pos``, ``forward``,
        ``up`` (3,), ``frustum`` = (center, halfwidth, bottom, top, near), as ``mjr_render`` uses them)."""
        center, half, bottom, top, near = (float(x) for x in frustum)
        left, right = center - half, center + half
        fx, fy = width * near / (right - left), height * near / (top - bottom)
        K = np.array([[fx, 0, -0.5 - left / near * fx], [0, fy, -0.5 + top / near * fy], [0, 0, 1]])
        fwd = np.asarray(forward, np.float64)
        fwd = fwd / np.linalg.norm(fwd)
        u = np.asarray(up, np.float64)
        u = u - (u @ fwd) * fwd
        T = _world_to_cam(np.asarray(pos, np.float64)[None], fwd[None], (u / np.linalg.norm(u))[None])
        return cls.from_opencv(K, T, width, height)

    @classmethod
    def from_mujoco(cls, model: Robot | mujoco.MjModel, names: str | Iterable[str], qpos: npt.ArrayLike | None = None,
                    *, width: int | None = None, height: int | None = None) -> "Cameras":
        """Named MJCF cameras (fixed, or mounted on a body and then taken at ``qpos``) exactly as
        MuJoCo draws them at ``width`` x ``height`` (default: the cameras' ``resolution``).

        ``model``: a :class:`profrobot.Robot` (``qpos``: its joint pose (K,), default the model's
        ``qpos0``) or a ``mujoco.MjModel`` (``qpos``: the full ``nq`` vector). ``names``: one
        name or a list. The matrices are read off MuJoCo's own GL camera for each (position,
        axes and frustum, which also covers ``fovy`` cameras and cameras with ``focal``/
        ``principal``/``sensorsize`` intrinsics) via :meth:`from_gl`."""
        who = "Cameras.from_mujoco"
        robot = None if isinstance(model, mujoco.MjModel) else model
        m = model if robot is None else robot.mj_model
        if not isinstance(m, mujoco.MjModel):
            raise InputError(f"{who}: model must be a profrobot.Robot or a mujoco.MjModel; got {type(model).__name__}")
        names = [names] if isinstance(names, str) else list(names)
        if not names:
            raise InputError(f"{who}: no camera names given")
        d = mujoco.MjData(m)
        if qpos is not None:
            q = np.asarray(qpos, dtype=np.float64)
            if robot is not None:
                if q.shape != (robot.njoint,) or not np.isfinite(q).all():
                    raise InputError(f"{who}: qpos must be a finite pose of shape ({robot.njoint},); got {q.shape}")
                d.qpos[robot.qpos_adr] = q
            else:
                if q.shape != (m.nq,) or not np.isfinite(q).all():
                    raise InputError(f"{who}: qpos must be a finite vector of shape ({m.nq},); got {q.shape}")
                d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)          # subtree centres of mass, for trackcom / targetbodycom cameras
        mujoco.mj_camlight(m, d)
        known = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(m.ncam)]
        out = []
        for name in names:
            cid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, name)
            if cid < 0:
                raise InputError(f"{who}: the model has no camera named {name!r}; it has {known}")
            if int(m.cam_projection[cid]) != int(mujoco.mjtProjection.mjPROJ_PERSPECTIVE):
                raise InputError(f"{who}: camera {name!r} is orthographic; only perspective cameras are supported")
            res = m.cam_resolution[cid]
            w = int(width) if width is not None else int(res[0])
            h = int(height) if height is not None else int(res[1])
            if (width is None or height is None) and tuple(res) == (1, 1):
                raise InputError(f"{who}: camera {name!r} has no resolution in the MJCF; pass width= and height=")
            cam = mujoco.MjvCamera()
            cam.type, cam.fixedcamid = mujoco.mjtCamera.mjCAMERA_FIXED, cid
            scn = mujoco.MjvScene(m, maxgeom=max(1, m.ngeom))
            opt = mujoco.MjvOption()
            mujoco.mjv_updateScene(m, d, opt, None, cam, mujoco.mjtCatBit.mjCAT_ALL.value, scn)
            g = mujoco.mjv_averageCamera(scn.camera[0], scn.camera[1])
            half = g.frustum_width or 0.5 * w / h * (g.frustum_top - g.frustum_bottom)
            out.append(cls.from_gl(g.pos, g.forward, g.up, (g.frustum_center, half, g.frustum_bottom, g.frustum_top,
                                                           g.frustum_near), w, h))
        if len({(c.width, c.height) for c in out}) > 1:
            raise InputError(f"{who}: the cameras have different resolutions {[(c.width, c.height) for c in out]}; "
                             "pass width= and height= (one image size for all)")
        return cls.from_opencv(np.concatenate([c.K for c in out]), np.concatenate([c.world_to_cam for c in out]),
                               out[0].width, out[0].height)

    # ---- the pinhole ----------------------------------------------------------------------------
    @property
    def free_params(self) -> dict | None:
        """Free cameras' MuJoCo parameters (``lookat`` (C, 3), ``distance``, ``azimuth``,
        ``elevation`` (C,), ``fovy``; a copy), or None."""
        return None if self._free is None else {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in self._free.items()}

    def _free_param(self, name: str):
        if self._free is None:
            raise AttributeError(f"{name}: these are not MuJoCo free cameras (see K and world_to_cam)")
        v = self._free[name]
        return v.copy() if isinstance(v, np.ndarray) else v

    lookat = property(lambda self: self._free_param("lookat"), doc="Free cameras: (C, 3) look-at points, metres.")
    distance = property(lambda self: self._free_param("distance"), doc="Free cameras: (C,) distances, metres.")
    azimuth = property(lambda self: self._free_param("azimuth"), doc="Free cameras: (C,) azimuths, degrees.")
    elevation = property(lambda self: self._free_param("elevation"), doc="Free cameras: (C,) elevations, degrees.")

    @property
    def is_free(self) -> bool:
        """True for MuJoCo free cameras (:meth:`free`): MuJoCo draws them with its ``MjvCamera``."""
        return self._free is not None

    @property
    def fovy(self) -> float:
        """The vertical field of view (degrees) of free cameras."""
        return self._free_param("fovy")

    def __len__(self) -> int:
        return len(self._K)

    def __getitem__(self, idx) -> "Cameras":
        idx = np.atleast_1d(np.arange(len(self))[idx])
        if self._free is not None:
            p = self._free
            return Cameras.free(p["lookat"][idx], p["distance"][idx], p["azimuth"][idx], p["elevation"][idx],
                                self.width, self.height, p["fovy"])
        return Cameras.from_opencv(self.K[idx], self.world_to_cam[idx], self.width, self.height,
                                   distortion=None if self.distortion is None else self.distortion[idx])

    def centres(self) -> np.ndarray:
        """(C, 3) camera centres in the world (metres): ``-R^T t``."""
        R, t = self.world_to_cam[:, :3, :3], self.world_to_cam[:, :3, 3]
        return -np.einsum("cji,cj->ci", R, t)

    def frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera centres, forward and up directions (C, 3) in the world (``up`` is ``-y``)."""
        R = self.world_to_cam[:, :3, :3]
        return self.centres(), R[:, 2].copy(), -R[:, 1]

    def project(self, points: npt.ArrayLike) -> np.ndarray:
        """Pixels (C, P, 2) of world points (P, 3) (metres) in each camera (no distortion)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        q = np.einsum("cij,pj->cpi", self.world_to_cam[:, :3, :3], p) + self.world_to_cam[:, None, :3, 3]
        uv = q[..., :2] / q[..., 2:3]
        return uv * self.K[:, None, [0, 1], [0, 1]] + self.K[:, None, :2, 2]

    def gl_frustum(self, c: int, near: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple]:
        """Camera ``c`` as MuJoCo's GL camera: ``pos``, ``forward``, ``up`` (3,) and the frustum
        ``(center, halfwidth, bottom, top)`` at distance ``near`` (module docs)."""
        K, T = self.K[c], self.world_to_cam[c]
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        left, right = near * (-0.5 - cx) / fx, near * (self.width - 0.5 - cx) / fx
        top, bottom = near * (cy + 0.5) / fy, -near * (self.height - 0.5 - cy) / fy
        R = T[:3, :3]
        return (self.centres()[c], R[2].copy(), -R[1], (0.5 * (left + right), 0.5 * (right - left), bottom, top))

    def resized(self, width: int, height: int | None = None) -> "Cameras":
        """The same views at another resolution: pixel edges stay put, so ``fx`` scales by
        ``width / W``, ``fy`` by ``height / H``, and ``cx -> (cx + 1/2) width / W - 1/2`` (likewise
        ``cy``). Free cameras keep their ``fovy`` (vertical) and square pixels instead, as MuJoCo
        draws them at any size."""
        height = int(height if height is not None else width)
        width = int(width)
        if self._free is not None:
            p = self._free
            return Cameras.free(p["lookat"], p["distance"], p["azimuth"], p["elevation"], width, height, p["fovy"])
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[:, 0, 0] *= sx
        K[:, 1, 1] *= sy
        K[:, 0, 2] = (K[:, 0, 2] + 0.5) * sx - 0.5
        K[:, 1, 2] = (K[:, 1, 2] + 0.5) * sy - 0.5
        return Cameras.from_opencv(K, self.world_to_cam, width, height, distortion=self.distortion)

    def undistorted(self) -> "Cameras":
        """These cameras without lens distortion (same K): what images are undistorted to."""
        if self.distortion is None:
            return self
        return Cameras.from_opencv(self.K, self.world_to_cam, self.width, self.height)

    def moved(self, delta: npt.ArrayLike) -> "Cameras":
        """These cameras with ``world_to_cam`` replaced by ``delta @ world_to_cam`` (``delta``
        (C, 4, 4) rigid, camera frame): e.g. a refined calibration."""
        d = _array(delta, "delta", (4, 4), "Cameras.moved")
        return Cameras.from_opencv(self.K, np.einsum("cij,cjk->cik", np.broadcast_to(d, (len(self), 4, 4)),
                                                     self.world_to_cam), self.width, self.height, distortion=self.distortion)

    # ---- files ----------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready: ``{"format", "width", "height", "K", "world_to_cam", "distortion"}``, and
        ``"free"`` for free cameras (their MuJoCo parameters)."""
        # + 0.0 turns -0.0 into 0.0: equal cameras give equal dicts, JSON and hashes
        d = dict(format=_FORMAT, width=self.width, height=self.height, K=(self._K + 0.0).tolist(),
                 world_to_cam=(self._T + 0.0).tolist(),
                 distortion=None if self._dist is None else (self._dist + 0.0).tolist())
        if self._free is not None:
            d["free"] = {k: ((v + 0.0).tolist() if isinstance(v, np.ndarray) else v) for k, v in self._free.items()}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Cameras":
        """The inverse of :meth:`to_dict`; also reads the free-camera dicts of earlier releases."""
        if not isinstance(d, dict):
            raise InputError(f"cameras: expected a dict; got {type(d).__name__}")
        if "format" not in d and "lookat" in d:          # earlier releases: the free-camera fields
            return cls.free(**{k: d[k] for k in (*_FREE_KEYS, "width", "height", "fovy") if k in d})
        if d.get("format") != _FORMAT:
            raise CorruptFileError(f"cameras: unknown format {d.get('format')!r} (expected {_FORMAT!r})")
        missing = {"width", "height", "K", "world_to_cam"} - set(d)
        if missing:
            raise CorruptFileError(f"cameras: missing {sorted(missing)}")
        if d.get("free") is not None:
            f = d["free"]
            return cls.free(f["lookat"], f["distance"], f["azimuth"], f["elevation"], d["width"], d["height"], f["fovy"])
        return cls.from_opencv(d["K"], d["world_to_cam"], d["width"], d["height"], distortion=d.get("distortion"))

    def save(self, path: str | os.PathLike) -> Path:
        """Write :meth:`to_dict` as JSON to ``path`` (atomically); returns the path."""
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict(), indent=1))
        return Path(path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Cameras":
        """Cameras from a JSON file written by :meth:`save` (or by hand: ``K``, ``world_to_cam``,
        ``width``, ``height``, optional ``distortion``, with ``"format": "profrobot.cameras/1"``)."""
        try:
            d = json.loads(Path(path).read_text())
        except (OSError, ValueError) as e:
            raise CorruptFileError(f"{path}: not a readable cameras JSON file ({e})") from e
        try:
            return cls.from_dict(d)
        except (InputError, KeyError, TypeError, ValueError) as e:
            raise CorruptFileError(f"{path}: {e}") from e

    def __eq__(self, other) -> bool:
        """Same cameras: the same :meth:`to_dict`, value for value."""
        if not isinstance(other, Cameras):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict()))

    def __repr__(self) -> str:
        kind = "free " if self.is_free else ""
        dist = ", distorted" if self.distortion is not None else ""
        return f"Cameras({len(self)} {kind}cameras, {self.width}x{self.height}{dist})"

    def mjv_camera(self, i: int) -> mujoco.MjvCamera:
        """Free camera ``i`` as MuJoCo's ``MjvCamera`` (for ``mujoco.Renderer.update_scene``)."""
        if not 0 <= int(i) < len(self):
            raise IndexError(f"camera {i} out of range for {len(self)} cameras")
        if self._free is None:
            raise InputError("mjv_camera: only free cameras are MjvCameras; MuJoCo draws the others through "
                             "profrobot.render.mjviews (the scene's GL camera set from K)")
        p = self._free
        return free_camera(p["lookat"][i], p["distance"][i], p["azimuth"][i], p["elevation"][i])


def ring_cameras(n: int = 4, *, distance: float = 1.8, elevation: float | list = -20.0, azimuth0: float = 0.0,
                 lookat: npt.ArrayLike = (0.0, 0.0, 0.4), size: int = 128, fovy: float = 45.0) -> Cameras:
    """``n`` free cameras evenly spaced in azimuth around ``lookat`` (one ring per elevation given)."""
    els = np.atleast_1d(np.asarray(elevation, dtype=float))
    az = (azimuth0 + 360.0 * np.arange(n) / n)
    A, E = np.meshgrid(az, els)
    m = A.size
    return Cameras.free(np.tile(np.asarray(lookat, dtype=float), (m, 1)), np.full(m, distance), A.ravel(), E.ravel(),
                        size, size, fovy)


def sphere_cameras(n: int, *, distance: float = 1.8, elevation_range: tuple[float, float] = (-60.0, 30.0),
                   lookat: npt.ArrayLike = (0.0, 0.0, 0.4), size: int = 128, fovy: float = 45.0, seed: int = 0,
                   jitter: float = 0.0) -> Cameras:
    """``n`` free cameras on a sphere cap (Fibonacci spiral in azimuth and uniform in sin(elevation)),
    looking at ``lookat``; ``jitter`` (metres) shifts each lookat randomly, as Dr. Robot does."""
    rng = np.random.default_rng(seed)
    i = np.arange(n) + 0.5
    s0, s1 = np.sin(np.deg2rad(elevation_range))
    el = np.rad2deg(np.arcsin(s0 + (s1 - s0) * i / n))
    az = (i * 137.50776405) % 360.0
    la = np.asarray(lookat, dtype=float) + jitter * rng.uniform(-1, 1, (n, 3))
    return Cameras.free(la, np.full(n, distance), az, el, size, size, fovy)


def free_camera(lookat: npt.ArrayLike, distance: float, azimuth: float, elevation: float) -> mujoco.MjvCamera:
    """A MuJoCo free camera (metres, degrees)."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = lookat
    cam.distance, cam.azimuth, cam.elevation = float(distance), float(azimuth), float(elevation)
    return cam
