"""MuJoCo's offscreen renderer for profrobot: multi-view renders of the robot alone (RGB, metric
depth, mask) and trajectory frames of the whole scene, and the chunk functions executors run for
them in drawing processes (never in the caller's: see :mod:`profrobot.gl`).

Each drawing process keeps one renderer per kind (and its GL context) for the robot and cameras
of its last chunk, here, beside the chunk functions; :func:`release_renderers` frees them (local
workers do when a call ends, :func:`profrobot.executors.on_release`).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt

from ..executors.base import on_release
from ..gl import renderer as gl_renderer, uses_gl
from ..errors import InputError
from ..robot.robot import Robot
from .cameras import Cameras, free_camera

__all__ = ["robot_visual_model", "MjViews", "MjFrames", "render_views_chunk", "render_depth_chunk", "render_frames_chunk",
           "update_scene", "set_gl_camera", "release_renderers"]


def robot_visual_model(robot: Robot) -> mujoco.MjModel:
    """A copy of the robot's model in which only the robot is drawn: world-body geoms (floor,
    obstacles) get alpha 0, which MuJoCo's scene builder skips."""
    m = copy.deepcopy(robot.mj_model)
    world = m.geom_bodyid == 0
    m.geom_rgba[world, 3] = 0.0
    m.geom_matid[world] = -1
    return m


class MjViews:
    """One MuJoCo renderer (one GL context, made on first use of :attr:`r`) for one model and
    camera set; :meth:`gl_camera` needs no GL."""

    def __init__(self, model: mujoco.MjModel, cameras: Cameras, *, whole_scene: bool = False):
        if cameras.distortion is not None:
            raise InputError("MuJoCo renders pinhole images: these cameras have lens distortion; render from "
                             "cameras.undistorted() (targets are undistorted to it: profrobot.render.distortion)")
        self.m = model
        _fit_buffer(model, cameras.width, cameras.height)
        if cameras.is_free:
            self.m.vis.global_.fovy = cameras.fovy
        self.d = mujoco.MjData(model)
        self.cams = cameras
        self._r = None
        robot_geom = np.asarray(model.geom_bodyid) != 0
        if whole_scene:  # every geom counts, and depth is kept wherever one is seen
            robot_geom[:] = True
        self.robot_geom = np.concatenate([robot_geom, [False]])  # index -1 (background) → False

    @property
    def r(self) -> mujoco.Renderer:
        """The renderer, made (with its GL context) on first use."""
        if self._r is None:
            self._r = gl_renderer(self.m, self.cams.height, self.cams.width)
        return self._r

    def render(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
            update_scene(m, d, r.scene, cams, c)
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

    def gl_camera(self, c: int) -> mujoco.MjvGLCamera:
        """MuJoCo's own (averaged) GL camera for camera ``c``: for checking :class:`Cameras`."""
        scn = mujoco.MjvScene(self.m, maxgeom=max(1, self.m.ngeom))
        update_scene(self.m, self.d, scn, self.cams, c)
        return mujoco.mjv_averageCamera(scn.camera[0], scn.camera[1])

    def close(self) -> None:
        if self._r is not None:
            self._r.close()
            self._r = None


def _fit_buffer(model: mujoco.MjModel, width: int, height: int) -> None:
    """Grow ``model``'s offscreen buffer (a copy's: callers pass their own) to ``width`` x
    ``height`` pixels where it is smaller (MuJoCo's default is 640 x 480; cameras are often larger)."""
    g = model.vis.global_
    g.offwidth, g.offheight = max(int(g.offwidth), int(width)), max(int(g.offheight), int(height))


def update_scene(m: mujoco.MjModel, d: mujoco.MjData, scn: mujoco.MjvScene, cameras: Cameras, c: int,
                 option: mujoco.MjvOption | None = None) -> None:
    """Build ``scn`` (e.g. a ``mujoco.Renderer``'s ``scene``) for camera ``c``: a free camera
    through MuJoCo's own ``MjvCamera``; any other from a placeholder free camera whose GL camera
    :func:`set_gl_camera` then replaces (the far plane, lights and geoms stay MuJoCo's)."""
    cam = cameras.mjv_camera(c) if cameras.is_free else free_camera((0, 0, 0), 1.0, 0.0, -30.0)
    mujoco.mjv_updateScene(m, d, option or mujoco.MjvOption(), None, cam, mujoco.mjtCatBit.mjCAT_ALL.value, scn)
    if not cameras.is_free:
        set_gl_camera(scn, cameras, c)


def set_gl_camera(scn: mujoco.MjvScene, cameras: Cameras, c: int) -> None:
    """Make camera ``c`` of ``cameras`` the scene's GL camera (both eyes, so the mono average is
    it): MuJoCo then renders exactly ``K`` and ``world_to_cam`` (:meth:`Cameras.gl_frustum`). The
    headlight, which ``mjv_updateScene`` placed at the camera it was given, follows."""
    near = scn.camera[0].frustum_near
    pos, fwd, up, (center, half, bottom, top) = cameras.gl_frustum(c, near)
    for g in (scn.camera[0], scn.camera[1]):
        g.pos[:], g.forward[:], g.up[:] = pos, fwd, up
        g.frustum_center, g.frustum_width, g.frustum_bottom, g.frustum_top = center, half, bottom, top
        g.orthographic = 0
    for i in range(scn.nlight):
        if scn.lights[i].headlight:
            scn.lights[i].pos[:], scn.lights[i].dir[:] = pos, fwd


class MjFrames:
    """RGB frames of poses from one camera, the whole scene drawn and contact points shown:
    trajectory pictures. ``size`` is (width, height); ``camera`` a dict of a free camera's
    lookat, distance, azimuth, elevation, or a one-camera :class:`Cameras` (drawn at ``size``
    through :meth:`Cameras.resized`)."""

    def __init__(self, model: mujoco.MjModel, qpos_adr: npt.ArrayLike, size: tuple[int, int],
                 camera: Cameras | Mapping[str, Any]):
        width, height = size
        if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
            model = copy.deepcopy(model)
            _fit_buffer(model, width, height)
        self.m, self.d, self.adr = model, mujoco.MjData(model), np.asarray(qpos_adr)
        if not isinstance(camera, Cameras):    # a free camera's dict, with the model's own fovy
            camera = Cameras.free([camera["lookat"]], camera["distance"], camera["azimuth"], camera["elevation"],
                                  width, height, float(model.vis.global_.fovy))
        if len(camera) != 1:
            raise InputError(f"trajectory pictures take one camera; got {len(camera)}")
        self.cams = camera.resized(width, height)
        if self.cams.is_free:
            self.m.vis.global_.fovy = self.cams.fovy
        self.opt = mujoco.MjvOption()
        self.opt.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT] = 1  # show where it touches
        self.r = gl_renderer(model, height, width)

    def render(self, poses: np.ndarray) -> np.ndarray:
        out = []
        for q in poses:
            self.d.qpos[self.adr] = q
            mujoco.mj_forward(self.m, self.d)
            update_scene(self.m, self.d, self.r.scene, self.cams, 0, self.opt)
            out.append(self.r.render())
        return np.stack(out)

    def close(self) -> None:
        self.r.close()


