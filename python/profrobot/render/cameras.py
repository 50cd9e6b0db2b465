"""Cameras: MuJoCo free cameras and the OpenCV matrices that match MuJoCo's pixels.

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
from dataclasses import dataclass

import mujoco
import numpy as np

from ..errors import InputError

__all__ = ["Cameras", "ring_cameras", "sphere_cameras", "free_camera"]


@dataclass(frozen=True, eq=False)
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

    def __eq__(self, other) -> bool:
        """Same cameras: the same :meth:`to_dict`, value for value."""
        if not isinstance(other, Cameras):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(json.dumps(self.to_dict()))

    def mjv_camera(self, i: int) -> mujoco.MjvCamera:
        """Camera ``i`` as MuJoCo's free ``MjvCamera`` (for ``mujoco.Renderer.update_scene``)."""
        if not 0 <= int(i) < len(self):
            raise IndexError(f"camera {i} out of range for {len(self)} cameras")
        return free_camera(self.lookat[i], self.distance[i], self.azimuth[i], self.elevation[i])


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


def free_camera(lookat, distance, azimuth, elevation) -> mujoco.MjvCamera:
    """A MuJoCo free camera (metres, degrees)."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = lookat
    cam.distance, cam.azimuth, cam.elevation = float(distance), float(azimuth), float(elevation)
    return cam
