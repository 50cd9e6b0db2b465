"""The native core (Rust, pyo3). Everything here releases the GIL while it works.

Shapes: B poses, K joints (MuJoCo joint order; radians for hinges, metres for slides), nbody
bodies (the world included), P candidate geom pairs. Arrays are read in any memory layout
(C or Fortran order, negative strides, sliced views): rows are read through the strides, never
reinterpreted. Invalid input raises :class:`ProfrobotError` (a ValueError), a bad robot model
:class:`ModelError`, a wrong dtype or object TypeError naming the dtype wanted; never a panic.
"""

from typing import final

import numpy as np
import numpy.typing as npt

__version__: str

class ProfrobotError(ValueError):
    """Base of every error profrobot raises on purpose (a ValueError)."""

@final
class ModelError(ProfrobotError):
    """A robot model the core cannot label exactly (inconsistent arrays, unsupported geoms or joints)."""

class RobotModel:
    """A robot scene's collision model, built once from flat MuJoCo arrays
    (``profrobot.Robot`` builds it; see ``Robot.core_arrays()`` for the keys)."""

    def __init__(self, arrays: dict[str, npt.NDArray | bool]) -> None: ...
    @property
    def njoint(self) -> int: ...
    @property
    def nbody(self) -> int: ...
    @property
    def ngeom(self) -> int:
        """Number of collidable geoms."""
    @property
    def npair(self) -> int:
        """Number of candidate geom pairs after MuJoCo's filters."""
    def pairs(self) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
        """(P, 2) MuJoCo geom ids, (P,) is-self-collision flag, (P,) contact margin (m)."""
    def sampling_ranges(self) -> npt.NDArray[np.float64]:
        """(K, 2) joint ranges; continuous hinges report [-pi, pi]."""
    def continuous(self) -> npt.NDArray[np.bool_]:
        """(K,) whether each joint is an unlimited hinge."""
    def forward_kinematics(self, poses: npt.NDArray[np.float64], threads: int | None = None
                           ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Body poses for (B, K) poses: xpos (B, nbody, 3) metres and xquat (B, nbody, 4) (w, x, y, z),
        as MuJoCo's ``mj_kinematics`` computes them."""
    def label(self, poses: npt.NDArray[np.float64], *, pairs: bool = False, distance: bool = False,
              threads: int | None = None) -> dict[str, npt.NDArray]:
        """Labels (B, K) float64 poses. Keys: collides, self_collides, scene_collides
        (B,) bool; n_pairs (B,) int32; with ``distance``, min_distance (B,) float64 metres
        (negative: penetration); with ``pairs``, colliding_pairs (M, 2) int64 (pose, pair index)."""
    def sample(self, n: int, seed: int, threads: int | None = None) -> npt.NDArray[np.float64]:
        """(n, K) uniform poses within the sampling ranges; identical for any thread count."""

def interpolate(start: npt.NDArray[np.float64], goal: npt.NDArray[np.float64], steps: int,
                continuous: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
    """(B, steps, K) poses from (B, K) start to goal, both ends included: shortest arc where
    ``continuous`` (K,), straight otherwise."""
