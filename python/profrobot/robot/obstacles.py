"""Obstacles for a robot's scene: geoms added to its ``mujoco.MjSpec`` (then recompiled), fixed to
the world or moving on scene joints (:class:`~profrobot.robot.family.Moves`). Positions in metres,
quaternions (w, x, y, z)."""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import mujoco
import numpy as np

from ..errors import InputError, InputTypeError
from .family import Moves, add_moving_geom

__all__ = ["Obstacle", "Box", "Sphere", "Capsule", "Cylinder", "Plane", "Mesh", "SpecEdit", "apply_edit"]


class SpecEdit(Protocol):
    """An edit a robot carries in its source and replays on its spec (an obstacle, a grasp, a margin)."""

    def add_to(self, spec: mujoco.MjSpec) -> None: ...


def apply_edit(spec: mujoco.MjSpec, edit: SpecEdit, what: str) -> None:
    """``edit.add_to(spec)`` (an obstacle, a grasp, any spec edit a robot carries in its source),
    MuJoCo's refusal (a ``ValueError``) raised as an :class:`InputError` naming ``what``."""
    try:
        edit.add_to(spec)
    except ValueError as e:
        if isinstance(e, InputError):
            raise
        raise InputError(f"{what}: MuJoCo refused it: {e}") from e

@dataclass(frozen=True)
class Obstacle(abc.ABC):
    """A geom of the scene. Positions in metres, quaternions (w, x, y, z).

    Fixed to the world, unless ``moves`` (:class:`~profrobot.robot.family.Moves`) says how it moves
    within a family of scenes: then it sits on scene joints named after it (``name`` required),
    see :mod:`profrobot.robot.family`."""

    pos: Sequence[float]
    quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)
    name: str | None = None
    rgba: Sequence[float] = (0.6, 0.6, 0.65, 1.0)
    moves: Moves | None = field(default=None, kw_only=True)

    @abc.abstractmethod
    def _geom_args(self, spec: mujoco.MjSpec | None) -> dict:
        """The geom's MuJoCo type and size (and any asset it needs, added to ``spec``)."""

    @property
    def label(self) -> str:
        """How messages name it: ``Box 'shelf'``, or ``Box at (0.4, 0, 0.2)`` when unnamed."""
        if self.name:
            return f"{type(self).__name__} {self.name!r}"
        try:
            where = ", ".join(f"{float(v):.3g}" for v in self.pos)
        except (TypeError, ValueError):
            where = repr(self.pos)
        return f"{type(self).__name__} at ({where})"

    def geom(self, spec: mujoco.MjSpec | None = None) -> dict:
        """The geom MuJoCo is given for this obstacle (``add_geom``'s keywords: ``pos``, unit
        ``quat``, ``rgba``, ``type``, ``size``, a mesh's name), validated: :class:`InputError`
        naming the obstacle and the entry. A :class:`Mesh` adds its mesh asset to ``spec``."""
        try:
            pos = np.asarray(self.pos, dtype=float)
            quat = np.asarray(self.quat, dtype=float)
        except (TypeError, ValueError) as e:
            raise InputError(f"{self.label}: pos must be 3 finite numbers and quat 4 ({e})") from e
        if pos.shape != (3,) or quat.shape != (4,) or not (np.isfinite(pos).all() and np.isfinite(quat).all()):
            raise InputError(f"{self.label}: pos must be 3 finite numbers and quat 4")
        if not np.linalg.norm(quat) > 0:
            raise InputError(f"{self.label}: quat is zero")
        if self.moves is not None and not isinstance(self.moves, Moves):
            raise InputTypeError(f"{self.label}: moves must be a profrobot.Moves; got {type(self.moves).__name__}")
        if self.moves is not None and isinstance(self, Plane):
            raise InputError(f"{self.label}: an infinite plane cannot move; use a thin Box")
        return dict(pos=pos, quat=quat / np.linalg.norm(quat), rgba=np.asarray(self.rgba, dtype=float),
                    **self._geom_args(spec))

    def add_to(self, spec: mujoco.MjSpec) -> None:
        kwargs = self.geom(spec)
        if self.moves is not None:
            pos = kwargs.pop("pos")
            add_moving_geom(spec, self.label, self.name, self.moves, pos, kwargs)
            return
        if self.name:
            kwargs["name"] = self.name
        spec.worldbody.add_geom(**kwargs)


def _positive(owner: str, **values: float) -> list[float]:
    out = []
    for key, v in values.items():
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise InputError(f"{owner}: {key} must be a positive length in metres; got {v!r}") from None
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{owner}: {key} must be a positive length in metres; got {v}")
        out.append(v)
    return out


@dataclass(frozen=True)
class Box(Obstacle):
    """A box of half extents ``half_size`` (metres)."""

    half_size: Sequence[float] = (0.1, 0.1, 0.1)

    def _geom_args(self, spec):
        h = np.asarray(self.half_size, dtype=object).reshape(-1)
        if len(h) != 3:
            raise InputError(f"{self.label}: half_size must be 3 lengths (x, y, z) in metres; got {self.half_size!r}")
        hx, hy, hz = _positive(f"{self.label}", **{"half_size x": h[0], "half_size y": h[1], "half_size z": h[2]})
        return dict(type=mujoco.mjtGeom.mjGEOM_BOX, size=[hx, hy, hz])


@dataclass(frozen=True)
class Sphere(Obstacle):
    """A ball of ``radius`` metres centred at ``pos``."""

    radius: float = 0.1

    def _geom_args(self, spec):
        (r,) = _positive(self.label, radius=self.radius)
        return dict(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[r, 0, 0])


@dataclass(frozen=True)
class Capsule(Obstacle):
    """A capsule along its local z axis: ``radius`` and ``half_length`` of the segment."""

    radius: float = 0.05
    half_length: float = 0.1

    def _geom_args(self, spec):
        r, h = _positive(self.label, radius=self.radius, half_length=self.half_length)
        return dict(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[r, h, 0])


@dataclass(frozen=True)
class Cylinder(Obstacle):
    """A cylinder along its local z axis."""

    radius: float = 0.05
    half_length: float = 0.1

    def _geom_args(self, spec):
        r, h = _positive(self.label, radius=self.radius, half_length=self.half_length)
        return dict(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[r, h, 0])


@dataclass(frozen=True)
class Plane(Obstacle):
    """An infinite plane (the half-space below local z = 0 is solid), e.g. a floor."""

    def _geom_args(self, spec):
        return dict(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])


@dataclass(frozen=True)
class Mesh(Obstacle):
    """A mesh obstacle from ``vertices`` (N, 3) in metres; it collides as its convex hull."""

    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def _geom_args(self, spec):
        v = np.asarray(self.vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or not np.isfinite(v).all():
            raise InputError(f"{self.label}: vertices must be a finite (N >= 4, 3) array; got shape {v.shape}")
        if spec is None:
            raise InputError(f"{self.label}: a mesh obstacle needs the spec its mesh is added to")
        mesh_name = f"{self.name or 'obstacle'}_mesh_{len(spec.meshes)}"
        spec.add_mesh(name=mesh_name, uservert=v.ravel())
        return dict(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh_name)
