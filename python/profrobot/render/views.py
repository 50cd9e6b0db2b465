"""Multi-view training data from MuJoCo: RGB, metric depth and the robot mask of P poses from C
cameras (:class:`Views`, saved to one ``.npz``), made by :func:`make_views`.

The cameras (:mod:`.cameras`) are OpenCV-convention matrices that match MuJoCo's pixels; the
renderer and its chunk function are in :mod:`.mjviews`, and run wherever the executor puts them
(:mod:`profrobot.executors`): never in this process.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from ..errors import CorruptFileError, InputError, InputTypeError
from ..executors import Executor, chunk_bounds, chunk_sizes, check_executor
from ..files import atomic_path, check_format, check_robot, format_tag
from .cameras import Cameras, ring_cameras, sphere_cameras  # noqa: F401  (their home before the split)
from ..robot.family import Layout
from ..robot.gate import with_layout
from ..robot.robot import Robot
from .mjviews import render_depth_chunk, render_views_chunk

__all__ = ["Views", "make_views", "render_depth"]


FORMAT_VERSION = 1  # compressed .npz: a JSON header (format, robot, cameras, meta), poses, rgb, depth, packed mask

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
    fingerprint: str = ""
    robot_name: str = ""
    metadata: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def background(self) -> np.ndarray:
        """(3,) background colour in [0, 1] (the median off-robot pixel of the renders)."""
        return np.asarray(self.metadata.get("background", [0.0, 0.0, 0.0]), dtype=np.float64)

    def __getitem__(self, idx) -> "Views":
        idx = np.atleast_1d(np.arange(len(self))[idx])
        return Views(self.poses[idx], self.cameras, self.rgb[idx], self.depth[idx], self.mask[idx],
                     self.fingerprint, self.robot_name, dict(self.metadata))

    def save(self, path: str | os.PathLike) -> Path:
        """Compressed ``.npz`` with a JSON header (robot fingerprint, cameras); written to a
        temporary file in the same directory and renamed, so a crash never leaves half a file."""
        path = os.fspath(path)
        header = dict(format=format_tag("views", FORMAT_VERSION), robot_fingerprint=self.fingerprint,
                      robot_name=self.robot_name, cameras=self.cameras.to_dict(), meta=self.metadata)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez_compressed(f, header=np.frombuffer(json.dumps(header).encode(), np.uint8),
                                poses=self.poses, rgb=self.rgb, depth=self.depth, mask=np.packbits(self.mask, axis=-1),
                                mask_width=np.int64(self.mask.shape[-1]))
        return Path(path)

    @classmethod
    def load(cls, path: str | os.PathLike, robot: Robot | None = None) -> "Views":
        """Load a view set saved by :meth:`save`; with ``robot``, refuse one rendered from another
        robot. A newer or foreign file raises :class:`~profrobot.errors.CorruptFileError`."""
        try:
            z = np.load(os.fspath(path))
            header = json.loads(z["header"].tobytes().decode())
        except (OSError, KeyError, ValueError, EOFError) as e:
            raise CorruptFileError(f"{path}: not a readable profrobot views file ({e})") from e
        check_format(header.get("format") if isinstance(header, dict) else header, "views", FORMAT_VERSION, str(path))
        try:
            mask = np.unpackbits(z["mask"], axis=-1, count=int(z["mask_width"])).astype(bool)
            v = cls(z["poses"], Cameras.from_dict(header["cameras"]), z["rgb"], z["depth"], mask,
                    header["robot_fingerprint"], header["robot_name"], header.get("meta", {}))
        except (OSError, KeyError, ValueError, EOFError) as e:
            raise CorruptFileError(f"{path}: not a readable profrobot views file ({e})") from e
        if robot is not None:
            check_robot(dict(robot_fingerprint=v.fingerprint, robot_name=v.robot_name), robot, f"views {path}", geometry=True)
        return v


def make_views(robot: Robot, poses: npt.ArrayLike, cameras: Cameras, size: int | None = None, *,
               layout: Layout | None = None, processes: int = 1, progress: bool = True, chunk: int = 8,
               executor: Executor | None = None) -> Views:
    """Render ``poses`` (P, K) of ``robot`` from ``cameras`` with MuJoCo, offscreen. Only the
    robot is drawn (world-body geoms are hidden); the background is MuJoCo's clear colour (black).

    The poses are cut into chunks of ``chunk`` (:func:`profrobot.executors.chunk_bounds`), each
    rendered by :func:`profrobot.render.mjviews.render_views_chunk` where ``executor`` puts it:
    ``None`` means :class:`profrobot.executors.LocalExecutor` with ``processes`` render worker
    processes (each with its own GL context), never this one; the backend is ``MUJOCO_GL`` if
    set, else the first of EGL and OSMesa that works (:mod:`profrobot.gl`). Raises
    :class:`profrobot.RendererUnavailableError` (saying what to install) when none does. A
    :class:`profrobot.executors.RayExecutor` renders the same chunks on its actors (each holding
    the robot and one MuJoCo renderer, its backend chosen on its node as above); the views are
    byte-identical to the local ones (``processes`` is then ignored).

    ``size``: if given, the cameras are re-rendered at ``size`` x ``size``. ``layout``: a family's
    layout δ (:mod:`profrobot.robot.gate`); ``poses`` are then its θ (P, K − D), and the views hold
    the full poses. No ``margin``: a margin widens obstacles for the exact answers, and the renderer
    draws the robot as modelled.
    """
    poses = _check_poses(robot, with_layout(robot, poses, layout), cameras)
    if size is not None:
        cameras = cameras.resized(size)
    parts = _render_chunks(render_views_chunk, robot, poses, cameras, executor, processes, chunk, "MuJoCo views",
                           progress)
    return _views_of(robot, poses, cameras, parts)


def _check_poses(robot, poses, cameras) -> np.ndarray:
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != robot.njoint:
        raise InputError(f"poses must have shape (P, {robot.njoint}); got {poses.shape}")
    if not np.isfinite(poses).all():
        raise InputError("poses contain NaN or inf")
    if not isinstance(cameras, Cameras):
        raise InputTypeError(f"cameras must be a profrobot.render.Cameras; got {type(cameras).__name__}")
    return poses


def _render_chunks(fn, robot, poses: np.ndarray, cameras: Cameras, executor, processes: int, chunk: int, desc: str,
                   progress: bool) -> list:
    """``fn`` (a chunk function of :mod:`.mjviews`) over the poses' full qpos in chunks of
    ``chunk``, where ``executor`` puts them; the chunks' results in order."""
    executor = check_executor(executor, processes=processes)
    qpos = np.tile(robot.mj_model.qpos0, (len(poses), 1))
    qpos[:, robot.qpos_adr] = poses
    bounds = chunk_bounds(len(qpos), chunk)
    ref = executor.put(qpos)  # once (Ray: through the object store); each chunk names its rows
    return executor.map(fn, [(cameras, ref, a, b) for a, b in bounds], robot=robot, sizes=chunk_sizes(bounds),
                        desc=desc, unit="pose", progress=progress)


