"""Robots from URDF: the file as MuJoCo's URDF compiler can take it, and the collision pairs a
URDF does not care about.

:meth:`profrobot.Robot.from_urdf` is the entry point; this module holds what it needs that is
about URDF (and SRDF) rather than about MuJoCo models, and imports nothing of profrobot's but
the errors (``robot_loading.py`` imports it):

- :func:`read_urdf`: the URDF text with every mesh it loads resolved to a real file
  (``package://pkg/...`` through ``package_dirs``, ``ROS_PACKAGE_PATH``, ``AMENT_PREFIX_PATH``,
  a folder named ``pkg`` above the URDF, or, last, one beside it (pybullet_data's layout);
  ``file://`` URIs; paths relative to the URDF's folder) and renamed to a flat asset name, the mesh bytes keyed by that name, and what MuJoCo's
  compiler cannot take (floating / planar / spherical joints, unlimited prismatic joints,
  unprocessed xacro) refused with the joint or file named;
- :func:`read_srdf`: MoveIt's ``<disable_collisions link1= link2= reason=/>`` pairs;
- :func:`body_pair_rates` and :func:`adjacent`: how often each pair of links collides over a
  seeded uniform sample, and which links a single moving joint joins (fixed joints collapsed),
  for the warning and for ``collision_matrix="auto"``.

Compiler settings written into the URDF's ``<mujoco><compiler/></mujoco>`` section (MuJoCo's
URDF extension), each only where the file does not set it itself: ``fusestatic="false"`` (every
link stays a body, so that the base link's contacts are self-collisions with a name that an
``<exclude>`` can use; MuJoCo's weld filters, hence which poses collide, are the same fused or
not), ``boundmass="1e-6" boundinertia="1e-10"`` (links without ``<inertial>`` compile; masses
decide no label), ``balanceinertia="true"`` (see :func:`fix_inertias`). ``meshdir`` is
dropped: every mesh name is already resolved.

Inertias: vendors' URDFs often carry inertia tensors that are not physical (UFactory's xArm6
``link2``: principal moments that break the triangle inequality A + B >= C, which MuJoCo's
compiler refuses). Collision labels do not depend on mass or inertia, so such files load:
triangle violations through MuJoCo's own ``balanceinertia`` (the principal moments set to their
mean), tensors with a principal moment <= 0 or not finite replaced by a diagonal one, each link
named in ``robot.collision_report()``.
"""

from __future__ import annotations

import os
import urllib.parse
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..errors import InputError, MissingFileError

ALWAYS = 0.99          # a pair colliding in at least this share of sampled poses collides "always"
SAMPLE = 2000          # poses sampled to find such pairs
SEED = 0

_UNSUPPORTED = {"floating": "a floating base (6 free DoF)", "planar": "a planar base (2 unlimited slides + a hinge)",
                "spherical": "a ball joint"}
_XACRO = ("{http://www.ros.org/wiki/xacro}", "{http://ros.org/wiki/xacro}")


class CollisionWarning(UserWarning):
    """A robot loaded (MJCF or URDF), but link pairs collide in (nearly) every pose: labels are
    MuJoCo's, and nearly every pose will read as colliding until such pairs are disabled
    (``srdf=`` or ``collision_matrix="auto"``)."""


class UrdfWarning(CollisionWarning):
    """A URDF robot loaded, but something about it deserves a look (pairs that collide in nearly
    every pose, a revolute joint without limits, SRDF links that are not in the URDF)."""


def auto_pairs(m, rates: dict, n: int, body_names) -> list["DisabledPair"]:
    """``collision_matrix="auto"``'s pairs: those colliding in >= :data:`ALWAYS` of ``n`` poses
    ("Always") and adjacent ones (one moving joint apart) colliding in any ("Adjacent"); never a
    pair with the world body (excluding the world would hide obstacles too)."""
    out = []
    for (a, b), r in sorted(rates.items()):
        if a == 0:
            continue
        if r > 0 and adjacent(m, a, b):
            reason = f"Adjacent: one joint apart, collide in {pct(r)} of {n} uniform poses"
        elif r >= ALWAYS:
            reason = f"Always: collide in {pct(r)} of {n} uniform poses"
        else:
            continue
        out.append(DisabledPair(body_names[a], body_names[b], reason))
    return out


