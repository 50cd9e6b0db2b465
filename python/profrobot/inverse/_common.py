"""What the inverse problems share: the labeller's robot and a path's certificate as a :class:`~profrobot.TrajectoryResult`."""

from __future__ import annotations

import time
from typing import Literal, overload

import numpy as np
import torch

from ..errors import InputError, RobotMismatchError
from ..kinematics.limits import Limits
from ..field.identity import Field, check_field, field_robot
from ..exact.certification import CLEARANCE, check_path
from ..robot.gate import with_margin
from ..optim.trajectory import TrajectoryResult, trajectory_result
from ..render.gaussians import GaussianRobot
from ..robot.robot import Robot


def check_field_matches_model(sdf: Field, model: GaussianRobot) -> None:
    """The field and the Gaussian robot must move the same joints: same count and limits
    (the field's scene may add obstacles the images do not show; the joints are the robot's)."""
    check_field(sdf)
    if sdf.njoint != model.njoint:
        raise RobotMismatchError(f"the field is for robot {getattr(sdf, 'robot_name', '?')!r} with {sdf.njoint} joints; "
                                 f"the Gaussian model {model.robot_name!r} has {model.njoint}")
    a = sdf.joint_limits.detach().double().cpu().numpy()
    b = model.joint_limits.detach().double().cpu().numpy()
    if a.shape != b.shape or not np.allclose(a, b, atol=1e-4):
        raise RobotMismatchError(f"the field's robot {getattr(sdf, 'robot_name', '?')!r} and the Gaussian model's "
                                 f"{model.robot_name!r} have different joint limits: not the same arm")


@overload
def labeller_robot(sdf, model, robot, who: str, *, required: Literal[True] = True, margin: float = CLEARANCE) -> Robot: ...
@overload
def labeller_robot(sdf, model, robot, who: str, *, required: bool, margin: float = CLEARANCE) -> Robot | None: ...
def labeller_robot(sdf, model, robot, who: str, *, required: bool = True, margin: float = CLEARANCE) -> Robot | None:
    """The scene the exact labeller certifies against: the field's (checked against ``model``'s
    joints and ``robot`` if given), else ``robot``, which ``who`` needs when ``required``; with
    a safety margin of ``margin`` metres around its obstacles (:mod:`profrobot.robot.margin`)."""
    if sdf is not None:
        check_field_matches_model(sdf, model)
        return with_margin(field_robot(sdf, robot), margin)
    if required and not isinstance(robot, Robot):
        raise InputError(f"{who} without a field needs robot= (the scene to certify against)")
    return robot if robot is None else with_margin(robot, margin)


def certified_path(robot: Robot, sdf, path: np.ndarray, density: int, method: str, iterations: int,
                   t0: float) -> TrajectoryResult:
    """``path`` (S, K) wrapped into the limits and put on the robot's joint couplings, certified
    continuously (:func:`~profrobot.exact.certification.check_path`: every waypoint, and every segment
    proven free at every pose; ``density`` is the sampled check's, unused by it), with the field
    along it (NaN without one)."""
    path = Limits.of(robot).numpy(path)
    g = (np.full(len(path), np.nan) if sdf is None else
         sdf(torch.as_tensor(path, dtype=torch.float32, device=sdf.joint_limits.device)).detach().cpu().numpy())
    return trajectory_result(robot, path, check_path(robot, path, density), g=g, method=method,
                             iterations=iterations, seconds=time.perf_counter() - t0)
