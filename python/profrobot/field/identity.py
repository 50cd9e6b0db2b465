"""Which robot a field belongs to: the scene the exact labeller certifies its answers against.

Every torch-side entry point that takes a field (``resolve``, ``plan_trajectory``, the inverse
problems) resolves its labeller's robot here, so a field for another arm is refused the same way
everywhere (:class:`~profrobot.errors.RobotMismatchError`).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Protocol

import torch

from ..errors import InputError, InputTypeError
from ..files import check_robot
from ..robot.robot import Robot

__all__ = ["Field", "check_field", "field_robot"]


class Field(Protocol):
    """A collision field as the torch side takes it (``sdf=``): g(θ) (B,) at poses θ (B, K), g < 0
    free. :class:`~profrobot.PoseSDF` and :class:`~profrobot.field.layout.LayoutField` (a family
    field at one layout) follow it, as does any module with their interface (:func:`check_field`)."""

    @property
    def njoint(self) -> int: ...

    @property
    def joint_limits(self) -> torch.Tensor: ...

    @property
    def fingerprint(self) -> str: ...

    def __call__(self, theta: torch.Tensor) -> torch.Tensor: ...


class _Shared:
    """Holds the field's Robot: copies of the module (deepcopy, snapshots) share it, since a
    Robot is immutable, instead of copying MuJoCo models and the Rust collision model. A pickle
    (``pickle``, ``torch.save``, DataLoader workers) carries the Robot itself (see
    ``Robot.__getstate__``): the unpickled field labels, certifies and adds obstacles like this
    one."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value

    def __deepcopy__(self, memo):
        return self

    def __reduce__(self):  # any protocol (the default slots pickling needs protocol 2)
        return (_Shared, (self.value,))


def check_field(sdf: Field) -> None:
    """``sdf`` must be a torch module with the PoseSDF interface (njoint, joint_limits, fingerprint)."""
    if not isinstance(sdf, torch.nn.Module) or not all(hasattr(sdf, a) for a in ("njoint", "joint_limits", "fingerprint")):
        raise InputTypeError(f"expected a profrobot.PoseSDF (or a module with its interface); got {type(sdf).__name__}")


@lru_cache(maxsize=8)
def _bundled(name: str) -> Robot:
    from ..scenes import load

    return load(name)


def field_robot(sdf: Field, robot: Robot | None) -> Robot:
    """The robot the exact labeller certifies against: ``robot`` if given (it must be the one the
    field was trained for), else the field's own robot (``sdf.robot``, set by ``train_sdf`` and
    ``PoseSDF.load``), else the bundled scene named by ``sdf.robot_name``."""
    check_field(sdf)
    if robot is None:
        robot = getattr(sdf, "robot", None)
    if robot is None:
        from ..scenes import family_names, names

        name = getattr(sdf, "robot_name", None)
        if name not in names() + family_names():
            raise InputError(f"the field's robot {name!r} is not a bundled scene; pass robot= so that "
                             "results can be certified by the exact labeller")
        robot = _bundled(name)
    if not isinstance(robot, Robot):
        raise InputTypeError(f"robot must be a profrobot.Robot; got {type(robot).__name__}")
    check_robot(sdf.fingerprint, robot, "the field", made_for=getattr(sdf, "robot_name", None), geometry=True)
    return robot
