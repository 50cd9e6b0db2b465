"""Multi-view training data from MuJoCo: RGB, metric depth and the robot mask, with the camera
intrinsics and extrinsics that match the pixels.

Camera conventions (OpenCV): ``x`` right, ``y`` down, ``z`` forward; ``world_to_cam`` (C, 4, 4)
maps world points (metres) to camera coordinates; ``K`` (C, 3, 3) maps them to pixels with pixel
*centres* at integer coordinates, so ``cx = W/2 - 1/2`` (checked against MuJoCo renders of a
known point in ``tests/test_render_views.py``). ``fx = fy = (H/2) / tan(fovy/2)``: MuJoCo's fovy
is vertical.

A camera is a MuJoCo *free* camera (``lookat``, ``distance``, ``azimuth``, ``elevation``, degrees),
which has no roll: its up vector lies in the vertical plane through the viewing direction. That
is what MuJoCo renders, so the matrices below are exact for its pixels (the headlight follows it).
"""

from __future__ import annotations

import json
import os
import pickle
from dataclasses import dataclass, field

import mujoco
import numpy as np

from .._gl import RenderWorkers
from ..files import atomic_path
from ..files import check_robot
from ..errors import CorruptFileError, InputError

__all__ = ["Cameras", "ring_cameras", "sphere_cameras", "Views", "make_views", "robot_visual_model"]