# --------------------------------------------------------------------------------------------
# Chunk functions (run by executors in drawing processes) and their per-process renderers
# --------------------------------------------------------------------------------------------

_VIEWS: tuple[object, Cameras, MjViews] | None = None      # (robot, cameras, renderer)
_DEPTH: tuple[object, Cameras, MjViews] | None = None      # (robot, cameras, renderer) of the whole scene
_FRAMES: tuple[object, tuple, MjFrames] | None = None      # (robot, (size, camera), renderer)


@uses_gl
def render_views_chunk(robot: Robot, cameras: Cameras, qpos: np.ndarray, start: int,
                       stop: int) -> tuple[np.ndarray, ...]:
    """Rows ``start:stop`` of ``qpos`` (P, nq: full MuJoCo qpos) rendered from ``cameras`` →
    ``(rgb, depth, mask)``, each stacked over the chunk's poses (see :meth:`MjViews.render`)."""
    global _VIEWS
    if _VIEWS is None or _VIEWS[0] is not robot or _VIEWS[1] != cameras:
        if _VIEWS is not None:
            _VIEWS[2].close()
            _VIEWS = None
        _VIEWS = (robot, cameras, MjViews(robot_visual_model(robot), cameras))
    views = _VIEWS[2]
    out = [views.render(q) for q in qpos[start:stop]]
    return tuple(np.stack(x) for x in zip(*out))


@uses_gl
def render_depth_chunk(robot: Robot, cameras: Cameras, qpos: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Rows ``start:stop`` of ``qpos`` (P, nq) drawn with the whole scene (robot and obstacles)
    from ``cameras`` → depth (S, C, H, W) float32, metres along each camera's z axis, 0 where no
    geom is seen: what a depth camera in the scene would measure, noise-free."""
    global _DEPTH
    if _DEPTH is None or _DEPTH[0] is not robot or _DEPTH[1] != cameras:
        if _DEPTH is not None:
            _DEPTH[2].close()
            _DEPTH = None
        _DEPTH = (robot, cameras, MjViews(copy.deepcopy(robot.mj_model), cameras, whole_scene=True))
    views = _DEPTH[2]
    return np.stack([views.render(q)[1] for q in qpos[start:stop]])


@uses_gl
def render_frames_chunk(robot: Robot, poses: np.ndarray, size: tuple[int, int],
                        camera: Cameras | Mapping[str, Any]) -> np.ndarray:
    """``poses`` (S, K) drawn with the whole scene from one camera (a free camera's dict or a
    one-camera :class:`Cameras`, see :class:`MjFrames`) → (S, H, W, 3) uint8."""
    global _FRAMES
    cam_key = json.dumps(camera.to_dict()) if isinstance(camera, Cameras) else repr(sorted(camera.items()))
    key = (tuple(int(s) for s in size), cam_key)
    if _FRAMES is None or _FRAMES[0] is not robot or _FRAMES[1] != key:
        if _FRAMES is not None:
            _FRAMES[2].close()
            _FRAMES = None
        model = copy.deepcopy(robot.mj_model) if isinstance(camera, Cameras) else robot.mj_model
        _FRAMES = (robot, key, MjFrames(model, robot.qpos_adr, size, camera))
    return _FRAMES[2].render(poses)


@on_release
def release_renderers() -> None:
    """Close this process's renderers (their GL contexts)."""
    global _VIEWS, _FRAMES, _DEPTH
    for cached in (_VIEWS, _FRAMES, _DEPTH):
        if cached is not None:
            cached[2].close()
    _VIEWS = _FRAMES = _DEPTH = None
