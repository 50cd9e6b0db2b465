"""Collision-aware optimisation with the learned field (paper §4.2 and the supplement):
the penalty, batched collision resolution and trajectories, all certified by the exact labeller."""

from ..exact.certification import PathCheck, certify_poses, check_path
from .penalty import collision_penalty
from .resolve import ResolveResult, certify_and_continue, resolve
from .adam import BatchedAdam
from .paths import PenaltyOptions, TangentOptions, penalty_descent, smooth_certified, tangent_walk, unwrap_path
from .trajectory import TrajectoryResult, plan_trajectories, plan_trajectory, trajectory_result

__all__ = ["collision_penalty", "resolve", "ResolveResult", "plan_trajectory", "plan_trajectories", "TrajectoryResult",
           "certify_poses", "check_path", "PathCheck", "PenaltyOptions", "TangentOptions", "penalty_descent",
           "smooth_certified", "tangent_walk", "unwrap_path", "trajectory_result", "BatchedAdam", "certify_and_continue"]