def srdf_pairs(path, body_names, name: str, source: str) -> list["DisabledPair"]:
    """The SRDF's ``<disable_collisions>`` pairs between bodies of the robot, each once; links it
    names that are not bodies are warned about and skipped."""
    srdf_path = os.path.abspath(os.fspath(path))
    pairs = read_srdf(srdf_path)
    known = set(body_names[1:])
    unknown = sorted({link for p in pairs for link in p[:2] if link not in known})
    if unknown:
        warnings.warn(f"{name}: {srdf_path} names links that are not bodies of {source} (or the world, which would "
                      f"also hide obstacles): {', '.join(unknown)}; their pairs are skipped", UrdfWarning, stacklevel=3)
    seen: set = set()
    out = []
    for p in pairs:
        key = frozenset(p[:2])
        if p.body1 in unknown or p.body2 in unknown or key in seen or len(key) < 2:
            continue
        seen.add(key)
        out.append(p)
    return out


class DisabledPair(NamedTuple):
    """A link pair whose collisions are not checked (a MuJoCo ``<exclude>``), and why."""

    body1: str
    body2: str
    reason: str


@dataclass
class UrdfFiles:
    """A URDF ready for MuJoCo: ``xml`` (mesh filenames replaced by asset names), ``assets``
    (name → bytes), the ``folder`` it was read from, its ``mimics`` (joint, mimicked joint,
    multiplier, offset), and notes for the collision report."""

    path: str
    name: str
    xml: str
    assets: dict[str, bytes]
    folder: str
    mimics: tuple[tuple[str, str, float, float], ...]
    meshes: dict[str, str] = field(default_factory=dict)   # asset name -> the URI the URDF gave
    notes: list[str] = field(default_factory=list)
    inertias: list[str] = field(default_factory=list)   # links whose <inertia> MuJoCo could not take as given


# --------------------------------------------------------------------------------------------
# package:// and relative mesh names
# --------------------------------------------------------------------------------------------

def _package_candidates(pkg: str, package_dirs, urdf_folder: str) -> list[tuple[str, str]]:
    """(folder, where it came from) that may hold package ``pkg``, in the order they are tried."""
    out: list[tuple[str, str]] = []
    dirs: list[str | os.PathLike] = []
    if isinstance(package_dirs, dict):
        if pkg in package_dirs:
            out.append((os.path.abspath(os.fspath(package_dirs[pkg])), "package_dirs"))
    elif package_dirs is not None:
        dirs = [package_dirs] if isinstance(package_dirs, (str, os.PathLike)) else list(package_dirs)

    def under(d: str | os.PathLike, why: str) -> None:
        d = os.path.abspath(os.fspath(d))
        out.append((os.path.join(d, pkg), why))
        if os.path.basename(os.path.normpath(d)) == pkg:
            out.append((d, why))

    for d in dirs:
        under(d, "package_dirs")
    for d in filter(None, os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep)):
        under(d, "ROS_PACKAGE_PATH")
    for d in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        out.append((os.path.join(os.path.abspath(d), "share", pkg), "AMENT_PREFIX_PATH"))
    here = os.path.abspath(urdf_folder)
    while True:   # a folder named after the package above the URDF (pkg/urdf/robot.urdf)
        if os.path.basename(here) == pkg:
            out.append((here, "a folder above the URDF"))
        parent = os.path.dirname(here)
        if parent == here:
            break
        here = parent
    # last: a folder named after the package beside the URDF (pybullet_data's franka_panda/panda.urdf
    # names package://meshes/... for franka_panda/meshes/)
    out.append((os.path.join(os.path.abspath(urdf_folder), pkg), "a folder beside the URDF"))
    return out