def render_depth(robot: Robot, poses: npt.ArrayLike, cameras: Cameras, *, layout: Layout | None = None,
                 processes: int = 1, progress: bool = False, chunk: int = 8,
                 executor: Executor | None = None) -> np.ndarray:
    """Depth images (P, C, H, W) float32 of the whole scene (robot and obstacles; a family's at
    each pose's scene joints) at ``poses`` (P, K) from ``cameras``: metres along each camera's z
    axis, 0 where no geom is seen. Rendered by MuJoCo like :func:`make_views` (same executors,
    same GL choice), pinhole only (lens distortion: render ``cameras.undistorted()``). ``layout``:
    a family's layout δ, one for all poses or (P, D), ``poses`` then θ (:mod:`profrobot.robot.gate`);
    no ``margin``, as in :func:`make_views`."""
    poses = _check_poses(robot, with_layout(robot, poses, layout), cameras)
    return np.concatenate(_render_chunks(render_depth_chunk, robot, poses, cameras, executor, processes, chunk,
                                         "MuJoCo depth", progress))


def _views_of(robot, poses: np.ndarray, cameras: Cameras, parts: list) -> Views:
    """The chunks' renders, in chunk order, as one :class:`Views`."""
    rgb, depth, mask = (np.concatenate(x) for x in zip(*parts))
    # MuJoCo's background (skybox or clear colour): the median off-robot pixel, for compositing
    off = rgb[~mask]
    bg = (np.median(off, axis=0) / 255.0).tolist() if len(off) else [0.0, 0.0, 0.0]
    return Views(poses, cameras, rgb, depth, mask, robot.fingerprint, robot.name, dict(background=bg))
