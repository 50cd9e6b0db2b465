"""The ways to build a :class:`~profrobot.Robot` (``Robot.from_*`` call these with the class): from the Menagerie, an MJCF or
URDF file (with a MoveIt SRDF or an automatic collision matrix), an ``MjSpec`` or a compiled
``MjModel``; and the collision report that says which pairs were disabled and why.

The file-based constructors (Menagerie, MJCF, URDF) record the robot's source
(:mod:`profrobot.robot.sources`: the files' bytes), so that a pickle rebuilds its editable spec exactly;
``from_spec`` keeps the spec itself (its pickle carries the compiled model too) and
``from_model`` none (obstacles cannot be added to it). Base layer: no torch.
"""

from __future__ import annotations

import os
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np

from . import urdf
from ..errors import InputError, MissingFileError
from .arrays import FREE, object_name
from .sources import _SpecSource, _Urdf



def root_tag(path: str) -> str | None:
    """The root element's tag of an XML file (None if it cannot be read)."""
    try:
        for _, el in ET.iterparse(path, events=("start",)):
            return el.tag
    except (ET.ParseError, OSError):
        return None
    return None


@dataclass(frozen=True)
class ExcludedPairs:
    """A spec edit: MuJoCo ``<exclude>``s between body pairs (names), from ``srdf=`` or
    ``collision_matrix="auto"`` (pickles replay it with the spec)."""

    pairs: tuple

    def add_to(self, spec: mujoco.MjSpec) -> None:
        for a, b in self.pairs:
            spec.add_exclude(bodyname1=a, bodyname2=b)




def from_menagerie(cls, name: str, entry: str | None = None) -> Any:
    """:meth:`Robot.from_menagerie` (see there)."""
    import mujoco_menagerie as mm

    try:
        path = str(mm.get(name).xml(entry))
    except mm.UnknownRobotError as e:
        raise InputError(f"unknown Menagerie robot {name!r}; known: {', '.join(mm.names())}") from e
    except mm.UnknownEntryPointError as e:
        raise InputError(str(e)) from e
    robot = cls.from_spec(mujoco.MjSpec.from_file(path), name=name if entry is None else f"{name}/{entry}")
    robot._source = _SpecSource(path)  # a pickle carries the files themselves (exact)
    return robot


def from_mjcf(cls, path: str | os.PathLike, *, srdf: str | os.PathLike | None = None,
              collision_matrix: str | None = None) -> Any:
    """:meth:`Robot.from_mjcf` (see there)."""
    path = os.fspath(path)
    if collision_matrix not in (None, "auto"):
        raise InputError(f"collision_matrix must be None or 'auto'; got {collision_matrix!r}")
    if not os.path.isfile(path):
        raise MissingFileError(f"no MJCF file at {path!r}")
    if path.lower().endswith(".urdf") or root_tag(path) == "robot":
        return cls.from_urdf(path, srdf=srdf, collision_matrix=collision_matrix)
    try:
        spec = mujoco.MjSpec.from_file(path)
    except Exception as e:  # mujoco raises ValueError with the parser's message
        raise InputError(f"could not read MJCF {path!r}: {e}") from e
    try:
        robot = cls.from_spec(spec, name=os.path.splitext(os.path.basename(path))[0])
    except InputError as e:
        missing = re.search(r"Error opening file '([^']+)'", str(e))
        if missing is None:
            raise
        raise MissingFileError(_where_looked(spec, path, missing.group(1))) from e
    robot._source = _SpecSource(os.path.abspath(path))  # a pickle carries the files themselves (exact)
    return _with_collision_matrix(robot, path, srdf, collision_matrix)


def _where_looked(spec: mujoco.MjSpec, path: str, name: str) -> str:
    """A file an MJCF names that MuJoCo could not open, with where it looked. MuJoCo's message
    names the file as it tried it, ``<compiler meshdir=…>`` (or ``texturedir``) already joined,
    relative to the MJCF's folder."""
    where = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(path)), name))
    dirs = ", ".join(f"{attr}={getattr(spec, attr, '') or ''!r}" for attr in ("meshdir", "texturedir"))
    return (f"{path}: MuJoCo could not open {name!r}, which the MJCF names; it looked at {where} (the MJCF's "
            f"folder, {dirs}). Fix the file name, <compiler meshdir=...> or copy the assets there")


