"""A family field at one layout: g(θ, δ) with δ fixed, as a field over the robot joints θ alone.

``PoseSDF.at(layout)`` builds one; every torch-side entry point that takes ``layout=`` (``resolve``,
``plan_trajectory``, ``pose_from_images``, ``trajectory_from_images``, ``actions_from_video``)
works on it unchanged: its ``robot`` is the family's scene pinned at δ (``Robot.at``), an ordinary
static scene, so every answer is certified by the exact labeller at exactly that layout.
"""

from __future__ import annotations

import os
from typing import Any, NoReturn, Protocol, cast, overload

import numpy as np
import numpy.typing as npt
import torch
from torch import nn

from ..errors import InputError, InputTypeError, RobotMismatchError
from ..robot.gate import Layout
from ..robot.gate import robot_at
from ..robot.robot import Robot
from .identity import Field, _Shared

__all__ = ["LayoutField", "field_at_layout"]


class _FamilyField(Protocol):
    """What a LayoutField uses of its family :class:`~profrobot.PoseSDF` (model.py imports this
    module, so it names no class of model.py)."""

    robot_name: str
    metrics: dict
    joint_limits: torch.Tensor
    robot_index: torch.Tensor | None

    @property
    def robot(self) -> Any: ...

    @property
    def scale(self) -> torch.Tensor: ...

    def scatter(self, theta: torch.Tensor, deltas: npt.ArrayLike) -> torch.Tensor: ...

    def __call__(self, theta: torch.Tensor) -> torch.Tensor: ...


class _Family(Protocol):
    """What :func:`field_at_layout` uses of a family field (a :class:`~profrobot.PoseSDF` with scene
    joints; model.py imports this module)."""

    robot_name: str
    fingerprint: str
    scene_joints: list[str]

    def at(self, layout: Layout) -> "LayoutField": ...


class LayoutField(nn.Module):
    """``g(θ) = field(θ, δ)`` for a fixed layout δ: the PoseSDF interface (``njoint``,
    ``joint_names``, ``joint_limits``, ``fingerprint``, ``robot``, ``prob``) over the robot joints.

    Attributes: ``field`` (the family :class:`PoseSDF`), ``layout`` (D,) float64 δ, ``robot`` (the
    static Robot at δ). Gradients flow to θ only. Pickles with the family field and layout."""

    joint_limits: torch.Tensor   # a buffer (register_buffer)

    def __init__(self, field: _FamilyField, layout: Layout):  # field: a family PoseSDF
        super().__init__()
        if not isinstance(field, nn.Module) or not getattr(field, "scene_joints", None):
            raise InputError("LayoutField needs a family field (a PoseSDF trained on a Robot with scene joints)")
        family = field.robot
        delta = family.check_layout(layout)
        robot = family.at(delta)
        self.field = field
        self.layout = delta
        self._robot = _Shared(robot)
        self.robot_name = field.robot_name
        self.fingerprint = robot.fingerprint
        self.joint_names = list(robot.joint_names)
        self.njoint = robot.njoint
        self.scene_joints: list[str] = []
        self.metrics = field.metrics
        self.register_buffer("joint_limits", field.joint_limits[field.robot_index].clone())

    @property
    def robot(self) -> Robot:
        """The family's scene at this layout (static obstacles): the labeller's robot."""
        return self._robot.value

    @property
    def scale(self) -> torch.Tensor:
        return self.field.scale

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        """g (B,) at robot poses θ (B, K − D) and this layout."""
        if not isinstance(theta, torch.Tensor):
            raise InputTypeError(f"theta must be a torch.Tensor; got {type(theta).__name__}")
        if theta.ndim != 2 or theta.shape[1] != self.njoint:
            raise InputError(f"theta must have shape (B, {self.njoint}) (the robot joints of {self.robot_name!r} at "
                             f"this layout); got {tuple(theta.shape)}")
        return self.field(self.field.scatter(theta, self.layout[None]))

    def prob(self, theta: torch.Tensor) -> torch.Tensor:
        """Collision probability sigmoid(s·g(θ)), (B,)."""
        return torch.sigmoid(self.scale * self(theta))

    def save(self, path: str | os.PathLike[str]) -> NoReturn:
        raise InputError("a LayoutField is a family field at one layout: save the family field (layout_field.field.save)")

    def __repr__(self) -> str:
        return f"LayoutField({self.field!r}, layout={np.array2string(self.layout, precision=3)})"


@overload
def field_at_layout(sdf: Field, robot: Robot | None, layout: Layout | None) -> tuple[Field, Robot | None]: ...
@overload
def field_at_layout(sdf: None, robot: Robot | None, layout: Layout | None) -> tuple[None, Robot | None]: ...
@overload
def field_at_layout(sdf: Field | None, robot: Robot | None,
                    layout: Layout | None) -> tuple[Field | None, Robot | None]: ...
def field_at_layout(sdf: Field | None, robot: Robot | None, layout: Layout | None) -> tuple[Field | None, Robot | None]:
    """The (field, robot) pair an entry point works with at a layout: ``sdf.at(layout)`` and its
    static robot for a family field; a family field without ``layout`` takes the layout of
    ``robot`` (a Robot made by ``family.at(δ)``); an ordinary field refuses ``layout``.
    ``sdf=None``: the robot as the gate gives it (:func:`profrobot.robot.gate.robot_at`: a family
    pinned at ``layout``, one refused without one)."""
    family = sdf is not None and bool(getattr(sdf, "scene_joints", None))
    if sdf is None:
        if robot is None:
            if layout is not None:
                raise InputError("layout= without a field needs robot= (the family of scenes)")
            return None, None
        return None, robot_at(robot, layout=layout)
    if not family:
        if layout is not None:
            raise InputError(f"layout= was given but the field for {getattr(sdf, 'robot_name', '?')!r} is not a family "
                             "field (trained on a Robot without scene joints)")
        return sdf, robot
    fam = cast(_Family, sdf)   # a family field: a PoseSDF with scene joints
    if layout is None:
        pinned = getattr(robot, "layout", None)
        if robot is None or pinned is None:
            raise InputError(f"the field for {fam.robot_name!r} covers a family of scenes (scene joints "
                             f"{', '.join(fam.scene_joints)}): pass layout=δ, the layout to work at, or "
                             "robot=family.at(δ)")
        if getattr(robot, "family_fingerprint", None) != sdf.fingerprint:
            raise RobotMismatchError(f"robot {robot.name!r} is a layout of another family than the field's")
        layout = pinned
    at = fam.at(layout)
    if robot is not None and getattr(robot, "geometry_fingerprint", robot.fingerprint) == sdf.fingerprint:
        # robot=family, layout=δ (a family with a safety margin keeps it at the layout)
        return at, robot.at(at.layout) if getattr(robot, "margin", 0.0) > 0 else at.robot
    if robot is not None and getattr(robot, "geometry_fingerprint", robot.fingerprint) != at.fingerprint:
        raise RobotMismatchError(f"robot {robot.name!r} is not the field's family at this layout; pass the family's "
                                 "robot.at(scene), or leave robot= out")
    return at, at.robot if robot is None else robot