# --------------------------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Cameras:
    """C free cameras sharing one image size and vertical field of view.

    ``lookat`` (C, 3) metres, ``distance`` (C,) metres, ``azimuth`` and ``elevation`` (C,)
    degrees (MuJoCo's: negative elevation looks down), ``fovy`` degrees, ``width``/``height``
    pixels.
    """

    lookat: np.ndarray
    distance: np.ndarray
    azimuth: np.ndarray
    elevation: np.ndarray
    width: int = 128
    height: int = 128
    fovy: float = 45.0

    def __post_init__(self):
        la = np.asarray(self.lookat, dtype=np.float64).reshape(-1, 3)
        n = len(la)
        arrs = {k: np.broadcast_to(np.asarray(getattr(self, k), dtype=np.float64), (n,)).copy()
                for k in ("distance", "azimuth", "elevation")}
        object.__setattr__(self, "lookat", la)
        for k, v in arrs.items():
            object.__setattr__(self, k, v)
        vals = np.concatenate([la.ravel(), *arrs.values(), [self.fovy]])
        if not np.isfinite(vals).all():
            raise InputError("Cameras: lookat, distance, azimuth, elevation and fovy must be finite")
        if (arrs["distance"] <= 0).any():
            raise InputError("Cameras: distance must be positive (metres)")
        if not 0 < self.fovy < 180:
            raise InputError(f"Cameras: fovy must be in (0, 180) degrees; got {self.fovy}")
        if int(self.width) < 1 or int(self.height) < 1:
            raise InputError(f"Cameras: image size must be positive; got {self.width}x{self.height}")

    def __len__(self) -> int:
        return len(self.lookat)

    def __getitem__(self, idx) -> "Cameras":
        idx = np.atleast_1d(np.arange(len(self))[idx])
        return Cameras(self.lookat[idx], self.distance[idx], self.azimuth[idx], self.elevation[idx],
                       self.width, self.height, self.fovy)

    def resized(self, width: int, height: int | None = None) -> "Cameras":
        """The same views at another resolution (same fovy)."""
        return Cameras(self.lookat, self.distance, self.azimuth, self.elevation, int(width),
                       int(height if height is not None else width), self.fovy)

    # ---- OpenCV matrices -------------------------------------------------------------------
    def frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Camera centre (C, 3), forward (C, 3) and up (C, 3), as ``mjv_updateCamera`` computes
        them for a free camera: ``forward = (cos e cos a, cos e sin a, sin e)``."""
        a, e = np.deg2rad(self.azimuth), np.deg2rad(self.elevation)
        fwd = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1)
        up = np.stack([-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)], -1)
        pos = self.lookat - self.distance[:, None] * fwd
        return pos, fwd, up

    @property
    def world_to_cam(self) -> np.ndarray:
        """(C, 4, 4): rows of R are the camera's right, down and forward axes; t = -R c."""
        pos, fwd, up = self.frames()
        right = np.cross(fwd, up)
        R = np.stack([right, -up, fwd], axis=1)
        T = np.zeros((len(self), 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = -np.einsum("cij,cj->ci", R, pos)
        T[:, 3, 3] = 1
        return T

    @property
    def K(self) -> np.ndarray:
        """(C, 3, 3) intrinsics, pixel centres at integers."""
        f = (self.height / 2) / np.tan(np.deg2rad(self.fovy) / 2)
        K = np.array([[f, 0, self.width / 2 - 0.5], [0, f, self.height / 2 - 0.5], [0, 0, 1]])
        return np.broadcast_to(K, (len(self), 3, 3)).copy()

    def to_dict(self) -> dict:
        return dict(lookat=self.lookat.tolist(), distance=self.distance.tolist(), azimuth=self.azimuth.tolist(),
                    elevation=self.elevation.tolist(), width=int(self.width), height=int(self.height), fovy=float(self.fovy))

    @classmethod
    def from_dict(cls, d: dict) -> "Cameras":
        return cls(**d)

    def mjv_camera(self, i: int) -> mujoco.MjvCamera:
        """Camera ``i`` as MuJoCo's free ``MjvCamera`` (for ``mujoco.Renderer.update_scene``)."""
        if not 0 <= int(i) < len(self):
            raise IndexError(f"camera {i} out of range for {len(self)} cameras")
        return _free_camera(self.lookat[i], self.distance[i], self.azimuth[i], self.elevation[i])


def ring_cameras(n: int = 4, *, distance: float = 1.8, elevation: float | list = -20.0, azimuth0: float = 0.0,
                 lookat=(0.0, 0.0, 0.4), size: int = 128, fovy: float = 45.0) -> Cameras:
    """``n`` cameras evenly spaced in azimuth around ``lookat`` (one ring per elevation given)."""
    els = np.atleast_1d(np.asarray(elevation, dtype=float))
    az = (azimuth0 + 360.0 * np.arange(n) / n)
    A, E = np.meshgrid(az, els)
    m = A.size
    return Cameras(np.tile(np.asarray(lookat, dtype=float), (m, 1)), np.full(m, distance), A.ravel(), E.ravel(),
                   size, size, fovy)


def sphere_cameras(n: int, *, distance: float = 1.8, elevation_range=(-60.0, 30.0), lookat=(0.0, 0.0, 0.4),
                   size: int = 128, fovy: float = 45.0, seed: int = 0, jitter: float = 0.0) -> Cameras:
    """``n`` cameras on a sphere cap (Fibonacci spiral in azimuth and uniform in sin(elevation)),
    looking at ``lookat``; ``jitter`` (metres) shifts each lookat randomly, as Dr. Robot does."""
    rng = np.random.default_rng(seed)
    i = np.arange(n) + 0.5
    s0, s1 = np.sin(np.deg2rad(elevation_range))
    el = np.rad2deg(np.arcsin(s0 + (s1 - s0) * i / n))
    az = (i * 137.50776405) % 360.0
    la = np.asarray(lookat, dtype=float) + jitter * rng.uniform(-1, 1, (n, 3))
    return Cameras(la, np.full(n, distance), az, el, size, size, fovy)


# --------------------------------------------------------------------------------------------
# MuJoCo rendering
# --------------------------------------------------------------------------------------------

def robot_visual_model(robot) -> mujoco.MjModel:
    """A copy of the robot's model in which only the robot is drawn: world-body geoms (floor,
    obstacles) get alpha 0, which MuJoCo's scene builder skips."""
    import copy

    m = copy.deepcopy(robot.mj_model)
    world = m.geom_bodyid == 0
    m.geom_rgba[world, 3] = 0.0
    m.geom_matid[world] = -1
    return m


def _free_camera(lookat, distance, azimuth, elevation) -> mujoco.MjvCamera:
    """A MuJoCo free camera (metres, degrees)."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = lookat
    cam.distance, cam.azimuth, cam.elevation = float(distance), float(azimuth), float(elevation)
    return cam


class _MjViews:
    """One MuJoCo renderer (one GL context, made on first use of ``r``) for one model and image
    size. It runs in a render worker (:mod:`profrobot._gl`); :meth:`gl_camera` needs no GL."""

    def __init__(self, model: mujoco.MjModel, cameras: Cameras):
        self.m = model
        self.m.vis.global_.fovy = cameras.fovy
        self.d = mujoco.MjData(model)
        self.cams = cameras
        self._r = None
        robot_geom = np.asarray(model.geom_bodyid) != 0
        self.robot_geom = np.concatenate([robot_geom, [False]])  # index -1 (background) → False

    @property
    def r(self) -> mujoco.Renderer:
        """The renderer, made (with its GL context) on first use."""
        if self._r is None:
            self._r = mujoco.Renderer(self.m, self.cams.height, self.cams.width)
        return self._r

    def camera(self, c: int) -> mujoco.MjvCamera:
        return self.cams.mjv_camera(c)

    def render(self, qpos: np.ndarray):
        """One pose (K,) over all C cameras → rgb (C,H,W,3) uint8, depth (C,H,W) metres (0 off the
        robot), mask (C,H,W) bool."""
        m, d, cams = self.m, self.d, self.cams
        r = self.r
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)
        C, H, W = len(cams), cams.height, cams.width
        rgb = np.empty((C, H, W, 3), np.uint8)
        depth = np.empty((C, H, W), np.float32)
        mask = np.empty((C, H, W), bool)
        for c in range(C):
            r.update_scene(d, self.camera(c))
            rgb[c] = r.render()
            r.enable_depth_rendering()
            depth[c] = r.render()
            r.disable_depth_rendering()
            r.enable_segmentation_rendering()
            seg = r.render()
            r.disable_segmentation_rendering()
            is_geom = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
            mask[c] = is_geom & self.robot_geom[np.where(is_geom, seg[..., 0], -1)]
        depth[~mask] = 0.0
        return rgb, depth, mask

    def gl_camera(self, c: int):
        """MuJoCo's own (averaged) GL camera for camera ``c``: for checking :class:`Cameras`."""
        scn = mujoco.MjvScene(self.m, maxgeom=max(1, self.m.ngeom))
        mujoco.mjv_updateScene(self.m, self.d, mujoco.MjvOption(), None, self.camera(c),
                               mujoco.mjtCatBit.mjCAT_ALL.value, scn)
        return mujoco.mjv_averageCamera(scn.camera[0], scn.camera[1])

    def close(self):
        if self._r is not None:
            self._r.close()
            self._r = None


# Render-worker entry points (profrobot._gl.RenderWorkers runs them in its subprocesses).
_WORKER: _MjViews | None = None


def _worker_init(model_bytes: bytes, cameras: Cameras) -> None:
    global _WORKER
    import pickle

    if _WORKER is not None:
        _WORKER.close()
    _WORKER = _MjViews(pickle.loads(model_bytes), cameras)
    _WORKER.r  # noqa: B018  (the GL context, now)


def _worker_render(qpos_chunk: np.ndarray):
    out = [_WORKER.render(q) for q in qpos_chunk]
    return tuple(np.stack(x) for x in zip(*out))


class _MjFrames:
    """RGB frames of poses from one free camera (contact points shown): trajectory pictures."""

    def __init__(self, model: mujoco.MjModel, qpos_adr, size: tuple[int, int], camera: dict):
        self.m, self.d, self.adr = model, mujoco.MjData(model), np.asarray(qpos_adr)
        width, height = size
        self.cam = _free_camera(camera["lookat"], camera["distance"], camera["azimuth"], camera["elevation"])
        self.opt = mujoco.MjvOption()
        self.opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT] = 1  # show where it touches
        self.r = mujoco.Renderer(model, height, width)

    def render(self, poses: np.ndarray) -> np.ndarray:
        out = []
        for q in poses:
            self.d.qpos[self.adr] = q
            mujoco.mj_forward(self.m, self.d)
            self.r.update_scene(self.d, camera=self.cam, scene_option=self.opt)
            out.append(self.r.render())
        return np.stack(out)

    def close(self):
        self.r.close()


_FRAMES: _MjFrames | None = None


def _frames_init(model_bytes: bytes, qpos_adr, size: tuple[int, int], camera: dict) -> None:
    global _FRAMES
    import pickle

    if _FRAMES is not None:
        _FRAMES.close()
    _FRAMES = _MjFrames(pickle.loads(model_bytes), qpos_adr, size, camera)


def _frames_render(poses: np.ndarray) -> np.ndarray:
    return _FRAMES.render(poses)


def _release() -> None:
    """Free a worker's renderers (its GL contexts) between calls."""
    global _WORKER, _FRAMES
    for r in (_WORKER, _FRAMES):
        if r is not None:
            r.close()
    _WORKER = _FRAMES = None


# --------------------------------------------------------------------------------------------
# Datasets
# --------------------------------------------------------------------------------------------

@dataclass
class Views:
    """Renders of P poses from C cameras.

    ``poses`` (P, K) radians/metres; ``rgb`` (P, C, H, W, 3) uint8; ``depth`` (P, C, H, W)
    float32 metres along the camera's z axis, 0 off the robot; ``mask`` (P, C, H, W) bool.
    """

    poses: np.ndarray
    cameras: Cameras
    rgb: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    robot_fingerprint: str = ""
    robot_name: str = ""
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def background(self) -> np.ndarray:
        """(3,) background colour in [0, 1] (the median off-robot pixel of the renders)."""
        return np.asarray(self.meta.get("background", [0.0, 0.0, 0.0]), dtype=np.float64)

    def __getitem__(self, idx) -> "Views":
        idx = np.atleast_1d(np.arange(len(self))[idx])
        return Views(self.poses[idx], self.cameras, self.rgb[idx], self.depth[idx], self.mask[idx],
                     self.robot_fingerprint, self.robot_name, dict(self.meta))

    def save(self, path: str | os.PathLike) -> None:
        """Compressed ``.npz`` with a JSON header (robot fingerprint, cameras); written to a
        temporary file in the same directory and renamed, so a crash never leaves half a file."""
        path = os.fspath(path)
        header = dict(format="profrobot.views/1", robot_fingerprint=self.robot_fingerprint,
                      robot_name=self.robot_name, cameras=self.cameras.to_dict(), meta=self.meta)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, header=np.frombuffer(json.dumps(header).encode(), np.uint8),
                                poses=self.poses, rgb=self.rgb, depth=self.depth, mask=np.packbits(self.mask, axis=-1),
                                mask_width=np.int64(self.mask.shape[-1]))

    @classmethod
    def load(cls, path: str | os.PathLike, robot=None) -> "Views":
        """Load a dataset; with ``robot``, refuse one rendered from another robot."""
        try:
            z = np.load(os.fspath(path))
            header = json.loads(z["header"].tobytes().decode())
            if header.get("format") != "profrobot.views/1":
                raise InputError(f"unknown format {header.get('format')!r}")
            mask = np.unpackbits(z["mask"], axis=-1, count=int(z["mask_width"])).astype(bool)
            v = cls(z["poses"], Cameras.from_dict(header["cameras"]), z["rgb"], z["depth"], mask,
                    header["robot_fingerprint"], header["robot_name"], header.get("meta", {}))
        except (OSError, KeyError, ValueError, EOFError) as e:
            raise CorruptFileError(f"{path}: not a readable profrobot views file ({e})") from e
        if robot is not None:
            check_robot(dict(robot_fingerprint=v.robot_fingerprint, robot_name=v.robot_name), robot, f"views {path}")
        return v