def _with_collision_matrix(self, source: str, srdf, collision_matrix: str | None) -> Any:
    """This (MJCF) robot with ``srdf=`` / ``collision_matrix="auto"`` applied as ``<exclude>``
    edits, and the always-colliding pairs that remain warned about."""
    disabled = urdf.srdf_pairs(srdf, self.body_names, self.name, source) if srdf is not None else []
    robot = _derived_excluding(self, disabled) if disabled else self
    rates, n = urdf.body_pair_rates(robot)
    bn = robot.body_names
    before = None
    if collision_matrix == "auto":
        auto = urdf.auto_pairs(robot.mj_model, rates, n, bn)
        if auto:
            before = robot
            robot = _derived_excluding(self, disabled + auto)
            disabled += auto
    left = {k: r for k, r in rates.items() if r >= urdf.ALWAYS and (collision_matrix != "auto" or k[0] == 0)}
    if left:
        listed = ", ".join(f"{bn[a]}–{bn[b]} ({urdf.pct(r)})" for (a, b), r in sorted(left.items()))
        warnings.warn(f"{self.name} ({source}): {len(left)} body pair(s) collide in (nearly) every pose (>= "
                      f"{urdf.pct(urdf.ALWAYS)} of {n} uniform poses): {listed}, so nearly every pose labels as "
                      "colliding. Pass collision_matrix='auto' (or srdf=, MoveIt <disable_collisions>) to "
                      "Robot.from_mjcf to disable such pairs; robot.collision_report() has the details.",
                      urdf.CollisionWarning, stacklevel=4)   # < _with_collision_matrix < from_mjcf < Robot.from_mjcf < the caller
    if disabled or left:
        robot.disabled_pairs = tuple(disabled)
        lines = [f"{robot.name}: from MJCF {source}"]
        if disabled:
            lines.append("  collisions not checked (MuJoCo <exclude>):")
            lines += [f"    {p.body1} – {p.body2}: {p.reason}" for p in disabled]
        if left:
            lines.append(f"  checked, colliding in >= {urdf.pct(urdf.ALWAYS)} of {n} uniform poses "
                         "(collision_matrix='auto' would disable them):")
            lines += [f"    {bn[a]} – {bn[b]}: {urdf.pct(r)}" for (a, b), r in sorted(left.items())]
        lines.append(_collision_rate_line(robot, n, before))
        robot._collision_notes = "\n".join(lines)
    return robot


def _derived_excluding(self, pairs) -> Any:
    """This robot with MuJoCo ``<exclude>``s between the body pairs ``pairs`` (DisabledPairs)."""
    edit = ExcludedPairs(tuple((p.body1, p.body2) for p in pairs))
    spec = self._editable("a collision matrix")
    edit.add_to(spec)
    return self._derived(spec, (edit,), self.name)


def from_urdf(cls, path: str | os.PathLike, *, package_dirs=None, srdf: str | os.PathLike | None = None,
              collision_matrix: str | None = None, name: str | None = None) -> Any:
    """:meth:`Robot.from_urdf` (see there)."""
    if collision_matrix not in (None, "auto"):
        raise InputError(f"collision_matrix must be None or 'auto'; got {collision_matrix!r}")
    files = urdf.read_urdf(path, package_dirs)
    name = name or files.name
    for note in files.notes:
        warnings.warn(f"{name} ({files.path}): {note}", urdf.UrdfWarning, stacklevel=3)
    root = _Urdf(files.xml, {}, dict(files.assets), files.folder, True, mimics=files.mimics)
    robot = _from_urdf_root(cls, root, files, name)
    disabled: list[urdf.DisabledPair] = []
    if srdf is not None:
        disabled = urdf.srdf_pairs(srdf, robot.body_names, name, files.path)
        if disabled:
            robot = _from_urdf_root(cls, replace(root, excludes=tuple(p[:2] for p in disabled)), files, name)
    rates, n = urdf.body_pair_rates(robot)
    m, bn = robot.mj_model, robot.body_names
    always = {k: r for k, r in rates.items() if r >= urdf.ALWAYS}
    before = None
    if collision_matrix == "auto":
        auto = urdf.auto_pairs(m, rates, n, bn)
        if auto:
            before = robot
            disabled += auto
            robot = _from_urdf_root(cls, replace(root, excludes=tuple(p[:2] for p in disabled)), files, name)
    left = {k: r for k, r in always.items() if collision_matrix != "auto" or k[0] == 0}
    if left:
        listed = ", ".join(f"{bn[a]}–{bn[b]} ({urdf.pct(r)})" for (a, b), r in sorted(left.items()))
        world = (" Pairs with 'world' are links fused into it (the URDF's <mujoco><compiler fusestatic=\"true\"/>): "
                 "disable them with srdf= naming the link, never the world." if any(a == 0 for a, _ in left) else "")
        warnings.warn(f"{name} ({files.path}): {len(left)} link pair(s) collide in (nearly) every pose (>= "
                      f"{urdf.pct(urdf.ALWAYS)} of {n} uniform poses): {listed}. These are MuJoCo's labels for this "
                      "URDF (a link welded to the world is not filtered against its child); pass srdf= (MoveIt "
                      "<disable_collisions>) or collision_matrix='auto' to disable such pairs; "
                      f"robot.collision_report() has the details.{world}", urdf.UrdfWarning, stacklevel=3)
    robot.disabled_pairs = tuple(disabled)
    robot._collision_notes = _urdf_report(robot, files, rates, n, left, before)
    return robot


