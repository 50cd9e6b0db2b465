"""A robot scene: a compiled MuJoCo model, its joints, and its collision geometry as the flat
arrays the Rust core (`profrobot._core.RobotModel`) labels with.

One description feeds every back end: the arrays below are copied from MuJoCo's *compiled*
model (``mjModel``), never re-parsed from XML, so bodies, hulls and filters are MuJoCo's own.
"""

from __future__ import annotations

import abc
import hashlib
import os
import warnings
from dataclasses import dataclass, field
from collections.abc import Sequence

import mujoco
import numpy as np

from . import _core
from .equalities import EqualityWarning, JointCouplings, read_equalities, read_tendons, unenforced_summary
from .errors import InputError

_FREE, _BALL, _SLIDE, _HINGE = (int(t) for t in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL,
                                                  mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_HINGE))
_GEOM_NAMES = {int(getattr(mujoco.mjtGeom, n)): n.removeprefix("mjGEOM_").lower() for n in dir(mujoco.mjtGeom) if n.startswith("mjGEOM_") and int(getattr(mujoco.mjtGeom, n)) < 9}


# --------------------------------------------------------------------------------------------
# Obstacles for a robot's static scene (added to its MjSpec, then recompiled)
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Obstacle(abc.ABC):
    """A static geom fixed to the world. Positions in metres, quaternions (w, x, y, z)."""

    pos: Sequence[float]
    quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)
    name: str | None = None
    rgba: Sequence[float] = (0.6, 0.6, 0.65, 1.0)

    @abc.abstractmethod
    def _geom_args(self, spec: mujoco.MjSpec) -> dict:
        """The geom's MuJoCo type and size (and any asset it needs, added to ``spec``)."""

    def add_to(self, spec: mujoco.MjSpec) -> None:
        pos = np.asarray(self.pos, dtype=float)
        quat = np.asarray(self.quat, dtype=float)
        if pos.shape != (3,) or quat.shape != (4,) or not (np.isfinite(pos).all() and np.isfinite(quat).all()):
            raise InputError(f"{type(self).__name__} {self.name!r}: pos must be 3 finite numbers and quat 4")
        if not np.linalg.norm(quat) > 0:
            raise InputError(f"{type(self).__name__} {self.name!r}: quat is zero")
        kwargs = dict(pos=pos, quat=quat / np.linalg.norm(quat), rgba=np.asarray(self.rgba, dtype=float),
                      **self._geom_args(spec))
        if self.name:
            kwargs["name"] = self.name
        spec.worldbody.add_geom(**kwargs)


def _positive(owner: str, **values: float) -> list[float]:
    out = []
    for key, v in values.items():
        v = float(v)
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{owner}: {key} must be a positive length in metres; got {v}")
        out.append(v)
    return out


@dataclass(frozen=True)
class Box(Obstacle):
    """A box of half extents ``half_size`` (metres)."""

    half_size: Sequence[float] = (0.1, 0.1, 0.1)

    def _geom_args(self, spec):
        hx, hy, hz = _positive(f"Box {self.name!r}", x=self.half_size[0], y=self.half_size[1], z=self.half_size[2])
        return dict(type=mujoco.mjtGeom.mjGEOM_BOX, size=[hx, hy, hz])


@dataclass(frozen=True)
class Sphere(Obstacle):
    radius: float = 0.1

    def _geom_args(self, spec):
        (r,) = _positive(f"Sphere {self.name!r}", radius=self.radius)
        return dict(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[r, 0, 0])


@dataclass(frozen=True)
class Capsule(Obstacle):
    """A capsule along its local z axis: ``radius`` and ``half_length`` of the segment."""

    radius: float = 0.05
    half_length: float = 0.1

    def _geom_args(self, spec):
        r, h = _positive(f"Capsule {self.name!r}", radius=self.radius, half_length=self.half_length)
        return dict(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[r, h, 0])


@dataclass(frozen=True)
class Cylinder(Obstacle):
    """A cylinder along its local z axis."""

    radius: float = 0.05
    half_length: float = 0.1

    def _geom_args(self, spec):
        r, h = _positive(f"Cylinder {self.name!r}", radius=self.radius, half_length=self.half_length)
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
            raise InputError(f"Mesh {self.name!r}: vertices must be a finite (N >= 4, 3) array; got shape {v.shape}")
        mesh_name = f"{self.name or 'obstacle'}_mesh_{len(spec.meshes)}"
        spec.add_mesh(name=mesh_name, uservert=v.ravel())
        return dict(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh_name)


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


