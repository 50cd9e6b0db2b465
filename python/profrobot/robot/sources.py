"""A robot's editable ``mujoco.MjSpec`` in a form that pickles (``MjSpec`` itself does not): where
the model came from (an MJCF file, a URDF, a spec) as bytes, and the edits made since, replayed
in order (:class:`SpecSource`)."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass

import mujoco


def _zip(files: dict[str, bytes]) -> dict[str, bytes]:
    return {k: zlib.compress(v, 1) for k, v in files.items()}


def _unzip(files: dict[str, bytes]) -> dict[str, bytes]:
    return {k: zlib.decompress(v) for k, v in files.items()}


@dataclass(frozen=True, eq=False)
class _Mjcf:
    """An MJCF model as bytes: the main file's text, the files it includes and every asset file
    its meshes, textures, height fields and skins read, keyed by the name MuJoCo looks them up
    by (the compiler folder joined with the ``file`` attribute), and the folder it was read from
    (``modelfiledir``: names in MuJoCo's compiled ``paths`` stay the same; the carried assets
    take precedence over any file there). Held as read; zlib-compressed in a pickle (once per
    object: compressing a Panda's meshes takes ~0.2 s, which a scene update on a robot just
    loaded, reading its sources, should not pay).

    ``exact``: the very files the model was parsed from (``from_mjcf``, ``from_menagerie``), so
    they compile to the same ``MjModel``, bit for bit. False for a spec given to ``from_spec``:
    written out with ``MjSpec.to_xml`` (6 significant digits), it may compile to another robot,
    which :meth:`Robot._restore` detects.
    """

    xml: str
    include: dict
    assets: dict
    modelfiledir: str
    exact: bool

    def spec(self) -> mujoco.MjSpec:
        spec = mujoco.MjSpec.from_string(self.xml, include=self.include or None, assets=self.assets or None)
        spec.modelfiledir = self.modelfiledir
        return spec

    def __getstate__(self) -> dict:
        zipped = self.__dict__.get("_zipped")
        if zipped is None:
            zipped = (_zip(self.include), _zip(self.assets))
            object.__setattr__(self, "_zipped", zipped)
        state = {k: v for k, v in self.__dict__.items() if k != "_zipped"}
        state["include"], state["assets"] = zipped
        return state

    def __setstate__(self, state: dict) -> None:
        for k, v in state.items():
            object.__setattr__(self, k, _unzip(v) if k in ("include", "assets") else v)


def _asset_files(spec: mujoco.MjSpec) -> list[tuple[str, str]]:
    """(name MuJoCo looks up, path on disk) of every file the spec's assets read: meshes, height
    fields and skins in ``meshdir``, textures (and cube faces) in ``texturedir``."""
    out = []

    def add(name: str, folder: str) -> None:
        if name:
            key = name if os.path.isabs(name) or not folder else os.path.join(folder, name)
            out.append((key, key if os.path.isabs(key) else os.path.join(spec.modelfiledir or "", key)))

    for m in spec.meshes:
        add(m.file, spec.meshdir)
    for h in spec.hfields:
        add(h.file, spec.meshdir)
    for sk in spec.skins:
        add(sk.file, spec.meshdir)
    for t in spec.textures:
        for name in (t.file, *t.cubefiles):
            add(name, spec.texturedir)
    return out


def _read(path: str) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def _read_mjcf(path: str) -> _Mjcf:
    """The MJCF file ``path`` and everything it reads, as :class:`_Mjcf` (exact unless it uses
    what this does not carry: attached ``<model>`` files, files no asset lists, two assets with
    the same base name, which MuJoCo's asset dictionary cannot tell apart)."""
    path = os.path.abspath(path)
    folder = os.path.dirname(path)
    xml = _read(path).decode("utf-8")
    include: dict[str, bytes] = {}
    exact, attrs, pending, seen = True, [], [path], set()
    while pending:
        p = pending.pop()
        if p in seen:
            continue
        seen.add(p)
        for el in ET.parse(p).getroot().iter():
            if el.tag == "include" and (name := el.get("file")):
                full = next((c for c in (os.path.join(folder, name), os.path.join(os.path.dirname(p), name))
                             if os.path.isfile(c)), os.path.join(folder, name))
                include[name] = _read(full)
                pending.append(full)
            elif el.tag == "model":
                exact = False
            else:
                attrs += [v for k, v in el.attrib.items() if k.startswith("file") and v]
    spec = mujoco.MjSpec.from_file(path)  # parsed, not compiled: the asset files with MuJoCo's folders
    assets = {key: _read(full) for key, full in _asset_files(spec)}
    bases = [os.path.basename(k).casefold() for k in assets]
    if len(set(bases)) < len(bases) or any(os.path.basename(v).casefold() not in bases for v in attrs):
        exact = False
    return _Mjcf(xml, include, assets, spec.modelfiledir, exact)


def _spec_mjcf(spec: mujoco.MjSpec) -> _Mjcf:
    """A spec given to ``from_spec`` as :class:`_Mjcf`: ``to_xml`` (not exact) and its assets,
    those in ``spec.assets`` and those on disk."""
    assets = dict(spec.assets)
    for key, full in _asset_files(spec):
        if key not in assets and os.path.basename(key) not in assets and os.path.isfile(full):
            assets[key] = _read(full)
    return _Mjcf(spec.to_xml(), {}, assets, spec.modelfiledir or "", exact=False)


@dataclass(frozen=True, eq=False)
class _Urdf(_Mjcf):
    """A URDF as bytes (:func:`profrobot.robot.urdf.read_urdf`: mesh filenames replaced by asset names,
    the meshes carried) and what :meth:`Robot.from_urdf` adds to its spec: a joint equality for
    each ``<mimic>`` that MuJoCo's URDF reader did not make one of (MuJoCo 4 makes them all), and
    the ``<exclude>``s of disabled link pairs. Exact: the same bytes and edits give the same model."""

    mimics: tuple = ()      # (joint, mimicked joint, multiplier, offset)
    excludes: tuple = ()    # (body1, body2)

    def spec(self) -> mujoco.MjSpec:
        spec = super().spec()
        coupled = {e.name1 for e in spec.equalities if e.type == mujoco.mjtEq.mjEQ_JOINT}
        for joint, other, mult, offset in self.mimics:
            if joint not in coupled:
                eq = spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, objtype=mujoco.mjtObj.mjOBJ_JOINT,
                                       name1=joint, name2=other)
                eq.data[:5] = [offset, mult, 0.0, 0.0, 0.0]
        for b1, b2 in self.excludes:
            spec.add_exclude(bodyname1=b1, bodyname2=b2)
        return spec


@dataclass(frozen=True, eq=False)
class _SpecSource:
    """How a robot's MjSpec was made: ``root`` plus the ``obstacles`` added since, in order.

    ``root`` is where the model came from until the first pickle reads it: an MJCF file's path
    (``from_mjcf``, ``from_menagerie``) or the ``MjSpec`` given to ``from_spec``; from then on the
    bytes (:class:`_Mjcf`), shared by the robots ``with_obstacles`` derives.
    """

    root: "str | mujoco.MjSpec | _Mjcf"
    obstacles: tuple = ()

    def loaded(self) -> "_SpecSource":
        if isinstance(self.root, _Mjcf):
            return self
        root = _read_mjcf(self.root) if isinstance(self.root, str) else _spec_mjcf(self.root)
        return _SpecSource(root, self.obstacles)

    def spec(self) -> mujoco.MjSpec:
        root = self.loaded().root
        assert isinstance(root, _Mjcf)   # loaded() reads the source
        spec = root.spec()
        for ob in self.obstacles:
            ob.add_to(spec)
        return spec

    def then(self, obstacles: tuple) -> "_SpecSource":
        return _SpecSource(self.root, self.obstacles + tuple(obstacles))