def _from_urdf_root(cls, root: "_Urdf", files: "urdf.UrdfFiles", name: str) -> Any:
    try:
        spec = root.spec()
        model = spec.compile()
    except Exception as e:
        raise InputError(f"{files.path}: MuJoCo could not compile the URDF: "
                         f"{urdf.explain_compile_error(files, e)}") from e
    free = [object_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint") for j in range(model.njnt) if model.jnt_type[j] == FREE]
    if free:
        raise InputError(f"{files.path}: the compiled model has a free joint ({', '.join(map(repr, free))}): a "
                         "floating base, which profrobot cannot label; fix the base link to the world")
    robot = cls(model, name=name, spec=spec)
    robot._source = _SpecSource(root)   # the URDF text and mesh bytes: pickles rebuild it exactly
    return robot


def _urdf_report(self, files: "urdf.UrdfFiles", rates: dict, n: int, always: dict, before: Any) -> str:
    bn = self.body_names
    lines = [f"{self.name}: from URDF {files.path} ({len(files.assets)} mesh file{'' if len(files.assets) == 1 else 's'}; links kept as bodies)"]
    cont = [j for j, c in zip(self.joint_names, self.continuous) if c]
    lines.append(f"  {self.njoint} joints; continuous: {', '.join(cont) or 'none'}")
    if files.inertias:
        lines.append("  inertias MuJoCo's compiler refuses, changed (labels do not depend on inertia):")
        lines += [f"    {line}" for line in files.inertias]
    for joint, other, mult, offset in files.mimics:
        lines.append(f"  mimic: {joint} = {mult:g}·{other} {'-' if offset < 0 else '+'} {abs(offset):g} (a MuJoCo "
                     "joint equality)")
    if self.disabled_pairs:
        lines.append("  collisions not checked (MuJoCo <exclude>):")
        lines += [f"    {p.body1} – {p.body2}: {p.reason}" for p in self.disabled_pairs]
    else:
        lines.append("  collisions not checked: none beyond MuJoCo's own filters")
    if always:
        lines.append(f"  checked, colliding in >= {urdf.pct(urdf.ALWAYS)} of {n} uniform poses (srdf= or "
                     "collision_matrix='auto' would disable them):")
        lines += [f"    {bn[a]} – {bn[b]}: {urdf.pct(r)}" for (a, b), r in sorted(always.items())]
    never = sum(1 for r in rates.values() if r == 0)
    lines.append(f"  {never} checked link pairs never touched in the {n} poses (kept: a sample does not prove never)")
    lines.append(_collision_rate_line(self, n, before))
    return "\n".join(lines)


def _collision_rate_line(self, n: int, before: Any) -> str:
    """The collision reports' last line: how often ``n`` seeded uniform poses collide, and
    how often they did ``before`` the collision matrix."""
    poses = self.core.sample(n, urdf.SEED, threads=None)
    self.couplings.apply(poses)
    rate = float(np.mean(self.core.collides(poses, threads=None)))
    was = "" if before is None else f" ({urdf.pct(float(np.mean(before.core.collides(poses, threads=None))))} before the matrix)"
    return f"  collides in {urdf.pct(rate)} of those {n} uniform poses{was}"


def collision_report(self) -> str:
    """:meth:`Robot.collision_report` (see there)."""
    if self._collision_notes:
        return self._collision_notes
    n = len(self._arrays["exclude"])
    return f"{self.name}: no collision pairs disabled by profrobot (MuJoCo's filters and the model's {n} <exclude>s apply)"


def from_spec(cls, spec: mujoco.MjSpec, *, name: str = "robot") -> Any:
    """:meth:`Robot.from_spec` (see there)."""
    try:
        model = spec.compile()
    except Exception as e:
        raise InputError(f"could not compile {name!r}: {e}") from e
    return cls(model, name=name, spec=spec)


def from_model(cls, model: mujoco.MjModel, *, name: str = "robot") -> Any:
    """:meth:`Robot.from_model` (see there)."""
    return cls(model, name=name)
