"""The Δθ oracle: for each colliding pose, the smallest joint-space move to a free pose that
the exact labeller can find (rays, marching and bisection, in Rust: ``rust/planning/oracle.rs``).

The yardstick for collision resolution: ``resolve(...).delta / nearest_free(...).distance``
says how much farther than necessary the optimiser moved each pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .certification import CLEARANCE, certify_poses
from ..errors import InputError
from ..robot import gate
from ..robot.gate import Layout, as_poses
from ..robot.robot import Robot


@dataclass
class NearestFree:
    """The nearest free pose found for each of B poses.

    Attributes:
        distance: (B,) float64, L2 length (radians / metres) of the move to ``poses``: 0 for a
            pose that is already free, inf where no free pose was found within ``max_distance``.
            An upper bound on the true nearest distance, tight to about ``tolerance`` along the
            best ray found.
        poses: (B, K) float64, the free poses (exactly free per :func:`label_poses`), within the
            joint limits; continuous joints are not wrapped. NaN rows where none was found.
        checks: (B,) int64, poses labelled for each search.
        certified: (B,) bool, the returned pose is certified free (:mod:`profrobot.exact.certification`:
            the search stops on the labeller's boundary, so a pose it finds may still be within
            the certification's clearance of contact); False where none was found.
    """

    distance: np.ndarray
    poses: np.ndarray
    checks: np.ndarray
    certified: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.distance)


def nearest_free(robot: Robot, poses: npt.ArrayLike, *, layout: Layout | None = None, margin: float = CLEARANCE,
                 directions: int = 256, refine: int = 1024, step: float = 0.02, tolerance: float = 1e-4,
                 max_distance: float | None = None, seed: int = 0, threads: int | None = None) -> NearestFree:
    """The nearest free pose the exact labeller finds for each of ``poses`` (B, K).

    From each colliding pose ``q``: ``directions`` seeded random unit directions ``u`` in joint
    space; each ray ``q + t u`` is marched in steps of ``step`` up to the best distance so far
    (or the joint limits), and its first free state bisected to ``tolerance``; then ``refine``
    perturbations of the best direction are probed at the best distance and bisected when
    free. Poses must lie within the joint limits (to 1e-9); the returned poses do too.

    Deterministic: the same ``seed`` gives the same answer for any thread count. Cost: about
    ``directions * distance / step + refine`` labelled poses per colliding pose.

    ``margin``: the answer keeps this many metres from every obstacle; a family searches its θ at
    ``layout`` (:mod:`profrobot.robot.gate`).
    """
    robot = gate.robot_at(robot, layout=layout, margin=margin)
    q = as_poses(robot, poses, check_limits=True)
    lim, limited = robot.joint_limits, ~robot.continuous
    q = np.where(limited, np.clip(q, lim[:, 0], lim[:, 1]), q)  # within the 1e-9 tolerance
    seed = gate.seed(seed)
    step, tolerance = gate.positive("step", step), gate.positive("tolerance", tolerance)
    if tolerance > step:
        raise InputError(f"tolerance ({tolerance}) must not exceed step ({step})")
    out = robot.core.nearest_free(
        np.ascontiguousarray(q), directions=gate.count("directions", directions), step=step, tolerance=tolerance,
        refine=gate.count("refine", refine, 0), max_distance=None if max_distance is None else gate.positive("max_distance", max_distance),
        seed=int(seed), threads=gate.threads(threads))
    found = np.isfinite(out["distance"])
    certified = np.zeros(len(q), dtype=bool)
    if found.any():
        certified[found] = certify_poses(robot, out["poses"][found])
    return NearestFree(**out, certified=certified)
