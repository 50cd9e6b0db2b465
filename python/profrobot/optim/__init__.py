"""Collision-aware optimisation with the learned field (paper §4.2 and the supplement):
the penalty, batched collision resolution and trajectories, all certified by the exact labeller."""

from ..exact.certification import PathCheck, certify_poses, check_path
from .penalty import collision_penalty
from .resolution import ResolveResult, resolve
from .adam import BatchedAdam
from .paths import PenaltyOptions, TangentOptions, unwrap_path
from .trajectory import TrajectoryResult, plan_trajectories, plan_trajectory

# The steps these are made of (optim.paths' penalty_descent, tangent_walk, smooth_certified;
# trajectory_result; resolve's certify_and_continue) are the layer's own: the inverse layer imports
# them from their modules, and users call the entry points, which pass every robot through the gate.
__all__ = ["collision_penalty", "resolve", "ResolveResult", "plan_trajectory", "plan_trajectories", "TrajectoryResult",
           "certify_poses", "check_path", "PathCheck", "PenaltyOptions", "TangentOptions", "unwrap_path",
           "BatchedAdam"]