class Robot:
    """A MuJoCo robot scene ready for exact collision labelling.

    The pose vector ``theta`` (K,) covers every joint in MuJoCo joint order (hinges in radians,
    slides in metres); free and ball joints are rejected. Static obstacles are the world-body
    geoms of the model (and those added with :meth:`with_obstacles`).

    Build one with :meth:`from_menagerie`, :meth:`from_mjcf`, :meth:`from_model`, or
    ``profrobot.scenes.load(name)``.
    """

    def __init__(self, model: mujoco.MjModel, *, name: str = "robot", spec: mujoco.MjSpec | None = None):
        if not isinstance(model, mujoco.MjModel):
            raise TypeError(f"Robot needs a mujoco.MjModel; got {type(model).__name__}")
        self.mj_model = model
        self.name = name
        self._spec = spec
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
        self._arrays = self._core_arrays()
        self.core = _core.RobotModel(self._arrays)
        self.pair_geoms, self.pair_is_self, self.pair_margin = self.core.pairs()
        self.fingerprint = self._fingerprint()

    # ---- constructors ------------------------------------------------------------------------
    @classmethod
    def from_menagerie(cls, name: str, entry: str | None = None) -> "Robot":
        """A MuJoCo Menagerie model by name (``entry``: an entry point; None: the default scene).

        Uses the ``mujoco_menagerie`` package (which honours ``MENAGERIE_ROOT`` for local copies).
        """
        import mujoco_menagerie as mm

        try:
            spec = mm.get(name).spec(entry)
        except mm.UnknownRobotError as e:
            raise InputError(f"unknown Menagerie robot {name!r}; known: {', '.join(mm.names())}") from e
        except mm.UnknownEntryPointError as e:
            raise InputError(str(e)) from e
        return cls.from_spec(spec, name=name if entry is None else f"{name}/{entry}")

    @classmethod
    def from_mjcf(cls, path: str | os.PathLike) -> "Robot":
        """An MJCF file on disk (its meshes resolved relative to it)."""
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"no MJCF file at {path!r}")
        try:
            spec = mujoco.MjSpec.from_file(path)
        except Exception as e:  # mujoco raises ValueError with the parser's message
            raise InputError(f"could not read MJCF {path!r}: {e}") from e
        return cls.from_spec(spec, name=os.path.splitext(os.path.basename(path))[0])

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
        """A new Robot: this scene plus static ``obstacles`` (Box, Sphere, Capsule, Cylinder,
        Plane, Mesh) fixed to the world. The original is left unchanged."""
        if self._spec is None:
            raise InputError(f"{self.name}: obstacles need the MjSpec; build the robot with from_menagerie, "
                             "from_mjcf or from_spec rather than from_model")
        spec = self._spec.copy()
        for ob in obstacles:
            if not isinstance(ob, Obstacle):
                raise TypeError(f"obstacles must be profrobot Obstacle objects; got {type(ob).__name__}")
            ob.add_to(spec)
        return Robot.from_spec(spec, name=name or self.name)

    # ---- description ---------------------------------------------------------------------------
    @property
    def njoint(self) -> int:
        return len(self.joint_names)

    @property
    def joint_limits(self) -> np.ndarray:
        """(K, 2) joint ranges in radians / metres; continuous hinges report [-pi, pi]."""
        return self.core.sampling_ranges()

    @property
    def spec(self) -> mujoco.MjSpec | None:
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
        return out

    def pair_names(self, k: int) -> tuple[str, str]:
        m = self.mj_model
        g1, g2 = self.pair_geoms[k]
        return (_name(m, mujoco.mjtObj.mjOBJ_GEOM, g1, "geom"), _name(m, mujoco.mjtObj.mjOBJ_GEOM, g2, "geom"))

    def __repr__(self) -> str:
        return (f"Robot({self.name!r}, joints={self.njoint}, collision geoms={self.core.ngeom}, "
                f"candidate pairs={self.core.npair})")

    # ---- the flat arrays -----------------------------------------------------------------------
    def _core_arrays(self) -> dict[str, np.ndarray]:
        m = self.mj_model
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

    def _fingerprint(self) -> str:
        """sha256 of everything that decides labels: joints, bodies, geoms, hulls, filters."""
        h = hashlib.sha256()
        h.update("\0".join(self.joint_names).encode())
        for key in sorted(self._arrays):
            v = np.asarray(self._arrays[key])
            h.update(key.encode())
            h.update(np.ascontiguousarray(np.round(v, 12) if v.dtype.kind == "f" else v).tobytes())
        return h.hexdigest()[:32]

    def core_arrays(self) -> dict[str, np.ndarray]:
        """A copy of the flat arrays handed to the Rust core (also the JSON schema of ModelDesc)."""
        return {k: (np.array(v) if isinstance(v, np.ndarray) else v) for k, v in self._arrays.items()}
