"""Certification by the exact labeller: what we return as safe is checked by the Rust
labeller (MuJoCo's collision rules, exact shapes), never by the learned field alone."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..labels import interpolate, label_poses
from ..robot import Robot
from ..errors import InputError


# Touching is not free: MuJoCo reports a contact at zero distance (e.g. a joint clamped at the
# limit where two links just meet), so a certified pose keeps at least this clearance (metres).
CLEARANCE = 1e-6


def _free(robot: Robot, poses: np.ndarray, clearance: float) -> np.ndarray:
    if clearance <= 0:
        return ~label_poses(robot, poses).collides
    lab = label_poses(robot, poses, distance=True)
    return ~lab.collides & (lab.min_distance > clearance)


def certify_poses(robot: Robot, poses: np.ndarray, clearance: float = CLEARANCE) -> np.ndarray:
    """(B,) bool: True where the exact labeller finds pose ``poses[i]`` (B, K) free, with every
    candidate pair at least ``clearance`` metres apart."""
    return _free(robot, np.asarray(poses, dtype=np.float64), float(clearance))


@dataclass
class PathCheck:
    """The exact labeller's verdict on a path of S waypoints.

    Attributes:
        free: the whole path is free: every waypoint and every dense sample between them.
        waypoint_collides: (S,) bool.
        segment_collides: (S−1,) bool, segment i joins waypoints i and i+1 (its end points included).
        dense: (S−1)·density + 1 poses checked, (D, K).
        dense_collides: (D,) bool.
    """

    free: bool
    waypoint_collides: np.ndarray
    segment_collides: np.ndarray
    dense: np.ndarray
    dense_collides: np.ndarray

    @property
    def colliding_segments(self) -> np.ndarray:
        """Indices i of segments [i, i+1] that collide somewhere."""
        return np.flatnonzero(self.segment_collides)


def check_path(robot: Robot, path: np.ndarray, density: int = 10, clearance: float = CLEARANCE) -> PathCheck:
    """Checks ``path`` (S, K) waypoints and ``density − 1`` SO(2)-interpolated poses between
    each consecutive pair (``density`` times finer than the waypoints); a pose counts as free
    with every candidate pair more than ``clearance`` metres apart."""
    path = np.asarray(path, dtype=np.float64)
    if path.ndim != 2 or len(path) < 2:
        raise InputError(f"path must have shape (S >= 2, K); got {path.shape}")
    if isinstance(density, bool) or not isinstance(density, (int, np.integer)) or density < 1:
        raise InputError(f"density must be a positive integer; got {density!r}")
    S, K = path.shape
    # (S−1, density+1, K): each segment with both its end points, so every segment is whole
    seg = interpolate(robot, path[:-1], path[1:], int(density) + 1)
    dense = np.concatenate([seg[:, :-1].reshape(-1, K), path[-1:]], axis=0)
    hit = ~_free(robot, dense, float(clearance))
    seg_hit = np.zeros(S - 1, dtype=bool)
    idx = np.arange(len(dense))
    # dense sample j lies in segment j // density; a shared end point belongs to both neighbours
    seg_hit[np.minimum(idx[hit] // density, S - 2)] = True
    ends = idx[hit][(idx[hit] % density == 0) & (idx[hit] > 0)] // density - 1
    seg_hit[ends[ends >= 0]] = True
    way = hit[::density]
    return PathCheck(free=not hit.any(), waypoint_collides=way, segment_collides=seg_hit,
                     dense=dense, dense_collides=hit)


def path_free_at(robot: Robot, path: np.ndarray, resolution: float, clearance: float = 0.0) -> bool:
    """Whether every segment of ``path`` (S, K) is free when re-interpolated (SO(2)) so that no
    joint moves more than ``resolution`` between two checked poses: the planner's own guarantee
    (:func:`profrobot.plan_path`), independent of how far apart the waypoints are."""
    from ..planning import so2_steps

    path = np.asarray(path, dtype=np.float64)
    d = so2_steps(robot, path)
    counts = np.maximum(np.ceil(np.abs(d).max(axis=1) / resolution).astype(int), 1)
    poses = np.concatenate([interpolate(robot, a, b, int(n) + 1)[1:] for a, b, n in zip(path[:-1], path[1:], counts)])
    return bool(certify_poses(robot, poses, clearance).all())