def _resolve(uri: str, urdf_path: str, package_dirs, meshdir: str = "", strip: bool = False
             ) -> tuple[str | None, str]:
    """The file a mesh ``uri`` names, or (None, what was tried and what to pass). Paths are
    relative to the URDF's folder (MuJoCo's ``meshdir`` and ``strippath`` first, when the URDF's
    ``<mujoco>`` section sets them)."""
    folder = os.path.dirname(urdf_path)
    scheme = uri.split("://", 1)[0].lower() if "://" in uri else ""
    if scheme in ("package", "model"):
        rest = uri.split("://", 1)[1]
        pkg, _, rel = rest.partition("/")
        cands = _package_candidates(pkg, package_dirs, folder)
        found = [(d, why) for d, why in cands if os.path.isdir(d)]
        if not found:
            looked = "; ".join(f"{d} ({why})" for d, why in cands)
            if len(cands) == 1:
                looked += ("; package_dirs does not name it, ROS_PACKAGE_PATH and AMENT_PREFIX_PATH are unset, and "
                           "no folder above the URDF has its name")
            return None, (f"package {pkg!r} not found (looked in: {looked}). Pass package_dirs={{{pkg!r}: "
                          f"'/path/to/{pkg}'}} (the folder holding {rel.split('/')[0] or 'the meshes'}/), or a list "
                          f"of folders that contain a {pkg}/ folder")
        for d, _why in found:
            full = os.path.normpath(os.path.join(d, rel))
            if os.path.isfile(full):
                return full, ""
        tried = "; ".join(f"{os.path.normpath(os.path.join(d, rel))} (package from {why})" for d, why in found)
        return None, (f"no such file: {tried}. If that is the wrong copy of {pkg!r}, pass "
                      f"package_dirs={{{pkg!r}: '/path/to/{pkg}'}}")
    if scheme == "file":
        full = urllib.parse.unquote(urllib.parse.urlparse(uri).path)
        return (full, "") if os.path.isfile(full) else (None, f"no such file: {full}")
    if scheme:
        return None, f"{scheme}:// URIs are not read (only package://, model://, file:// and paths); download the mesh and name its path"
    tried_paths: list[str] = []
    for name in ([os.path.basename(uri)] if strip else []) + [uri]:
        for base in ([os.path.join(folder, meshdir)] if meshdir else []) + [folder]:
            full = os.path.normpath(name if os.path.isabs(name) else os.path.join(base, name))
            if os.path.isfile(full):
                return full, ""
            tried_paths.append(full)
    return None, f"no such file: {' or '.join(dict.fromkeys(tried_paths))} (relative to the URDF's folder)"


def _float(el: ET.Element, key: str) -> float | None:
    v = el.get(key)
    if v is None:
        return None
    try:
        return float(v)
    except ValueError:
        return None


def read_urdf(path: str | os.PathLike, package_dirs=None) -> UrdfFiles:
    """The URDF at ``path`` with its meshes resolved (see the module docs); raises
    :class:`InputError` naming the file and what to pass for what it cannot take."""
    path = os.path.abspath(os.fspath(path))
    if not os.path.isfile(path):
        raise MissingFileError(f"no URDF file at {path!r}")
    if package_dirs is not None and not isinstance(package_dirs, (dict, str, os.PathLike, list, tuple)):
        raise InputError(f"package_dirs must be a dict {{package: folder}} or a list of folders; got {type(package_dirs).__name__}")
    try:
        tree = ET.parse(path)
    except ET.ParseError as e:
        raise InputError(f"{path}: not well-formed XML: {e}") from e
    root = tree.getroot()
    if root.tag != "robot":
        raise InputError(f"{path}: not a URDF (root element <{root.tag}>, not <robot>)")
    if any(el.tag.startswith(_XACRO) for el in root.iter()) or any("${" in v for el in root.iter() for v in el.attrib.values()):
        raise InputError(f"{path}: unprocessed xacro (xacro: elements or ${{...}} expressions); expand it first: "
                         f"xacro {os.path.basename(path)} > robot.urdf")

    mj = root.find("mujoco")
    if mj is None:
        mj = ET.SubElement(root, "mujoco")
    comp = mj.find("compiler")
    if comp is None:
        comp = ET.SubElement(mj, "compiler")
    discard = comp.get("discardvisual", "true").strip().lower() != "false"
    for option, value in (("fusestatic", "false"), ("boundmass", "1e-6"), ("boundinertia", "1e-10")):
        comp.attrib.setdefault(option, value)
    balance = comp.attrib.setdefault("balanceinertia", "true").strip().lower() == "true"
    inertias = fix_inertias(root, balance)
    meshdir = comp.attrib.pop("meshdir", "")
    strip = comp.get("strippath", "false").strip().lower() == "true"

    problems, unsupported, mimics, notes = [], [], [], []
    for j in root.findall("joint"):
        jname, jtype = j.get("name", "?"), j.get("type", "?")
        if jtype in _UNSUPPORTED:
            unsupported.append(f"{jname!r} (type {jtype}: {_UNSUPPORTED[jtype]})")
            continue
        lim = j.find("limit")
        lo, hi = (None, None) if lim is None else (_float(lim, "lower"), _float(lim, "upper"))
        if jtype == "continuous" and lim is not None:   # URDF: a continuous joint has no position limits
            lim.attrib.pop("lower", None)
            lim.attrib.pop("upper", None)
        elif jtype == "prismatic" and (lo is None or hi is None or lo > hi):
            problems.append(f"prismatic joint {jname!r} has no valid <limit lower= upper=>: no range to sample; "
                            "add its travel in metres")
        elif jtype == "revolute" and (lo is None or hi is None or lo > hi):
            notes.append(f"revolute joint {jname!r} has no valid <limit lower= upper=>: taken as continuous")
        mim = j.find("mimic")
        if mim is not None and (mimicked := mim.get("joint")):
            mult, off = _float(mim, "multiplier"), _float(mim, "offset")
            mimics.append((jname, mimicked, 1.0 if mult is None else mult, 0.0 if off is None else off))
    if unsupported:
        raise InputError(f"{path}: profrobot labels fixed-base robots, and these joints are not hinges or slides with "
                         f"a range: {', '.join(unsupported)}. Make the joint type=\"fixed\" (the robot at its base's "
                         "pose; move obstacles relative to it) and load the URDF again")

    sections = ["collision"] + ([] if discard else ["visual"])
    assets: dict[str, bytes] = {}
    by_file: dict[str, str] = {}
    meshes: dict[str, str] = {}
    taken: set[str] = set()
    missing: dict[str, tuple[str, list[str]]] = {}
    for link in root.findall("link"):
        for sec in sections:
            for m in link.findall(f"{sec}/geometry/mesh"):
                uri = m.get("filename", "")
                full, why = _resolve(uri, path, package_dirs, meshdir, strip)
                if full is None:
                    missing.setdefault(uri, (why, []))[1].append(f"{link.get('name')!r} ({sec})")
                    continue
                key = by_file.get(full)
                if key is None:
                    stem, ext = os.path.splitext(os.path.basename(full))
                    key, i = stem + ext.lower(), 2
                    while key.casefold() in taken:   # MuJoCo names meshes by stem: keep different files apart
                        key, i = f"{stem}_{i}{ext.lower()}", i + 1
                    taken.add(key.casefold())
                    by_file[full] = key
                    with open(full, "rb") as f:
                        assets[key] = f.read()
                    meshes[key] = uri
                m.set("filename", key)
    problems += [f"mesh {uri!r} (used by link {', '.join(links)}): {why}" for uri, (why, links) in missing.items()]
    if problems:
        raise InputError(f"{path}: " + "; ".join(problems))
    name = root.get("name") or os.path.splitext(os.path.basename(path))[0]
    xml = ET.tostring(root, encoding="unicode")
    return UrdfFiles(path, name, xml, assets, os.path.dirname(path), tuple(mimics), meshes, notes, inertias)


