"""Pictures of a trajectory: MuJoCo's offscreen renderer to a GIF (Pillow) or MP4 (imageio, if
installed), colliding frames marked; joint curves and g along the path as a matplotlib plot.

MuJoCo renders in a worker process with a backend it chose (``MUJOCO_GL`` if set, else EGL, then
OSMesa: :mod:`profrobot.gl`); :class:`profrobot.RendererUnavailableError` says what to install
when none works.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..files import atomic_path
from ..exact.certification import certify_poses
from ..robot.robot import Robot
from ..errors import InputError

# A view from the front-left, above the table; override with ``camera=``.
DEFAULT_CAMERA = dict(lookat=(0.25, 0.0, 0.35), distance=2.3, azimuth=60.0, elevation=-25.0)


def trajectory_frames(robot: Robot, path: np.ndarray, collides: np.ndarray, size: tuple[int, int], camera,
                      chunk: int = 32) -> list:
    """``path`` (S, K) as S Pillow images of ``size`` (width, height) from ``camera`` (a free
    camera's lookat, distance, azimuth, elevation, or a one-camera
    :class:`profrobot.render.Cameras`, e.g. a calibrated one), the whole scene drawn, frames where ``collides``
    framed red and captioned. MuJoCo draws ``chunk`` poses at a time in a render worker
    (:func:`profrobot.render.mjviews.render_frames_chunk` on a
    :class:`~profrobot.executors.LocalExecutor`); Pillow marks them here."""
    from PIL import Image, ImageDraw

    from ..executors import LocalExecutor, chunk_bounds
    from ..render.mjviews import render_frames_chunk

    width, height = size
    if width < 1 or height < 1:
        raise InputError(f"size must be positive (width, height) pixels; got {size}")
    chunks = [(path[a:b], (width, height), camera) for a, b in chunk_bounds(len(path), chunk)]
    rgb = np.concatenate(LocalExecutor(processes=1).map(render_frames_chunk, chunks, robot=robot, progress=False))
    frames = []
    for i, pixels in enumerate(rgb):
        img = Image.fromarray(pixels)
        draw = ImageDraw.Draw(img)
        if collides[i]:  # a red frame and a caption: the exact labeller finds a collision here
            draw.rectangle([0, 0, width - 1, height - 1], outline=(230, 20, 20), width=6)
            draw.text((10, height - 22), "COLLISION", fill=(255, 40, 40))
        draw.text((10, 8), f"{i + 1}/{len(path)}", fill=(255, 255, 255))
        frames.append(img)
    return frames


def render_trajectory(robot: Robot, path, out: str | os.PathLike, *, collides=None, fps: int = 20,
                      size: tuple[int, int] | None = None, camera=None) -> Path:
    """Render ``path`` (S, K) with MuJoCo to ``out`` (.gif, or .mp4 with imageio installed).

    ``collides`` (S,) bool marks frames with a red border (default: the poses that are
    not certified free, :mod:`profrobot.exact.certification`). ``camera``: a dict of lookat, distance,
    azimuth, elevation (a free camera; missing keys from the default view), or a one-camera
    :class:`profrobot.render.Cameras` (e.g. the rig's, ``cams[2]``). ``size`` (width, height):
    default the camera's own size for a :class:`~profrobot.render.Cameras`, else (480, 360). The
    file is written atomically.
    """
    from ..exact.labels import as_poses

    path = as_poses(robot, path, name="path")
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise InputError(f"out must end in .gif or .mp4; got {out.name!r}")
    collides = ~certify_poses(robot, path) if collides is None else np.asarray(collides, dtype=bool)
    if collides.shape != (len(path),):
        raise InputError(f"collides must have shape ({len(path)},); got {collides.shape}")
    if hasattr(camera, "world_to_cam"):          # a profrobot.render.Cameras (duck-typed: no render import here)
        if len(camera) != 1:
            raise InputError(f"camera must be one camera (e.g. cams[0]); got {len(camera)}")
        size = (camera.width, camera.height) if size is None else size
    else:
        camera = {**DEFAULT_CAMERA, **(camera or {})}
        size = (480, 360) if size is None else size
    width, height = (int(s) for s in size)
    frames = trajectory_frames(robot, path, collides, (width, height), camera)
    with atomic_path(out) as tmp:
        if suffix == ".gif":
            frames[0].save(tmp, save_all=True, append_images=frames[1:], duration=int(1000 / fps), loop=0)
        else:
            try:
                import imageio.v3 as iio
            except ImportError as e:
                raise InputError("MP4 output needs imageio with its ffmpeg plugin; write a .gif instead") from e
            iio.imwrite(tmp, np.stack([np.asarray(f) for f in frames]), fps=fps)
    return out


def plot_trajectory(result, out: str | os.PathLike, *, joint_names=None, l_thres: float | None = -0.1,
                    straight=None) -> Path:
    """Joint curves (top) and g along the path (bottom) of a TrajectoryResult (or an object with
    ``path`` (S, K), ``g`` (S,), ``waypoint_uncertified`` (S,)), saved atomically as an image.
    ``straight``: optionally the g values (S,) of the straight interpolation, drawn dashed."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ..viz import save_figure

    path, g = np.asarray(result.path), np.asarray(result.g)
    S, K = path.shape
    names = joint_names or [f"joint {k}" for k in range(K)]
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for k in range(K):
        ax1.plot(path[:, k], label=names[k])
    ax1.set_ylabel("θ (rad / m)")
    ax1.legend(fontsize=7, ncol=3, loc="best")
    ax2.plot(g, color="k", label="g along the path")
    if straight is not None:
        ax2.plot(np.asarray(straight), "k--", alpha=0.5, label="g, straight interpolation")
    if l_thres is not None:
        ax2.axhline(l_thres, color="tab:blue", lw=0.8, label=f"l_thres = {l_thres}")
    ax2.axhline(0, color="tab:red", lw=0.8)
    hit = np.flatnonzero(np.asarray(result.waypoint_uncertified))
    if len(hit):
        ax2.scatter(hit, g[hit], color="tab:red", zorder=3, label="colliding (exact)")
    ax2.set_xlabel("waypoint")
    ax2.set_ylabel("g (g > 0: colliding)")
    ax2.legend(fontsize=7, loc="best")
    title = getattr(result, "summary", None)
    if callable(title):
        fig.suptitle(title(), fontsize=8)
    fig.tight_layout()
    try:
        return save_figure(fig, out, dpi=110)
    finally:
        plt.close(fig)