def make_views(robot, poses, cameras: Cameras, size: int | None = None, *, processes: int = 1,
               progress: bool = True, chunk: int = 8, executor=None) -> Views:
    """Render ``poses`` (P, K) of ``robot`` from ``cameras`` with MuJoCo, offscreen. Only the
    robot is drawn (world-body geoms are hidden); the background is MuJoCo's clear colour (black).

    MuJoCo's OpenGL runs in ``processes`` render worker processes (each with its own GL context),
    never in this one; the backend is ``MUJOCO_GL`` if set, else the first of EGL and OSMesa that
    works (:mod:`profrobot._gl`). Raises :class:`profrobot.RendererUnavailableError` (saying what
    to install) when none does.

    ``size``: if given, the cameras are re-rendered at ``size`` x ``size``; ``chunk``: poses per
    request to a worker.

    ``executor``: ``None`` (the local render workers above) or a
    :class:`profrobot.executors.RayExecutor`, whose actors (each holding the robot and one
    MuJoCo renderer, its backend chosen on its node as above) render the same chunks; the views
    are byte-identical to the local ones (``processes`` is then ignored: the executor's workers
    render).
    """
    from tqdm.auto import tqdm

    from ..executors import check_executor

    executor = check_executor(executor)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != robot.njoint:
        raise InputError(f"poses must have shape (P, {robot.njoint}); got {poses.shape}")
    if not np.isfinite(poses).all():
        raise InputError("poses contain NaN or inf")
    if not isinstance(cameras, Cameras):
        raise TypeError(f"cameras must be a profrobot.render.Cameras; got {type(cameras).__name__}")
    if size is not None:
        cameras = cameras.resized(size)
    m = robot_visual_model(robot)
    qpos = np.tile(m.qpos0, (len(poses), 1))
    qpos[:, robot.qpos_adr] = poses
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise InputError(f"chunk must be a positive integer; got {chunk!r}")
    if executor is not None:
        bounds = [(i, min(i + chunk, len(qpos))) for i in range(0, len(qpos), chunk)]
        ref = executor.put(qpos)  # once, through the object store; each chunk names its rows
        parts = executor.map_chunks(robot, "render", [(cameras, ref, a, b) for a, b in bounds],
                                    sizes=[b - a for a, b in bounds], desc="MuJoCo views", unit="pose",
                                    progress=progress)
        return _views_of(robot, poses, cameras, parts)
    chunks = [qpos[i:i + chunk] for i in range(0, len(qpos), chunk)]
    parts = []
    with RenderWorkers(min(processes, len(chunks))) as workers:
        workers.call(__name__, "_worker_init", pickle.dumps(m), cameras)
        with tqdm(total=len(poses), desc="MuJoCo views", unit="pose", disable=not progress) as bar:
            for out, ch in zip(workers.map(__name__, "_worker_render", chunks), chunks):
                parts.append(out)
                bar.update(len(ch))
        workers.call(__name__, "_release")
    return _views_of(robot, poses, cameras, parts)


def _views_of(robot, poses: np.ndarray, cameras: Cameras, parts: list) -> Views:
    """The chunks' renders, in chunk order, as one :class:`Views`."""
    rgb, depth, mask = (np.concatenate(x) for x in zip(*parts))
    # MuJoCo's background (skybox or clear colour): the median off-robot pixel, for compositing
    off = rgb[~mask]
    bg = (np.median(off, axis=0) / 255.0).tolist() if len(off) else [0.0, 0.0, 0.0]
    return Views(poses, cameras, rgb, depth, mask, robot.fingerprint, robot.name, dict(background=bg))