_INERTIA = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")


def fix_inertias(root: ET.Element, balance: bool) -> list[str]:
    """Make every link's ``<inertial><inertia/>`` one MuJoCo's compiler takes, in place, and say
    what was done, one line per link. Labels do not depend on inertia (module docs).

    - principal moments (eigenvalues of the symmetric tensor) that break A + B >= C: left to
      MuJoCo's ``balanceinertia`` (``balance``, the compiler setting, true unless the file sets
      it false), which sets them to their mean: the check is MuJoCo's (strict, on the
      principal moments), reported here;
    - a principal moment <= 0, or an entry that is not a finite number: the tensor replaced by
      the diagonal of its moments' mean magnitude (``boundinertia`` where that is 0), which
      ``balanceinertia`` cannot do.
    """
    out = []
    for link in root.findall("link"):
        el = link.find("inertial/inertia")
        if el is None:
            continue
        v = [_float(el, k) if el.get(k) is not None else 0.0 for k in _INERTIA]
        lname = link.get("name", "?")
        if any(x is None or not np.isfinite(x) for x in v):
            bad = ", ".join(f"{k}={el.get(k)!r}" for k, x in zip(_INERTIA, v) if x is None or not np.isfinite(x))
            _set_diagonal(el, 1e-10)
            out.append(f"{lname}: inertia entries that are not finite numbers ({bad}); replaced by diag(1e-10) kg·m²")
            continue
        xx, xy, xz, yy, yz, zz = v
        eig = np.linalg.eigvalsh(np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]))
        moments = ", ".join(f"{x:.4g}" for x in eig)
        if eig[0] <= 0:
            mean = float(np.mean(np.abs(eig))) or 1e-10
            _set_diagonal(el, mean)
            out.append(f"{lname}: principal moments ({moments}) kg·m² are not all positive; replaced by "
                       f"diag({mean:.4g}) kg·m²")
        elif eig[0] + eig[1] < eig[2]:
            if not balance:
                continue   # the file asked for MuJoCo's refusal: its error names the link
            out.append(f"{lname}: principal moments ({moments}) kg·m² break A + B >= C; balanced by MuJoCo's "
                       f"balanceinertia (each set to their mean, {float(np.mean(eig)):.4g})")
    return out


