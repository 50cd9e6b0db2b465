"""A robot scene: a compiled MuJoCo model, its joints, and its collision geometry as the flat
arrays the Rust core (`profrobot._core.RobotModel`) labels with.

One description feeds every back end: the arrays below are copied from MuJoCo's *compiled*
model (``mjModel``), never re-parsed from XML, so bodies, hulls and filters are MuJoCo's own.

A Robot pickles (multiprocessing, DataLoader workers, Ray, ``torch.save``) and deep-copies; see
:meth:`Robot.__getstate__` for what a pickle carries.
"""

from __future__ import annotations

import copy
import hashlib
import os
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from collections.abc import Sequence

import mujoco
import numpy as np

from . import _core, urdf
from .family import MarkedSceneJoints, PinnedLayout, model_scene_joints
from .equalities import EqualityWarning, JointCouplings, read_equalities, read_tendons, unenforced_summary
from .errors import CorruptFileError, InputError, InputTypeError, MissingFileError, RobotMismatchError
from .margin import ObstacleMargin, check_margin
from .obstacles import Box, Capsule, Cylinder, Mesh, Obstacle, Plane, Sphere  # noqa: F401  (their home before the split)
from .pointcloud import CLOUD_GEOM_ID, PointCloud
from .sources import _Mjcf, _SpecSource, _Urdf, _read_mjcf, _spec_mjcf, _zip, _unzip  # noqa: F401  (likewise; old pickles name them here)

_FREE, _BALL, _SLIDE, _HINGE = (int(t) for t in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL,
                                                  mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_HINGE))
_GEOM_NAMES = {int(getattr(mujoco.mjtGeom, n)): n.removeprefix("mjGEOM_").lower() for n in dir(mujoco.mjtGeom) if n.startswith("mjGEOM_") and int(getattr(mujoco.mjtGeom, n)) < 9}


#: metres: the least distance every candidate pair keeps in a certified pose (what it means:
#: :mod:`profrobot.certification`, which re-exports it).
CLEARANCE = 1e-6

_STATE_FORMAT = "profrobot.Robot/1"

#: what a Robot keeps for itself only: derived scenes (at(), with_margin()) and the MuJoCo reference
#: with its point cloud (pointcloud.reference_model); left out of copies, derived robots and pickles
_CACHES = ("_layouts", "_margins", "_reference_model", "_reference_ids")


# --------------------------------------------------------------------------------------------
# Robot
# --------------------------------------------------------------------------------------------

def _name(m: mujoco.MjModel, obj: mujoco.mjtObj, i: int, prefix: str) -> str:
    return mujoco.mj_id2name(m, obj, i) or f"{prefix}{i}"


_WARNED: set[str] = set()


def _frame(pos: np.ndarray, quat: np.ndarray, sameframe: int, inertial: tuple[np.ndarray, np.ndarray]
           ) -> tuple[np.ndarray, np.ndarray]:
    """A frame's pose in its body, taken the way ``mj_local2Global`` takes it.

    MuJoCo's compiler flags frames that (nearly) coincide with their body's frame or inertial
    frame (``*_sameframe``) and ``mj_kinematics`` then *copies* that frame instead of composing
    ``body · (pos, quat)``:
    0 none: (pos, quat); 1 body: (0, 1); 2 inertia: the inertial frame; 3 body rotation:
    (pos, 1); 4 inertial rotation: (pos, inertial quat).
    Composing the flagged pose instead leaves the geometry off MuJoCo's by up to the
    compiler's tolerance (seen: 3e-8 m on a gripper), enough to flip contacts on the boundary.
    With the frame returned here, ``body · frame`` equals MuJoCo's copy to rounding (1e-16 m).
    """
    one = np.array([1.0, 0.0, 0.0, 0.0])
    ipos, iquat = inertial
    sf = int(sameframe)
    if sf == 0:
        return pos, quat
    if sf == 1:
        return np.zeros(3), one
    if sf == 2:
        return ipos, iquat
    if sf == 3:
        return pos, one
    if sf == 4:
        return pos, iquat
    raise InputError(f"unknown MuJoCo sameframe flag {sf}")


def geom_local_frames(m: mujoco.MjModel, gids) -> tuple[np.ndarray, np.ndarray]:
    """(G, 3) positions and (G, 4) quaternions (w, x, y, z) of geoms ``gids`` in their bodies'
    frames, following MuJoCo's ``geom_sameframe`` flags (see :func:`_frame`)."""
    pos, quat = [], []
    for g in np.asarray(gids, dtype=int):
        b = int(m.geom_bodyid[g])
        inertial = _frame(m.body_ipos[b], m.body_iquat[b], m.body_sameframe[b], (None, None))
        p, q = _frame(m.geom_pos[g], m.geom_quat[g], m.geom_sameframe[g], inertial)
        pos.append(p)
        quat.append(q)
    return np.asarray(pos, dtype=np.float64).reshape(-1, 3), np.asarray(quat, dtype=np.float64).reshape(-1, 4)


def _hull_vertices(m: mujoco.MjModel, mesh: int) -> np.ndarray:
    """The vertices MuJoCo collides for a mesh: its convex hull's when compiled, else all."""
    adr, num = m.mesh_vertadr[mesh], m.mesh_vertnum[mesh]
    verts = m.mesh_vert[adr:adr + num]
    gadr = m.mesh_graphadr[mesh]
    if gadr >= 0:
        # mesh_graph layout: numvert, numface, vert_edgeadr[numvert], vert_globalid[numvert], ...
        nv = int(m.mesh_graph[gadr])
        ids = m.mesh_graph[gadr + 2 + nv: gadr + 2 + 2 * nv]
        verts = verts[ids]
    return np.ascontiguousarray(verts, dtype=np.float64)


