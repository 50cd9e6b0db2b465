"""The differentiable side's base (torch): forward kinematics over the Rust core's body tree
(:mod:`.fk`) and the joint limits the optimisers keep (:mod:`.limits`)."""

from __future__ import annotations

from .fk import BodyPoses, Kinematics, axis_angle_matrix, quat_to_matrix
from .limits import Limits

__all__ = ["Kinematics", "BodyPoses", "quat_to_matrix", "axis_angle_matrix", "Limits"]