def _set_diagonal(el: ET.Element, value: float) -> None:
    for k in _INERTIA:
        el.set(k, repr(value) if k in ("ixx", "iyy", "izz") else "0")


def explain_compile_error(files: UrdfFiles, err: Exception) -> str:
    """MuJoCo's compile error with the URIs the URDF gave for the assets it names."""
    msg = str(err)
    hints = []
    for key, uri in files.meshes.items():
        if f"'{key}'" in msg or f"'{os.path.splitext(key)[0]}'" in msg:
            hints.append(f"{key!r} is {uri!r}")
    if "no decoder" in msg:
        hints.append("MuJoCo reads STL, OBJ and MSH meshes: convert the others (e.g. COLLADA .dae) to STL or OBJ")
    return msg.strip().replace("\n", " ") + (f" ({'; '.join(hints)})" if hints else "")


# --------------------------------------------------------------------------------------------
# SRDF
# --------------------------------------------------------------------------------------------

def read_srdf(path) -> list[DisabledPair]:
    """Every ``<disable_collisions link1= link2= reason=/>`` of the SRDF at ``path`` (others,
    ``disable_default_collisions`` and ``enable_collisions``, are not read: warned)."""
    path = os.path.abspath(os.fspath(path))
    if not os.path.isfile(path):
        raise MissingFileError(f"no SRDF file at {path!r}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise InputError(f"{path}: not well-formed XML: {e}") from e
    out = []
    for el in root.iter("disable_collisions"):
        a, b = el.get("link1"), el.get("link2")
        if not a or not b:
            raise InputError(f"{path}: <disable_collisions> needs link1= and link2=; got {el.attrib}")
        out.append(DisabledPair(a, b, f"SRDF: {el.get('reason') or 'no reason given'}"))
    other = sorted({el.tag for el in root.iter() if el.tag in ("disable_default_collisions", "enable_collisions")})
    if other:
        warnings.warn(f"{path}: {', '.join('<' + t + '>' for t in other)} not read; only <disable_collisions> pairs "
                      "are applied", UrdfWarning, stacklevel=3)
    return out


# --------------------------------------------------------------------------------------------
# Which link pairs collide how often
# --------------------------------------------------------------------------------------------

def body_pair_rates(robot, n: int = SAMPLE, seed: int = SEED) -> tuple[dict[tuple[int, int], float], int]:
    """{(body1, body2): share of ``n`` seeded uniform poses (joint couplings applied, as
    ``sample_poses`` draws them) in which some geom of body1 touches one of body2}, over the
    robot's candidate pairs between two bodies (every such pair is a key, 0.0 when never seen;
    body 0, the world, only where a URDF link was fused into it), and ``n``."""
    m = robot.mj_model
    poses = robot.core.sample(int(n), int(seed), threads=None)
    robot.couplings.apply(poses)
    out = robot.core.label(poses, pairs=True, distance=False, threads=None)
    gb = np.asarray(m.geom_bodyid)
    pair_bodies = np.sort(gb[np.asarray(robot.pair_geoms, dtype=np.int64).reshape(-1, 2)], axis=1)
    rates = {(int(a), int(b)): 0.0 for a, b in pair_bodies if a != b}
    cp = np.asarray(out["colliding_pairs"], dtype=np.int64).reshape(-1, 2)
    if len(cp):
        rows = np.unique(np.column_stack([cp[:, 0], pair_bodies[cp[:, 1]]]), axis=0)
        keys, counts = np.unique(rows[:, 1:], axis=0, return_counts=True)
        for (a, b), c in zip(keys, counts):
            if a != b:
                rates[(int(a), int(b))] = float(c) / n
    return rates, int(n)


def adjacent(m, b1: int, b2: int) -> bool:
    """Whether one moving joint joins links ``b1`` and ``b2`` (fixed joints collapsed: MuJoCo's
    weld groups, the world's included), as MoveIt's "Adjacent"."""
    weld, parent = m.body_weldid, m.body_parentid
    w1, w2 = int(weld[b1]), int(weld[b2])
    return w1 != w2 and (int(weld[parent[w2]]) == w1 or int(weld[parent[w1]]) == w2)


def pct(x: float) -> str:
    return f"{100 * x:.1f} %"