def _core_arrays(m: mujoco.MjModel) -> dict[str, np.ndarray]:
    """The flat arrays (ModelDesc) the Rust core labels with, from a compiled model."""
    f64 = lambda a, cols=None: np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1, cols) if cols
                                                    else np.asarray(a, dtype=np.float64))
    i32 = lambda a: np.ascontiguousarray(a, dtype=np.int32)
    collidable = (m.geom_contype != 0) | (m.geom_conaffinity != 0)
    collidable[m.pair_geom1] = True
    collidable[m.pair_geom2] = True
    gids = np.flatnonzero(collidable)
    override = bool(m.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE)
    geom_margin = m.geom_margin[gids].copy()
    pair_margin = m.pair_margin.copy()
    if override:  # mj_assignMargin: every contact uses o_margin
        geom_margin[:] = m.opt.o_margin / 2
        pair_margin[:] = m.opt.o_margin

    mesh_ids = sorted({int(m.geom_dataid[g]) for g in gids if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH})
    mesh_index = {mid: i for i, mid in enumerate(mesh_ids)}
    hulls = [_hull_vertices(m, mid) for mid in mesh_ids]
    adr = np.cumsum([0] + [len(h) for h in hulls])[:-1]
    geom_mesh = [mesh_index.get(int(m.geom_dataid[g]), -1) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH else -1
                 for g in gids]
    geom_pos, geom_quat = geom_local_frames(m, gids)
    excl = np.array([[s >> 16, s & 0xFFFF] for s in m.exclude_signature], dtype=np.int32).reshape(-1, 2)
    dis = m.opt.disableflags
    return dict(
        body_parent=i32(m.body_parentid), body_weld=i32(m.body_weldid),
        body_pos=f64(m.body_pos, 3), body_quat=f64(m.body_quat, 4),
        jnt_type=i32(m.jnt_type), jnt_body=i32(m.jnt_bodyid), jnt_pos=f64(m.jnt_pos, 3),
        jnt_axis=f64(m.jnt_axis, 3), jnt_qpos0=f64(m.qpos0[m.jnt_qposadr]),
        jnt_range=f64(m.jnt_range, 2), jnt_limited=np.ascontiguousarray(m.jnt_limited != 0),
        geom_id=i32(gids), geom_type=i32(m.geom_type[gids]), geom_body=i32(m.geom_bodyid[gids]),
        geom_pos=f64(geom_pos, 3), geom_quat=f64(geom_quat, 4),
        geom_size=f64(m.geom_size[gids], 3),
        geom_contype=np.ascontiguousarray(m.geom_contype[gids], dtype=np.uint32),
        geom_conaffinity=np.ascontiguousarray(m.geom_conaffinity[gids], dtype=np.uint32),
        geom_margin=f64(geom_margin), geom_mesh=i32(geom_mesh),
        mesh_vert_adr=np.ascontiguousarray(adr, dtype=np.uint32),
        mesh_vert_num=np.ascontiguousarray([len(h) for h in hulls], dtype=np.uint32),
        mesh_vert=f64(np.concatenate(hulls) if hulls else np.zeros((0, 3)), 3),
        exclude=excl,
        pair_geom=np.ascontiguousarray(np.stack([m.pair_geom1, m.pair_geom2], axis=1), dtype=np.int32).reshape(-1, 2),
        pair_margin=f64(pair_margin),
        filter_parent=not (dis & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT),
        contact_enabled=not (dis & (mujoco.mjtDisableBit.mjDSBL_CONTACT | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)),
    )


def _fingerprint(joint_names: list[str], arrays: dict[str, np.ndarray], scene_joints: Sequence[str] = ()) -> str:
    """sha256 of everything that decides labels: joints, bodies, geoms, hulls, filters (and, for a
    family of scenes, which joints are scene joints)."""
    h = hashlib.sha256()
    h.update("\0".join(joint_names).encode())
    if scene_joints:
        h.update(("scene:" + "\0".join(scene_joints)).encode())
    for key in sorted(arrays):
        if key == "jnt_scene" or key.startswith("eq_"):  # scene joints: by name above; couplings decide no label
            continue
        v = np.asarray(arrays[key])
        h.update(key.encode())
        h.update(np.ascontiguousarray(np.round(v, 12) if v.dtype.kind == "f" else v).tobytes())
    return h.hexdigest()[:32]


def _root_tag(path: str) -> str | None:
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


class Robot:
    """A MuJoCo robot scene ready for exact collision labelling.

    The pose vector ``theta`` (K,) covers every joint in MuJoCo joint order (hinges in radians,
    slides in metres); free and ball joints are rejected. Static obstacles are the world-body
    geoms of the model (and those added with :meth:`with_obstacles`).

    A *family of scenes* (:mod:`profrobot.family`) also has scene joints, the joints that move
    obstacles (``scene_joints``; ``scene_index`` / ``robot_index`` split the pose vector into δ and
    θ): built by ``with_obstacles`` with ``moves=``, :meth:`with_scene_joints`, or an MJCF that
    names them. :meth:`at` pins a layout δ into an ordinary static scene.

    Build one with :meth:`from_menagerie`, :meth:`from_mjcf`, :meth:`from_urdf`,
    :meth:`from_model`, or ``profrobot.scenes.load(name)``.

    A Robot pickles and deep-copies: the copy labels byte for byte like the original, has its
    fingerprint, and ``with_obstacles`` works on it (see :meth:`__getstate__`).
    """

    #: link (body) pairs whose collisions profrobot was asked not to check (``from_urdf``'s
    #: ``srdf=`` / ``collision_matrix="auto"``), applied as MuJoCo ``<exclude>``s: (body1, body2, reason)
    disabled_pairs: tuple = ()
    _collision_notes: str = ""
    #: the joints that move obstacles (a family of scenes, :mod:`profrobot.family`); () otherwise
    scene_joints: tuple = ()
    #: for a layout made by :meth:`at`: the family's scene-joint values (D,) and fingerprint
    layout: np.ndarray | None = None
    family_fingerprint: str | None = None
    #: metres: the safety margin every obstacle geom has at least (:meth:`with_margin`); 0 for the
    #: model's own margins
    margin: float = 0.0
    #: the point-cloud obstacle (:meth:`with_points`, :mod:`profrobot.pointcloud`), or None
    cloud: PointCloud | None = None

    def __init__(self, model: mujoco.MjModel, *, name: str = "robot", spec: mujoco.MjSpec | None = None):
        if not isinstance(model, mujoco.MjModel):
            raise InputTypeError(f"Robot needs a mujoco.MjModel; got {type(model).__name__}")
        self._mj_model: mujoco.MjModel | None = model
        self.name = name
        self._spec = spec
        self._source: _SpecSource | None = _SpecSource(spec) if spec is not None else None
        self._spec_lost: str | None = None  # why a pickle could not carry the spec
        m = model
        bad = [(_name(m, mujoco.mjtObj.mjOBJ_JOINT, j, "joint"), int(t)) for j, t in enumerate(m.jnt_type)
               if t not in (_HINGE, _SLIDE)]
        if bad:
            kinds = {_FREE: "free", _BALL: "ball"}
            desc = ", ".join(f"{n!r} ({kinds.get(t, t)})" for n, t in bad)
            raise InputError(f"{name}: only hinge and slide joints are supported; found {desc}. "
                             "Remove free-floating objects and ball joints from the scene.")
        if m.njnt == 0:
            raise InputError(f"{name}: the model has no joints, so there is no pose to label")

        self.joint_names: list[str] = [_name(m, mujoco.mjtObj.mjOBJ_JOINT, j, "joint") for j in range(m.njnt)]
        self.joint_types: list[str] = ["hinge" if t == _HINGE else "slide" for t in m.jnt_type]
        self.qpos_adr = np.asarray(m.jnt_qposadr, dtype=np.int64)
        self.continuous = (m.jnt_type == _HINGE) & (m.jnt_limited == 0)
        self.joint_parents = self._joint_parents()
        self.body_names: list[str] = [_name(m, mujoco.mjtObj.mjOBJ_BODY, b, "body") for b in range(m.nbody)]
        self.equalities = read_equalities(m)
        self.tendons = read_tendons(m)
        self.couplings = JointCouplings(m, self.joint_names)
        loose = unenforced_summary(self.equalities, self.tendons)
        if loose and loose not in _WARNED:  # once per process for the same couplings
            _WARNED.add(loose)
            warnings.warn(f"{name}: uniform sampling leaves these couplings free: {loose}. "
                          "sample_poses(..., equalities='settle') projects poses onto them "
                          "(robot.equalities lists every equality).", EqualityWarning, stacklevel=3)
        self._arrays = _core_arrays(m)
        self._arrays.update(self.couplings.arrays())  # the core keeps planned and searched poses on them
        self.scene_joints = self._read_scene_joints(m)
        if self.scene_joints:  # the labeller counts robot–obstacle contacts as scene contacts
            self._arrays["jnt_scene"] = np.array([n in self.scene_joints for n in self.joint_names])
        self.core = _core.RobotModel(self._arrays)
        self.pair_geoms, self.pair_is_self, self.pair_margin = self.core.pairs()
        self.fingerprint = _fingerprint(self.joint_names, self._arrays, self.scene_joints)
        #: the fingerprint of the robot before any safety margin (:meth:`with_margin`): the geometry
        #: a field, views or Gaussians were made for. Labels follow :attr:`fingerprint`.
        self.geometry_fingerprint = self.fingerprint
        self.layout = None
        self.family_fingerprint = None

    def _read_scene_joints(self, m: mujoco.MjModel) -> tuple[str, ...]:
        names = model_scene_joints(m)
        index = {n: j for j, n in enumerate(self.joint_names)}
        for n in names:
            j = index.get(n)
            if j is None:
                raise InputError(f"{self.name}: the model's profrobot:scene_joints names {n!r}, which is not a joint")
            if not m.jnt_limited[j]:
                raise InputError(f"{self.name}: scene joint {n!r} has no range; a family needs each scene joint's "
                                 "range (limited=\"true\" range=\"low high\")")
        if len(set(names)) != len(names):
            raise InputError(f"{self.name}: profrobot:scene_joints lists a joint twice: {names}")
        if names:
            self._check_scene_bodies(m, {index[n] for n in names})
        return tuple(sorted(names, key=index.__getitem__))  # MuJoCo joint order

    def _check_scene_bodies(self, m: mujoco.MjModel, scene: set[int]) -> None:
        """What makes a layout pinned into a static scene label like the family: each scene body
        carries scene joints only, hangs from a body fixed to the world, has no robot joint below
        it, and its subtree is excluded (``<exclude>``) from the world and from the other scene
        bodies' subtrees (pinned, MuJoCo filters those pairs as welded together)."""
        bn = self.body_names
        tops = sorted({int(m.jnt_bodyid[j]) for j in scene})
        below = {t: [b for b in range(m.nbody) if int(m.body_weldid[b]) == t] for t in tops}
        for t in tops:
            sub = [self.joint_names[j] for j in range(m.njnt) if j not in scene and self._is_below(m, int(m.jnt_bodyid[j]), t)]
            if sub:
                names = sub
                raise InputError(f"{self.name}: scene body {bn[t]!r} also moves with robot joints {names}; a scene "
                                 "body carries scene joints only and has no robot joint below it")
            if int(m.body_weldid[m.body_parentid[t]]) != 0:
                raise InputError(f"{self.name}: scene body {bn[t]!r} hangs from {bn[int(m.body_parentid[t])]!r}, which "
                                 "moves; a scene body's parent must be fixed to the world")
        excluded = {int(s) for s in m.exclude_signature}
        sig = lambda a, b: ((min(a, b) << 16) + max(a, b)) in excluded or ((max(a, b) << 16) + min(a, b)) in excluded
        missing, done = [], [0]
        for t in tops:
            for b in below[t]:
                missing += [(bn[o], bn[b]) for o in done if not sig(o, b)]
            done += below[t]
        if missing:
            lines = "".join(f'\n  <exclude body1="{a}" body2="{b}"/>' for a, b in missing[:8])
            raise InputError(f"{self.name}: scene bodies must not collide with the world or with each other (pinned at a "
                             f"layout, MuJoCo would filter those pairs); the model lacks {len(missing)} <exclude>(s):{lines}"
                             f"{' ...' if len(missing) > 8 else ''}\nAdd them to the MJCF's <contact>, or build the family "
                             "with robot.with_scene_joints(names), which adds them")

    @staticmethod
    def _is_below(m: mujoco.MjModel, b: int, top: int) -> bool:
        while b > 0:
            if b == top:
                return True
            b = int(m.body_parentid[b])
        return False

    # ---- constructors ------------------------------------------------------------------------
    @classmethod
    def from_menagerie(cls, name: str, entry: str | None = None) -> "Robot":
        """A MuJoCo Menagerie model by name (``entry``: an entry point; None: the default scene).

        Uses the ``mujoco_menagerie`` package (which honours ``MENAGERIE_ROOT`` for local copies).
        """
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

    @classmethod
    def from_mjcf(cls, path: str | os.PathLike, *, srdf: str | os.PathLike | None = None,
                  collision_matrix: str | None = None) -> "Robot":
        """An MJCF file on disk (its meshes resolved relative to it); a URDF (``.urdf``, or a
        ``<robot>`` root) goes to :meth:`from_urdf` with these options.

        Collisions as :meth:`from_urdf`: the model's own pairs by default, with a
        :class:`profrobot.urdf.CollisionWarning` naming the body pairs that collide in >= 99 % of
        2000 seeded uniform poses (a base overlapping the shoulder makes every pose "collide");
        ``srdf=`` disables a MoveIt SRDF's ``<disable_collisions>`` pairs, ``collision_matrix=
        "auto"`` the always-colliding pairs and the adjacent ones that ever touch (never a pair
        with the world). Disabled pairs become MuJoCo ``<exclude>``s on the spec, so the
        cross-check still compares like with like; ``robot.disabled_pairs`` and
        ``robot.collision_report()`` say which and why."""
        path = os.fspath(path)
        if collision_matrix not in (None, "auto"):
            raise InputError(f"collision_matrix must be None or 'auto'; got {collision_matrix!r}")
        if not os.path.isfile(path):
            raise MissingFileError(f"no MJCF file at {path!r}")
        if path.lower().endswith(".urdf") or _root_tag(path) == "robot":
            return cls.from_urdf(path, srdf=srdf, collision_matrix=collision_matrix)
        try:
            spec = mujoco.MjSpec.from_file(path)
        except Exception as e:  # mujoco raises ValueError with the parser's message
            raise InputError(f"could not read MJCF {path!r}: {e}") from e
        robot = cls.from_spec(spec, name=os.path.splitext(os.path.basename(path))[0])
        robot._source = _SpecSource(os.path.abspath(path))  # a pickle carries the files themselves (exact)
        return robot._with_collision_matrix(path, srdf, collision_matrix)

    def _with_collision_matrix(self, source: str, srdf, collision_matrix: str | None) -> "Robot":
        """This (MJCF) robot with ``srdf=`` / ``collision_matrix="auto"`` applied as ``<exclude>``
        edits, and the always-colliding pairs that remain warned about."""
        disabled = urdf.srdf_pairs(srdf, self.body_names, self.name, source) if srdf is not None else []
        robot = self._derived_excluding(disabled) if disabled else self
        rates, n = urdf.body_pair_rates(robot)
        bn = robot.body_names
        before = None
        if collision_matrix == "auto":
            auto = urdf.auto_pairs(robot.mj_model, rates, n, bn)
            if auto:
                before = robot
                robot = self._derived_excluding(disabled + auto)
                disabled += auto
        left = {k: r for k, r in rates.items() if r >= urdf.ALWAYS and (collision_matrix != "auto" or k[0] == 0)}
        if left:
            listed = ", ".join(f"{bn[a]}–{bn[b]} ({urdf.pct(r)})" for (a, b), r in sorted(left.items()))
            warnings.warn(f"{self.name} ({source}): {len(left)} body pair(s) collide in (nearly) every pose (>= "
                          f"{urdf.pct(urdf.ALWAYS)} of {n} uniform poses): {listed}, so nearly every pose labels as "
                          "colliding. Pass collision_matrix='auto' (or srdf=, MoveIt <disable_collisions>) to "
                          "Robot.from_mjcf to disable such pairs; robot.collision_report() has the details.",
                          urdf.CollisionWarning, stacklevel=3)
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
            lines.append(robot._collision_rate_line(n, before))
            robot._collision_notes = "\n".join(lines)
        return robot

    def _derived_excluding(self, pairs) -> "Robot":
        """This robot with MuJoCo ``<exclude>``s between the body pairs ``pairs`` (DisabledPairs)."""
        edit = ExcludedPairs(tuple((p.body1, p.body2) for p in pairs))
        spec = self._editable("a collision matrix")
        edit.add_to(spec)
        return self._derived(spec, (edit,), self.name)

    @classmethod
    def from_urdf(cls, path: str | os.PathLike, *, package_dirs=None, srdf: str | os.PathLike | None = None,
                  collision_matrix: str | None = None, name: str | None = None) -> "Robot":
        """A URDF file, compiled by MuJoCo's URDF compiler with its meshes resolved.

        ``package_dirs``: where ``package://pkg/...`` meshes live, as ``{"pkg": "/path/to/pkg"}``
        or a list of folders that contain ``pkg/``; then ``ROS_PACKAGE_PATH``,
        ``AMENT_PREFIX_PATH`` (``share/pkg``), a folder named ``pkg`` above the URDF and, last,
        one beside it (pybullet_data's layout) are tried. Relative mesh paths are relative to the
        URDF's folder. A mesh that cannot be found raises :class:`InputError` naming the URDF,
        the URI, where it looked and what to pass.

        Collision geometry only (MuJoCo's ``discardvisual``, unless the URDF's ``<mujoco>``
        section says otherwise); meshes collide as MuJoCo's convex hulls. Joint limits are the
        URDF's; ``continuous`` joints (and revolute joints without limits) are unlimited hinges,
        ``robot.continuous``. A ``<mimic>`` joint becomes a MuJoCo joint equality
        (``polycoef = offset, multiplier``), enforced by ``sample_poses``' ``equalities="auto"``.
        Floating, planar and spherical joints are refused (profrobot labels fixed-base robots).
        Inertias MuJoCo's compiler refuses (A + B < C, as in UFactory's xArm6, or a moment <= 0)
        are balanced or replaced, and named in the collision report: labels do not depend on them.

        Collisions: by default the pairs are MuJoCo's (labels agree with MuJoCo's compile of the
        file), and link pairs that collide in >= 99 % of 2000 seeded uniform poses are warned
        about (:class:`profrobot.urdf.UrdfWarning`), typically a base link overlapping link 1 (a
        link welded to the world is not filtered against its child). ``srdf=``: a MoveIt SRDF
        whose ``<disable_collisions>`` pairs are disabled. ``collision_matrix="auto"``: disable
        the pairs that collide in >= 99 % of those poses and the adjacent pairs (one moving joint
        apart, fixed joints collapsed) that collide in any; nothing else. Disabled pairs are MuJoCo
        ``<exclude>``s on the spec, so :func:`profrobot.crosscheck` still compares like with like;
        ``robot.disabled_pairs`` lists them and ``robot.collision_report()`` says why.
        """
        if collision_matrix not in (None, "auto"):
            raise InputError(f"collision_matrix must be None or 'auto'; got {collision_matrix!r}")
        files = urdf.read_urdf(path, package_dirs)
        name = name or files.name
        for note in files.notes:
            warnings.warn(f"{name} ({files.path}): {note}", urdf.UrdfWarning, stacklevel=2)
        root = _Urdf(files.xml, {}, _zip(files.assets), files.folder, True, mimics=files.mimics)
        robot = cls._from_urdf_root(root, files, name)
        disabled: list[urdf.DisabledPair] = []
        if srdf is not None:
            disabled = urdf.srdf_pairs(srdf, robot.body_names, name, files.path)
            if disabled:
                robot = cls._from_urdf_root(replace(root, excludes=tuple(p[:2] for p in disabled)), files, name)
        rates, n = urdf.body_pair_rates(robot)
        m, bn = robot.mj_model, robot.body_names
        always = {k: r for k, r in rates.items() if r >= urdf.ALWAYS}
        before = None
        if collision_matrix == "auto":
            auto = urdf.auto_pairs(m, rates, n, bn)
            if auto:
                before = robot
                disabled += auto
                robot = cls._from_urdf_root(replace(root, excludes=tuple(p[:2] for p in disabled)), files, name)
        left = {k: r for k, r in always.items() if collision_matrix != "auto" or k[0] == 0}
        if left:
            listed = ", ".join(f"{bn[a]}–{bn[b]} ({urdf.pct(r)})" for (a, b), r in sorted(left.items()))
            world = (" Pairs with 'world' are links fused into it (the URDF's <mujoco><compiler fusestatic=\"true\"/>): "
                     "disable them with srdf= naming the link, never the world." if any(a == 0 for a, _ in left) else "")
            warnings.warn(f"{name} ({files.path}): {len(left)} link pair(s) collide in (nearly) every pose (>= "
                          f"{urdf.pct(urdf.ALWAYS)} of {n} uniform poses): {listed}. These are MuJoCo's labels for this "
                          "URDF (a link welded to the world is not filtered against its child); pass srdf= (MoveIt "
                          "<disable_collisions>) or collision_matrix='auto' to disable such pairs; "
                          f"robot.collision_report() has the details.{world}", urdf.UrdfWarning, stacklevel=2)
        robot.disabled_pairs = tuple(disabled)
        robot._collision_notes = robot._urdf_report(files, rates, n, left, before)
        return robot

    @classmethod
    def _from_urdf_root(cls, root: "_Urdf", files: "urdf.UrdfFiles", name: str) -> "Robot":
        try:
            spec = root.spec()
            model = spec.compile()
        except Exception as e:
            raise InputError(f"{files.path}: MuJoCo could not compile the URDF: "
                             f"{urdf.explain_compile_error(files, e)}") from e
        free = [_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint") for j in range(model.njnt) if model.jnt_type[j] == _FREE]
        if free:
            raise InputError(f"{files.path}: the compiled model has a free joint ({', '.join(map(repr, free))}): a "
                             "floating base, which profrobot cannot label; fix the base link to the world")
        robot = cls(model, name=name, spec=spec)
        robot._source = _SpecSource(root)   # the URDF text and mesh bytes: pickles rebuild it exactly
        return robot

    def _urdf_report(self, files: "urdf.UrdfFiles", rates: dict, n: int, always: dict, before: "Robot | None") -> str:
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
        lines.append(self._collision_rate_line(n, before))
        return "\n".join(lines)

    def _collision_rate_line(self, n: int, before: "Robot | None") -> str:
        """The collision reports' last line: how often ``n`` seeded uniform poses collide, and
        how often they did ``before`` the collision matrix."""
        poses = self.core.sample(n, urdf.SEED, threads=None)
        self.couplings.apply(poses)
        rate = float(np.mean(self.core.collides(poses, threads=None)))
        was = "" if before is None else f" ({urdf.pct(float(np.mean(before.core.collides(poses, threads=None))))} before the matrix)"
        return f"  collides in {urdf.pct(rate)} of those {n} uniform poses{was}"

    def collision_report(self) -> str:
        """What profrobot disabled among this robot's collision pairs, and why (``from_urdf``);
        for other robots, that MuJoCo's filters and the model's own ``<exclude>``s apply."""
        if self._collision_notes:
            return self._collision_notes
        n = len(self._arrays["exclude"])
        return f"{self.name}: no collision pairs disabled by profrobot (MuJoCo's filters and the model's {n} <exclude>s apply)"

    @classmethod
    def from_spec(cls, spec: mujoco.MjSpec, *, name: str = "robot") -> "Robot":
        """An editable ``mujoco.MjSpec`` (kept, so that obstacles can be added later)."""
        try:
            model = spec.compile()
        except Exception as e:
            raise InputError(f"could not compile {name!r}: {e}") from e
        return cls(model, name=name, spec=spec)

    @classmethod
    def from_model(cls, model: mujoco.MjModel, *, name: str = "robot") -> "Robot":
        """An already compiled ``mujoco.MjModel`` (obstacles cannot be added to it afterwards)."""
        return cls(model, name=name)

    def with_obstacles(self, obstacles: Sequence[Obstacle], *, name: str | None = None) -> "Robot":
        """A new Robot: this scene plus ``obstacles`` (Box, Sphere, Capsule, Cylinder, Plane, Mesh),
        fixed to the world, or movable within ranges (``moves=Moves(...)``: the result is a family
        of scenes, see :mod:`profrobot.family`). The original is left unchanged."""
        if isinstance(obstacles, Obstacle):
            raise InputTypeError(f"obstacles must be a list of obstacles; got one {type(obstacles).__name__}: "
                                 f"pass [{type(obstacles).__name__}(...)]")
        try:
            obstacles = tuple(obstacles)
        except TypeError:
            raise InputTypeError(f"obstacles must be a list of profrobot obstacles (Box, Sphere, ...); got "
                                 f"{type(obstacles).__name__}") from None
        for i, ob in enumerate(obstacles):
            if not isinstance(ob, (Obstacle, PointCloud)):
                raise InputTypeError(f"obstacles[{i}] must be a profrobot Obstacle (Box, Sphere, Capsule, Cylinder, "
                                     f"Plane, Mesh) or a PointCloud; got {type(ob).__name__}")
        clouds = [ob for ob in obstacles if isinstance(ob, PointCloud)]
        obstacles = tuple(ob for ob in obstacles if not isinstance(ob, PointCloud))
        if clouds:  # balls join this robot's cloud (one cloud per robot: their union)
            union = sum(clouds[1:], self.cloud + clouds[0] if self.cloud is not None else clouds[0])
            base = self.with_obstacles(obstacles, name=name) if obstacles else self
            return base.with_points(union)
        spec = self._editable("obstacles")
        taken = {g.name for g in spec.geoms if g.name} | {b.name for b in spec.bodies if b.name}
        for i, ob in enumerate(obstacles):
            if ob.name and ob.name in taken:
                raise InputError(f"obstacles[{i}]: the name {ob.name!r} is taken (by another obstacle or by a geom or "
                                 f"body of {self.name}); names must be unique")
            if ob.name:
                taken.add(ob.name)
            try:
                ob.add_to(spec)
            except ValueError as e:
                if isinstance(e, InputError):
                    raise
                raise InputError(f"obstacles[{i}] ({ob.label}): MuJoCo refused it: {e}") from e
        return self._derived(spec, obstacles, name or self.name)

    def _derived(self, spec: mujoco.MjSpec, edits: tuple, name: str) -> "Robot":
        """The robot of ``spec``, this robot's spec after ``edits`` (their ``add_to``), carrying
        the edits in its source (pickles rebuild it) and this robot's collision notes."""
        if self.margin > 0 and not any(isinstance(e, ObstacleMargin) for e in edits):
            keep = ObstacleMargin(self.margin)  # obstacles added to a robot with a margin get it too
            keep.add_to(spec)
            edits = tuple(edits) + (keep,)
        robot = Robot.from_spec(spec, name=name)
        robot.margin = self.margin
        if self._source is not None:
            robot._source = self._source.then(edits)
        if self.disabled_pairs or self._collision_notes:
            robot.disabled_pairs, robot._collision_notes = self.disabled_pairs, self._collision_notes
        if self.cloud is not None:  # the point cloud stays (with this robot's margin)
            robot = robot.with_points(self.cloud)
        return robot

    # ---- point clouds (profrobot.pointcloud) ---------------------------------------------------
    def with_points(self, points, radius=None) -> "Robot":
        """This scene with the point-cloud obstacle ``points``: a :class:`~profrobot.PointCloud`, or
        an (N, 3) array of world points in metres with ``radius`` (metres: one number, the sensor's
        resolution, or one per point; default 0.005). It **replaces** this robot's cloud, if any
        (``with_obstacles([cloud])`` adds to it); ``None`` or an empty cloud removes it.

        Cheap enough to call per camera frame: the MuJoCo model and the geoms' hulls are shared,
        only the cloud's tree and the candidate pairs are built (``rust/cloud.rs``). The balls get
        this robot's :attr:`margin`. The result keeps :attr:`geometry_fingerprint` (a field trained
        on the modelled scene still guides it; every answer is certified against the cloud too) and
        ``layout``; its :attr:`fingerprint` covers the cloud."""
        if points is None:
            cloud = None
        elif isinstance(points, PointCloud):
            if radius is not None:
                raise InputError("radius is given by the PointCloud itself; pass radius only with an array of points")
            cloud = points
        else:
            cloud = PointCloud(points, 0.005 if radius is None else radius)
        new = object.__new__(type(self))
        new.__dict__.update({k: v for k, v in self.__dict__.items()
                             if k not in _CACHES})
        arrays = {k: v for k, v in self._arrays.items() if not k.startswith("cloud_")}
        if cloud is not None and len(cloud):
            arrays.update(cloud.core_arrays(self.margin))
            new.core = self.core.with_cloud(arrays["cloud_points"], arrays["cloud_radius"], self.margin)
        else:
            new.core = self.core.with_cloud(None, None)
        new._arrays = arrays
        new.cloud = cloud
        new.pair_geoms, new.pair_is_self, new.pair_margin = new.core.pairs()
        new.fingerprint = _fingerprint(self.joint_names, arrays, self.scene_joints)
        return new

    def _editable(self, what: str) -> mujoco.MjSpec:
        base = self.spec
        if base is None:
            if self._spec_lost:
                raise InputError(f"{self.name}: {what} needs the MjSpec, which this robot's pickle could not carry "
                                 f"({self._spec_lost}); use the original robot")
            raise InputError(f"{self.name}: {what} needs the MjSpec; build the robot with from_menagerie, "
                             "from_mjcf or from_spec rather than from_model")
        return base.copy()

    # ---- families of scenes (profrobot.family) -------------------------------------------------
    def with_scene_joints(self, names: Sequence[str], *, name: str | None = None) -> "Robot":
        """A family of scenes from this model: its joints ``names`` (each with a finite range) become
        scene joints δ, the ones that move obstacles; the rest stay the robot's θ. Scene bodies get
        ``<exclude>``s against the world and each other (see :mod:`profrobot.family`)."""
        if isinstance(names, str) or not all(isinstance(n, str) for n in names):
            raise InputTypeError("names must be a list of joint names")
        edit = MarkedSceneJoints(tuple(names))
        spec = self._editable("with_scene_joints")
        edit.add_to(spec)
        return self._derived(spec, (edit,), name or self.name)

    @property
    def is_family(self) -> bool:
        """Whether some joints are scene joints (a family of scenes, :mod:`profrobot.family`)."""
        return bool(self.scene_joints)

    @property
    def scene_index(self) -> np.ndarray:
        """(D,) indices of the scene joints δ in the pose vector."""
        return np.array([self.joint_names.index(n) for n in self.scene_joints], dtype=np.int64)

    @property
    def robot_index(self) -> np.ndarray:
        """(K − D,) indices of the robot's own joints θ in the pose vector (all of them for an
        ordinary scene)."""
        return np.setdiff1d(np.arange(self.njoint), self.scene_index)

    def check_scene(self, scene, *, name: str = "scene") -> np.ndarray:
        """A layout δ as a float64 array (D,): one value per scene joint (radians / metres, in
        ``scene_joints`` order), finite and within the family's ranges, else :class:`InputError`
        naming the entry. A dict ``{joint name: value}`` must name every scene joint."""
        if not self.scene_joints:
            raise InputError(f"{self.name} is not a family of scenes (it has no scene joints), so it takes no {name}")
        D = len(self.scene_joints)
        if isinstance(scene, dict):
            unknown = sorted(set(scene) - set(self.scene_joints))
            missing = [n for n in self.scene_joints if n not in scene]
            if unknown or missing:
                raise InputError(f"{name} must give every scene joint of {self.name}: "
                                 + "; ".join(filter(None, [f"unknown {unknown}" if unknown else "",
                                                           f"missing {missing}" if missing else ""])))
            scene = [scene[n] for n in self.scene_joints]
        if hasattr(scene, "detach"):  # a torch tensor
            scene = scene.detach().cpu().numpy()
        try:
            delta = np.array(scene, dtype=np.float64)
        except (TypeError, ValueError) as e:
            raise InputError(f"{name} must be {D} numbers (one per scene joint); got {scene!r}") from e
        if delta.shape != (D,):
            raise InputError(f"{name} must have shape ({D},), one value per scene joint {list(self.scene_joints)}; "
                             f"got shape {delta.shape}")
        limits = self.joint_limits[self.scene_index]
        for i, (v, (lo, hi), n) in enumerate(zip(delta, limits, self.scene_joints)):
            if not np.isfinite(v):
                raise InputError(f"{name}[{i}] ({n}) is {v}")
            if not lo - 1e-9 <= v <= hi + 1e-9:
                raise InputError(f"{name}[{i}] ({n}) = {v:.6g} is outside the family's range [{lo:.6g}, {hi:.6g}]: "
                                 "refused rather than extrapolated; build a family with wider ranges")
        return np.clip(delta, limits[:, 0], limits[:, 1])

    def compose(self, theta, scene) -> np.ndarray:
        """Full pose vectors (N, K) from robot poses θ (N, K − D) and a layout δ (D,) or one per
        pose (N, D): the labeller's view of a family."""
        theta = np.asarray(theta, dtype=np.float64)
        one = theta.ndim == 1
        theta = np.atleast_2d(theta)
        ri = self.robot_index
        if theta.ndim != 2 or theta.shape[1] != len(ri):
            raise InputError(f"theta must have {len(ri)} columns (the robot joints of {self.name}); got shape {theta.shape}")
        out = np.empty((len(theta), self.njoint))
        out[:, ri] = theta
        out[:, self.scene_index] = self.check_scenes(scene, len(theta))
        return out[0] if one else out

    def check_scenes(self, scene, n: int) -> np.ndarray:
        """The layouts of ``n`` poses, each checked by :meth:`check_scene`: (1, D) for one layout
        (D,) or dict shared by all, (n, D) for one layout per pose (rows named ``scene[i]``)."""
        if hasattr(scene, "detach"):  # a torch tensor
            scene = scene.detach().cpu().numpy()
        if isinstance(scene, dict) or np.ndim(scene) != 2:
            return self.check_scene(scene)[None]
        rows = np.asarray(scene, dtype=np.float64)
        if len(rows) != n:
            raise InputError(f"scene must be (D,) or one layout per pose ({n}, D); got shape {rows.shape}")
        return np.stack([self.check_scene(d, name=f"scene[{i}]") for i, d in enumerate(rows)])

    def at(self, scene, *, name: str | None = None) -> "Robot":
        """The family's scene at layout δ (``scene``: (D,) or ``{scene joint: value}``): an ordinary
        Robot whose scene bodies are pinned there (static obstacles), its pose vector θ the
        robot joints. ``robot.layout`` keeps δ and ``robot.family_fingerprint`` the family's.

        Refused (:class:`InputError`): δ outside the family's ranges, wrong length, NaN, and a
        layout whose obstacles overlap the robot's fixed base (every pose would collide)."""
        delta = self.check_scene(scene)
        delta.setflags(write=False)
        key = (delta.tobytes(), name)

        def build() -> "Robot":
            self._check_base_clear(delta)
            edit = PinnedLayout(tuple(zip(self.scene_joints, (float(v) for v in delta))))
            spec = self._editable("at(scene)")
            edit.add_to(spec)
            robot = self._derived(spec, (edit,), name or self.name)
            robot.layout, robot.family_fingerprint = delta, self.geometry_fingerprint
            return robot

        return self._cached("_layouts", key, build)

    def _cached(self, cache: str, key, build) -> "Robot":
        """``build()``'s robot, kept in ``self.<cache>`` under ``key`` (the 4 latest): derived
        scenes cost a MuJoCo compile; pickles and deep copies leave the caches out."""
        memo = self.__dict__.setdefault(cache, {})
        if key not in memo:
            robot = build()
            if len(memo) >= 4:
                memo.pop(next(iter(memo)))
            memo[key] = robot
        return memo[key]

    def with_margin(self, margin: float) -> "Robot":
        """This scene with a safety margin of ``margin`` metres around every obstacle
        (:mod:`profrobot.margin`: what it guarantees and assumes): a robot–obstacle pair is in
        contact, for the labeller and MuJoCo alike, when it is less than ``margin`` apart, so a
        pose or motion certified on the result keeps ``margin`` from every obstacle. Self pairs
        are unchanged. ``margin`` at most :data:`CLEARANCE` (the certification's own clearance)
        returns this robot; the result is cached (one per margin).

        The result keeps ``layout``, ``family_fingerprint`` and :attr:`geometry_fingerprint`
        (so a field trained on this robot still guides it); its :attr:`fingerprint` differs
        (its labels do)."""
        m = check_margin(margin)
        if m <= max(CLEARANCE, self.margin):
            return self

        def build() -> "Robot":
            edit = ObstacleMargin(m)
            spec = self._editable("with_margin")
            edit.add_to(spec)
            robot = self._derived(spec, (edit,), self.name)
            robot.margin = m
            if self.cloud is not None:  # its balls get the margin too
                robot = robot.with_points(self.cloud)
            robot.geometry_fingerprint = self.geometry_fingerprint
            robot.layout, robot.family_fingerprint = self.layout, self.family_fingerprint
            return robot

        return self._cached("_margins", m, build)

    def _check_base_clear(self, delta: np.ndarray) -> None:
        """Refuse a layout whose scene bodies touch, or come within :data:`CLEARANCE` of, a body
        fixed to the world (the robot's base, a static body). Those pairs do not depend on θ:
        on the family every pose would fail certification, while pinned, MuJoCo filters them
        (welded together), so the layout could not certify like the family (issue 33: an
        obstacle 0.5 µm from the base was accepted, then certified on one and not the other)."""
        m = self.mj_model
        d = mujoco.MjData(m)
        d.qpos[self.qpos_adr] = self.joint_limits.mean(1)
        d.qpos[self.qpos_adr[self.scene_index]] = delta
        mujoco.mj_kinematics(m, d)
        weld, gbody = self._arrays["body_weld"], dict(zip(self._arrays["geom_id"], self._arrays["geom_body"]))
        gbody[CLOUD_GEOM_ID] = 0  # the point cloud: on the world
        scene_welds = {int(self._arrays["jnt_body"][j]) for j in self.scene_index}
        for k, (g1, g2) in enumerate(self.pair_geoms):
            b1, b2 = int(gbody[int(g1)]), int(gbody[int(g2)])
            for a, b in ((b1, b2), (b2, b1)):
                if int(weld[a]) in scene_welds and int(weld[b]) == 0 and CLOUD_GEOM_ID not in (g1, g2):
                    need = max(float(self.pair_margin[k]), CLEARANCE)
                    dist = mujoco.mj_geomDistance(m, d, int(g1), int(g2), 10 * need + 1e-3, None)
                    if dist <= need:
                        what = "overlaps" if dist <= 0 else f"is {dist:.3g} m from"
                        raise InputError(f"at this layout the obstacle body {self.body_names[a]!r} {what} "
                                         f"{self.body_names[b]!r}, which is fixed to the world (the robot's base or a "
                                         f"static body): every pose would collide or, within the certification's "
                                         f"clearance ({need:g} m), fail certification; choose another layout")

    # ---- description ---------------------------------------------------------------------------
    @property
    def njoint(self) -> int:
        return len(self.joint_names)

    @property
    def joint_limits(self) -> np.ndarray:
        """(K, 2) joint ranges in radians / metres; continuous hinges report [-pi, pi]."""
        return self.core.sampling_ranges()

    def project(self, poses) -> np.ndarray:
        """A copy of ``poses`` ((B, K) or (K,), radians / metres) with every dependent joint of a
        joint equality (the Panda's second finger, a URDF mimic joint, a polynomial coupling)
        recomputed from its independent joint: the pose the mechanism is in."""
        q = np.array(poses, dtype=np.float64, copy=True)
        one = q.ndim == 1
        q2 = np.atleast_2d(q)
        if q2.ndim != 2 or q2.shape[1] != self.njoint:
            raise InputError(f"poses must have shape (B, {self.njoint}) for {self.name}; got {np.shape(poses)}")
        self.couplings.apply(q2)
        return q2[0] if one else q2

    def feasible(self, poses, atol: float = 1e-9) -> np.ndarray:
        """(B,) bool: whether each pose ((B, K) or (K,)) is one the robot can take: every limited
        joint within its limits and every joint equality met, both to ``atol`` (rad / m). The
        core's certification refuses any other pose."""
        q = np.atleast_2d(np.asarray(poses, dtype=np.float64))
        if q.ndim != 2 or q.shape[1] != self.njoint:
            raise InputError(f"poses must have shape (B, {self.njoint}) for {self.name}; got {np.shape(poses)}")
        lim, limited = self.joint_limits, ~self.continuous
        inside = ~(((q < lim[:, 0] - atol) | (q > lim[:, 1] + atol)) & limited).any(axis=1)
        return inside & (self.couplings.residual(q) <= atol)

    @property
    def mj_model(self) -> mujoco.MjModel:
        """The compiled MuJoCo model (an unpickled robot compiles it again on first use)."""
        if self._mj_model is None:
            self._restore()
        return self._mj_model

    @property
    def spec(self) -> mujoco.MjSpec | None:
        """The editable ``mujoco.MjSpec`` (None for :meth:`from_model`; an unpickled robot rebuilds
        it on first use)."""
        if self._spec is None and self._source is not None:
            self._restore()
        return self._spec

    def _joint_parents(self) -> list[int]:
        """Index of each joint's kinematic parent joint (-1 for roots): the previous joint on the
        same body, else the last joint of the nearest ancestor body that has one."""
        m = self.mj_model
        last_joint_of_body = {}
        for j in range(m.njnt):
            last_joint_of_body[int(m.jnt_bodyid[j])] = j
        parents = []
        for j in range(m.njnt):
            b = int(m.jnt_bodyid[j])
            if j > 0 and int(m.jnt_bodyid[j - 1]) == b:
                parents.append(j - 1)
                continue
            p, parent = int(m.body_parentid[b]), -1
            while p != 0:
                if p in last_joint_of_body:
                    parent = last_joint_of_body[p]
                    break
                p = int(m.body_parentid[p])
            parents.append(parent)
        return parents

    def geom_table(self) -> list[dict]:
        """One dict per collidable geom: MuJoCo id, name, type, body, and whether it is robot."""
        m = self.mj_model
        out = []
        for g in self._arrays["geom_id"]:
            b = int(m.geom_bodyid[g])
            out.append(dict(id=int(g), name=_name(m, mujoco.mjtObj.mjOBJ_GEOM, g, "geom"),
                            type=_GEOM_NAMES.get(int(m.geom_type[g]), str(m.geom_type[g])),
                            body=self.body_names[b]))
        if self.cloud is not None and len(self.cloud):
            out.append(dict(id=CLOUD_GEOM_ID, name="point cloud", type="cloud", body=self.body_names[0]))
        return out

    def pair_names(self, k: int) -> tuple[str, str]:
        m = self.mj_model
        name = lambda g: "point cloud" if g == CLOUD_GEOM_ID else _name(m, mujoco.mjtObj.mjOBJ_GEOM, g, "geom")
        g1, g2 = self.pair_geoms[k]
        return name(int(g1)), name(int(g2))

    def __repr__(self) -> str:
        return (f"Robot({self.name!r}, joints={self.njoint}, collision geoms={self.core.ngeom}, "
                f"candidate pairs={self.core.npair})")

    # ---- the flat arrays -----------------------------------------------------------------------
    def core_arrays(self) -> dict[str, np.ndarray]:
        """A copy of the flat arrays handed to the Rust core (also the JSON schema of ModelDesc)."""
        return {k: (np.array(v) if isinstance(v, np.ndarray) else v) for k, v in self._arrays.items()}

    # ---- pickling and copies -------------------------------------------------------------------
    def __getstate__(self) -> dict:
        """What a pickle of a Robot carries (format ``profrobot.Robot/1``), a dict of:

        - ``format``: ``"profrobot.Robot/1"`` (another is refused with ``CorruptFileError``);
        - what labelling needs, as built: ``core`` (the Rust ``RobotModel``, whose own pickle keeps
          every float to the bit), the flat arrays ``_arrays``, ``fingerprint``, ``name``, joint
          and body names, ``joint_types``, ``qpos_adr``, ``continuous``, ``joint_parents``,
          ``equalities``, ``tendons``, ``couplings``, ``pair_geoms``, ``pair_is_self``,
          ``pair_margin``: an unpickled robot labels at once, byte for byte like this one;
        - ``source``: how to rebuild the editable ``MjSpec`` (``MjSpec`` does not pickle, and its
          ``to_xml`` keeps 6 significant digits): the MJCF text, its included files and every
          mesh / texture file it reads, zlib-compressed, plus the obstacles added since, in order;
          None for :meth:`from_model`. Files are read once, at the first pickle, and then kept;
        - ``mj_model``: the compiled ``MjModel`` as MuJoCo's own pickle state (its binary model,
          bytes: any pickle protocol; MuJoCo's pickling aborts the process under protocols 0 and 1)
          only where the source cannot rebuild it exactly (``from_model``, ``from_spec``); for
          ``from_mjcf`` / ``from_menagerie`` / ``from_urdf`` robots (a URDF's source is its text with
          mesh names made asset names, the mesh bytes, the mimic equalities and ``<exclude>``s
          added) it is left out (the meshes are already in the
          source: half the size) and compiled again on first use of :attr:`mj_model` or
          :attr:`spec`.

        Whatever is rebuilt is checked: the rebuilt model must have this robot's fingerprint, else
        :class:`~profrobot.errors.RobotMismatchError` (e.g. a ``from_spec`` spec that its XML
        does not reproduce, or a spec edited after the robot was built). A Panda scene pickles to
        about 6 MB (the meshes' files, compressed).
        """
        state = {k: v for k, v in self.__dict__.items()
                 if k not in ("_mj_model", "_spec", "_source") + _CACHES}
        source = self._source
        if source is not None and not isinstance(source.root, _Mjcf):
            try:
                source = self._source = source.loaded()  # read once, kept for later pickles
            except Exception as e:  # a file gone, unreadable, a spec to_xml refuses
                source = None
                state["_spec_lost"] = f"{type(e).__name__}: {e}"
        model = self._mj_model
        if model is None and (source is None or not source.root.exact):
            model = self.mj_model  # never the case for robots built here; compiled to be safe
        state["format"] = _STATE_FORMAT
        state["source"] = source
        state["mj_model"] = None if source is not None and source.root.exact else model.__getstate__()
        return state

    def __setstate__(self, state: dict) -> None:
        state = dict(state)
        fmt = state.pop("format", None)
        if fmt != _STATE_FORMAT:
            raise CorruptFileError(f"not a pickled profrobot Robot of format {_STATE_FORMAT!r} (got {fmt!r}); "
                                   "it was written by another profrobot version")
        model, source = state.pop("mj_model"), state.pop("source")
        if model is not None:
            data, model = model, mujoco.MjModel.__new__(mujoco.MjModel)
            model.__setstate__(data)
        self.__dict__.update(state)
        self._mj_model, self._spec, self._source = model, None, source

    def __copy__(self) -> "Robot":
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        return new

    def __deepcopy__(self, memo: dict) -> "Robot":
        """An independent robot equal to a pickled copy: the same labels, fingerprint and name,
        a copy of the MuJoCo model and of the editable spec (``MjSpec.copy``)."""
        new = object.__new__(type(self))
        memo[id(self)] = new
        for key, value in self.__dict__.items():
            if key in _CACHES:  # built again on first use
                continue
            if key == "_spec":
                value = None if value is None else value.copy()
            elif key != "_source":  # immutable; its root may be an MjSpec, which deepcopy cannot copy
                value = copy.deepcopy(value, memo)
            new.__dict__[key] = value
        return new

    def _restore(self) -> None:
        """Rebuild the MjSpec (and the MjModel, if the pickle left it out) from the source, and
        check that it compiles to this very robot."""
        try:
            spec = self._source.spec()
            model = spec.compile()
        except Exception as e:
            raise CorruptFileError(f"{self.name}: could not rebuild the MuJoCo model from the MJCF this robot "
                                   f"carries: {type(e).__name__}: {e}") from e
        names = [_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint") for j in range(model.njnt)]
        arrays = _core_arrays(model)
        if self.cloud is not None and len(self.cloud):
            arrays.update(self.cloud.core_arrays(self.margin))
        if _fingerprint(names, arrays, tuple(n for n in names if n in model_scene_joints(model))) != self.fingerprint:
            how = ("its MjSpec, written out with MjSpec.to_xml (6 significant digits), compiles to another robot"
                   if not self._source.loaded().root.exact else
                   "the MJCF files it was built from now compile to another robot (edited since, another MuJoCo "
                   "version, or its spec was edited after the robot was built)")
            raise RobotMismatchError(f"{self.name}: cannot rebuild the MuJoCo model of this robot: {how}. "
                                     "Labelling is unaffected; rebuild the robot itself for obstacles.")
        self._spec = spec
        if self._mj_model is None:
            self._mj_model = model
