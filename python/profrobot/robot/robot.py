"""A robot scene: a compiled MuJoCo model, its joints, and its collision geometry as the flat
arrays the Rust core (`profrobot._core.RobotModel`) labels with.

One description feeds every back end: the arrays are copied from MuJoCo's *compiled* model
(``mjModel``, :mod:`profrobot.robot.arrays`), never re-parsed from XML, so bodies, hulls and
filters are MuJoCo's own.

:class:`Robot` is built here from its seams: its constructors and collision report
(:mod:`profrobot.robot.loading`), scene joints, layouts and margins (:mod:`profrobot.robot.layouts`),
pickling and copies (:mod:`profrobot.robot.state`); what stays here is the scene itself, its
obstacles and point cloud, and its joints. A Robot pickles (multiprocessing, DataLoader workers,
Ray, ``torch.save``) and deep-copies; see :meth:`Robot.__getstate__` for what a pickle carries.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import mujoco
import numpy as np
import numpy.typing as npt

from .._core import RobotModel
from .family import Layout
from .equalities import EqualityWarning, JointCouplings, read_equalities, read_tendons, unenforced_summary
from ..errors import InputError, InputTypeError
from . import layouts as _layouts
from . import loading as _loading
from . import file as _file
from . import grasp as _grasp
from . import state as _state
from . import world as _world
from .arrays import BALL, FREE, GEOM_NAMES, HINGE, SLIDE, label_fingerprint, model_arrays, object_name
from .margin import ObstacleMargin
from .obstacles import Obstacle, apply_edit
from .pointcloud import CLOUD_GEOM_ID, PointCloud
from .sources import _SpecSource


#: coupling warnings already given in this process (one per set of couplings)
_WARNED: set[str] = set()


class Robot:
    """A MuJoCo robot scene ready for exact collision labelling.

    The pose vector ``theta`` (K,) covers every joint in MuJoCo joint order (hinges in radians,
    slides in metres); free and ball joints are rejected. Static obstacles are the world-body
    geoms of the model (and those added with :meth:`with_obstacles`).

    A *family of scenes* (:mod:`profrobot.robot.family`) also has scene joints, the joints that move
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
    #: the joints that move obstacles (a family of scenes, :mod:`profrobot.robot.family`); () otherwise
    scene_joints: tuple = ()
    #: for a layout made by :meth:`at`: the family's scene-joint values (D,) and fingerprint
    layout: np.ndarray | None = None
    family_fingerprint: str | None = None
    #: metres: the safety margin every obstacle geom has at least (:meth:`with_margin`); 0 for the
    #: model's own margins
    margin: float = 0.0
    #: the point-cloud obstacle (:meth:`with_points`, :mod:`profrobot.robot.pointcloud`), or None
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
        bad = [(object_name(m, mujoco.mjtObj.mjOBJ_JOINT, j, "joint"), int(t)) for j, t in enumerate(m.jnt_type)
               if t not in (HINGE, SLIDE)]
        if bad:
            kinds = {FREE: "free", BALL: "ball"}
            desc = ", ".join(f"{n!r} ({kinds.get(t, t)})" for n, t in bad)
            raise InputError(f"{name}: only hinge and slide joints are supported; found {desc}. "
                             "Remove free-floating objects and ball joints from the scene.")
        if m.njnt == 0:
            raise InputError(f"{name}: the model has no joints, so there is no pose to label")
        # MuJoCo's autolimits reads a range whose two ends are equal as no range at all: the joint
        # would move freely where its author meant it held (0 0 is MuJoCo's "no range" itself)
        pinned = [j for j in range(m.njnt) if not m.jnt_limited[j] and m.jnt_range[j, 0] == m.jnt_range[j, 1] != 0]
        if pinned:
            desc = ", ".join(f"{object_name(m, mujoco.mjtObj.mjOBJ_JOINT, j, 'joint')!r} [{m.jnt_range[j, 0]:g}, "
                             f"{m.jnt_range[j, 1]:g}]" for j in pinned)
            raise InputError(f"{name}: joint range with equal ends: {desc}. MuJoCo reads such a range as none (the "
                             "joint would move without limit); give the joint a range lo < hi, or remove it (a fixed "
                             "body), and hold joints where they are with ik(..., locked=[...]) / plan_path(..., locked=[...])")

        self.joint_names: list[str] = [object_name(m, mujoco.mjtObj.mjOBJ_JOINT, j, "joint") for j in range(m.njnt)]
        self.joint_types: list[str] = ["hinge" if t == HINGE else "slide" for t in m.jnt_type]
        self.qpos_adr = np.asarray(m.jnt_qposadr, dtype=np.int64)
        self.continuous = (m.jnt_type == HINGE) & (m.jnt_limited == 0)
        self.joint_parents = self._joint_parents()
        self.body_names: list[str] = [object_name(m, mujoco.mjtObj.mjOBJ_BODY, b, "body") for b in range(m.nbody)]
        self.equalities = read_equalities(m)
        self.tendons = read_tendons(m)
        self.couplings = JointCouplings(m, self.joint_names)
        loose = unenforced_summary(self.equalities, self.tendons)
        if loose and loose not in _WARNED:  # once per process for the same couplings
            _WARNED.add(loose)
            warnings.warn(f"{name}: uniform sampling leaves these couplings free: {loose}. "
                          "sample_poses(..., equalities='settle') projects poses onto them "
                          "(robot.equalities lists every equality).", EqualityWarning, stacklevel=3)
        self._arrays = model_arrays(m)
        self._arrays.update(self.couplings.arrays())  # the core keeps planned and searched poses on them
        self.scene_joints = _layouts.read_scene_joints(self, m)
        if self.scene_joints:  # the labeller counts robot–obstacle contacts as scene contacts
            self._arrays["jnt_scene"] = np.array([n in self.scene_joints for n in self.joint_names])
        self.core = RobotModel(self._arrays)
        self.pair_geoms, self.pair_is_self, self.pair_margin = self.core.pairs()
        self.fingerprint = label_fingerprint(self.joint_names, self._arrays, self.scene_joints)
        #: the fingerprint of the robot before any safety margin (:meth:`with_margin`): the geometry
        #: a field, views or Gaussians were made for. Labels follow :attr:`fingerprint`.
        self.geometry_fingerprint = self.fingerprint
        self.layout = None
        self.family_fingerprint = None

    # ---- constructors and the collision report (robot/loading.py) -------------------------------
    @classmethod
    def from_menagerie(cls, name: str, entry: str | None = None) -> "Robot":
        """A MuJoCo Menagerie model by name (``entry``: an entry point; None: the default scene).

        Uses the ``mujoco_menagerie`` package (which honours ``MENAGERIE_ROOT`` for local copies).
        """
        return _loading.from_menagerie(cls, name, entry)

    @classmethod
    def from_mjcf(cls, path: str | os.PathLike, *, srdf: str | os.PathLike | None = None,
                  collision_matrix: str | None = None) -> "Robot":
        """An MJCF file on disk (its meshes resolved relative to it); a URDF (``.urdf``, or a
        ``<robot>`` root) goes to :meth:`from_urdf` with these options.

        Collisions as :meth:`from_urdf`: the model's own pairs by default, with a
        :class:`profrobot.robot.urdf.CollisionWarning` naming the body pairs that collide in >= 99 % of
        2000 seeded uniform poses (a base overlapping the shoulder makes every pose "collide");
        ``srdf=`` disables a MoveIt SRDF's ``<disable_collisions>`` pairs, ``collision_matrix=
        "auto"`` the always-colliding pairs and the adjacent ones that ever touch (never a pair
        with the world). Disabled pairs become MuJoCo ``<exclude>``s on the spec, so the
        cross-check still compares like with like; ``robot.disabled_pairs`` and
        ``robot.collision_report()`` say which and why."""
        return _loading.from_mjcf(cls, path, srdf=srdf, collision_matrix=collision_matrix)

    @classmethod
    def from_urdf(cls, path: str | os.PathLike, *,
                  package_dirs: Mapping[str, str | os.PathLike[str]] | str | os.PathLike[str]
                  | Iterable[str | os.PathLike[str]] | None = None, srdf: str | os.PathLike | None = None,
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
        about (:class:`profrobot.robot.urdf.UrdfWarning`), typically a base link overlapping link 1 (a
        link welded to the world is not filtered against its child). ``srdf=``: a MoveIt SRDF
        whose ``<disable_collisions>`` pairs are disabled. ``collision_matrix="auto"``: disable
        the pairs that collide in >= 99 % of those poses and the adjacent pairs (one moving joint
        apart, fixed joints collapsed) that collide in any; nothing else. Disabled pairs are MuJoCo
        ``<exclude>``s on the spec, so :func:`profrobot.crosscheck` still compares like with like;
        ``robot.disabled_pairs`` lists them and ``robot.collision_report()`` says why.
        """
        return _loading.from_urdf(cls, path, package_dirs=package_dirs, srdf=srdf, collision_matrix=collision_matrix, name=name)

    def collision_report(self) -> str:
        """What profrobot disabled among this robot's collision pairs, and why (``from_urdf``);
        for other robots, that MuJoCo's filters and the model's own ``<exclude>``s apply."""
        return _loading.collision_report(self)

    @classmethod
    def from_spec(cls, spec: mujoco.MjSpec, *, name: str = "robot") -> "Robot":
        """An editable ``mujoco.MjSpec`` (kept, so that obstacles can be added later)."""
        return _loading.from_spec(cls, spec, name=name)

    @classmethod
    def from_model(cls, model: mujoco.MjModel, *, name: str = "robot") -> "Robot":
        """An already compiled ``mujoco.MjModel`` (obstacles cannot be added to it afterwards)."""
        return _loading.from_model(cls, model, name=name)

    # ---- families of scenes, layouts and margins (robot/family.py) ------------------------------
    def with_scene_joints(self, names: Sequence[str], *, name: str | None = None) -> "Robot":
        """A family of scenes from this model: its joints ``names`` (each with a finite range) become
        scene joints δ, the ones that move obstacles; the rest stay the robot's θ. Scene bodies get
        ``<exclude>``s against the world and each other (see :mod:`profrobot.robot.family`)."""
        return _layouts.with_scene_joints(self, names, name=name)

    @property
    def is_family(self) -> bool:
        """Whether some joints are scene joints (a family of scenes, :mod:`profrobot.robot.family`)."""
        return _layouts.is_family(self)

    @property
    def scene_index(self) -> np.ndarray:
        """(D,) indices of the scene joints δ in the pose vector."""
        return _layouts.scene_index(self)

    @property
    def robot_index(self) -> np.ndarray:
        """(K − D,) indices of the robot's own joints θ in the pose vector (all of them for an
        ordinary scene)."""
        return _layouts.robot_index(self)

    def check_layout(self, layout: Layout, *, name: str = "layout") -> np.ndarray:
        """A layout δ as a float64 array (D,): one value per scene joint (radians / metres, in
        ``scene_joints`` order), finite and within the family's ranges, else :class:`InputError`
        naming the entry. A dict ``{joint name: value}`` must name every scene joint."""
        return _layouts.check_layout(self, layout, name=name)

    def compose(self, theta: npt.ArrayLike, layout: Layout) -> np.ndarray:
        """Full pose vectors (N, K) from robot poses θ (N, K − D) and a layout δ (D,) or one per
        pose (N, D): the labeller's view of a family."""
        return _layouts.compose(self, theta, layout)

    def check_layouts(self, layout: Layout, n: int) -> np.ndarray:
        """The layouts of ``n`` poses, each checked by :meth:`check_layout`: (1, D) for one layout
        (D,) or dict shared by all, (n, D) for one layout per pose (rows named ``layout[i]``)."""
        return _layouts.check_layouts(self, layout, n)

    def at(self, layout: Layout, *, name: str | None = None) -> "Robot":
        """The family's scene at layout δ (``layout``: (D,) or ``{scene joint: value}``): an ordinary
        Robot whose scene bodies are pinned there (static obstacles), its pose vector θ the
        robot joints. ``robot.layout`` keeps δ and ``robot.family_fingerprint`` the family's.

        Refused (:class:`InputError`): δ outside the family's ranges, wrong length, NaN, and a
        layout whose obstacles overlap the robot's fixed base (every pose would collide)."""
        return _layouts.at(self, layout, name=name)

    def with_margin(self, margin: float) -> "Robot":
        """This scene with a safety margin of ``margin`` metres around every obstacle
        (:mod:`profrobot.robot.margin`: what it guarantees and assumes): a robot–obstacle pair is in
        contact, for the labeller and MuJoCo alike, when it is less than ``margin`` apart, so a
        pose or motion certified on the result keeps ``margin`` from every obstacle. Self pairs
        are unchanged. ``margin`` at most :data:`CLEARANCE` (the certification's own clearance)
        returns this robot; the result is cached (one per margin).

        The result keeps ``layout``, ``family_fingerprint`` and :attr:`geometry_fingerprint`
        (so a field trained on this robot still guides it); its :attr:`fingerprint` differs
        (its labels do)."""
        return _layouts.with_margin(self, margin)

    # ---- robot files (robot/file.py) -------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write this robot to ``path`` atomically, in one file: its MJCF or URDF text, the meshes'
        bytes, obstacles, cloud, margin and collision matrix (its pickle; a Panda cell is about
        6 MB). :meth:`load` reads it back with the same fingerprint."""
        return _file.write(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Robot":
        """The robot :meth:`save` wrote to ``path`` (or a field directory's ``robot.pkl``), read
        by a restricted unpickler: profrobot's classes and numpy arrays only, so a tampered file
        runs none of its code (:mod:`profrobot.robot.file`). Raises
        :class:`~profrobot.errors.MissingFileError` for no file and
        :class:`~profrobot.errors.CorruptFileError` for anything but a robot file."""
        return _file.read(path, cls)

    # ---- pickles and copies (robot/state.py) ---------------------------------------------------
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
        return _state.getstate(self)

    def __setstate__(self, state: dict) -> None:
        _state.setstate(self, state)

    def __copy__(self) -> "Robot":
        return _state.shallow_copy(self)

    def __deepcopy__(self, memo: dict) -> "Robot":
        """An independent robot equal to a pickled copy: the same labels, fingerprint and name,
        a copy of the MuJoCo model and of the editable spec (``MjSpec.copy``)."""
        return _state.deep_copy(self, memo)

    def with_obstacles(self, obstacles: Sequence[Obstacle], *, name: str | None = None) -> "Robot":
        """A new Robot: this scene plus ``obstacles`` (Box, Sphere, Capsule, Cylinder, Plane, Mesh),
        fixed to the world, or movable within ranges (``moves=Moves(...)``: the result is a family
        of scenes, see :mod:`profrobot.robot.family`). The original is left unchanged."""
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
        # static primitives are written into the core's arrays, MuJoCo compiled on first use
        # (robot/world.py); the rest are edits of the spec, compiled now
        fast = _world.fits(self, obstacles)
        spec = None if fast else self._editable("obstacles")
        taken = set(_world.world_geoms(self).names if spec is None else _world.spec_names(spec))
        for i, ob in enumerate(obstacles):
            if ob.name and ob.name in taken:
                raise InputError(f"obstacles[{i}]: the name {ob.name!r} is taken (by another obstacle or by a geom or "
                                 f"body of {self.name}); names must be unique")
            if ob.name:
                taken.add(ob.name)
            if spec is not None:
                apply_edit(spec, ob, f"obstacles[{i}] ({ob.label})")
        if spec is None:
            return _world.with_primitives(self, obstacles, name or self.name)
        return self._derived(spec, obstacles, name or self.name)

    def attach(self, obstacle: "str | Obstacle", *, to: str, at: npt.ArrayLike | None = None,
               touching: Sequence[str] = ()) -> "Robot":
        """A new Robot holding ``obstacle`` with its body ``to`` (:mod:`profrobot.robot.grasp`):
        the name of a fixed geom of the world, taken where it is when the robot is at pose ``at``
        ((K,), the grasp), or a new named :class:`Obstacle` whose ``pos`` / ``quat`` are in
        ``to``'s frame. The object moves with ``to`` and is checked against the world and the
        robot's other bodies; it may touch ``to``, the bodies whose parent is ``to`` (MuJoCo's
        rules: a hand's fingers) and the bodies named in ``touching``. The labeller, the
        certificates, the planner, IK and pickles see it; the original is left unchanged."""
        return _grasp.attach(self, obstacle, to=to, at=at, touching=touching)

    def detach(self, name: str, *, at: npt.ArrayLike) -> "Robot":
        """A new Robot that has let go of the held object ``name``: it stays in the world where
        the robot holds it at pose ``at`` ((K,), the place), a fixed obstacle again."""
        return _grasp.detach(self, name, at=at)

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

    # ---- point clouds (profrobot.robot.pointcloud) ---------------------------------------------------
    def with_points(self, points: PointCloud | npt.ArrayLike | None, radius: npt.ArrayLike | None = None) -> "Robot":
        """This scene with the point-cloud obstacle ``points``: a :class:`~profrobot.PointCloud`, or
        an (N, 3) array of world points in metres with ``radius`` (metres: one number, the sensor's
        resolution, or one per point; default 0.005). It **replaces** this robot's cloud, if any
        (``with_obstacles([cloud])`` adds to it); ``None`` or an empty cloud removes it.

        Cheap enough to call per camera frame: the MuJoCo model and the geoms' hulls are shared,
        only the cloud's tree and the candidate pairs are built (``rust/geometry/cloud.rs``). The balls get
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
        arrays = {k: v for k, v in self._arrays.items() if not k.startswith("cloud_")}
        if cloud is not None and len(cloud):
            arrays.update(cloud.core_arrays(self.margin))
            core = self.core.with_cloud(arrays["cloud_points"], arrays["cloud_radius"], self.margin)
        else:
            core = self.core.with_cloud(None, None)
        new = _state.with_core(self, arrays, core, keep=("_spec_from",))   # (the cloud is not in the spec)
        new.cloud = cloud
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

    # ---- description ---------------------------------------------------------------------------
    @property
    def njoint(self) -> int:
        return len(self.joint_names)

    @property
    def body_parents(self) -> np.ndarray:
        """(nbody,) int32: each body's parent body id, in MuJoCo's body order (the world's, 0, is
        its own); :attr:`body_names` names them."""
        return self._arrays["body_parent"].copy()

    @property
    def joint_bodies(self) -> np.ndarray:
        """(K,) int32: the body each joint moves (an id into :attr:`body_names`)."""
        return self._arrays["jnt_body"].copy()

    @property
    def joint_anchors(self) -> np.ndarray:
        """(K, 3) float64: each joint's anchor in its body's frame, metres (MuJoCo's ``jnt_pos``)."""
        return self._arrays["jnt_pos"].copy()

    @property
    def body_offsets(self) -> np.ndarray:
        """(nbody, 3) float64: each body's origin in its parent's frame, metres (MuJoCo's
        ``body_pos``; the world's is zero)."""
        return self._arrays["body_pos"].copy()

    @property
    def joint_limits(self) -> np.ndarray:
        """(K, 2) joint ranges in radians / metres; continuous hinges report [-pi, pi]."""
        return self.core.sampling_ranges()

    def project(self, poses: npt.ArrayLike) -> np.ndarray:
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

    def feasible(self, poses: npt.ArrayLike, atol: float = 1e-9) -> np.ndarray:
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
            _state.restore(self)
        return self._mj_model

    @property
    def spec(self) -> mujoco.MjSpec | None:
        """The editable ``mujoco.MjSpec`` (None for :meth:`from_model`; an unpickled robot rebuilds
        it on first use)."""
        if self._spec is None and self._source is not None:
            _state.restore(self)
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
            out.append(dict(id=int(g), name=object_name(m, mujoco.mjtObj.mjOBJ_GEOM, g, "geom"),
                            type=GEOM_NAMES.get(int(m.geom_type[g]), str(m.geom_type[g])),
                            body=self.body_names[b]))
        if self.cloud is not None and len(self.cloud):
            out.append(dict(id=CLOUD_GEOM_ID, name="point cloud", type="cloud", body=self.body_names[0]))
        return out

    def pair_names(self, k: int) -> tuple[str, str]:
        m = self.mj_model
        name = lambda g: "point cloud" if g == CLOUD_GEOM_ID else object_name(m, mujoco.mjtObj.mjOBJ_GEOM, g, "geom")
        g1, g2 = self.pair_geoms[k]
        return name(int(g1)), name(int(g2))

    def __repr__(self) -> str:
        return (f"Robot({self.name!r}, joints={self.njoint}, collision geoms={self.core.ngeom}, "
                f"candidate pairs={self.core.npair})")

    # ---- the flat arrays -----------------------------------------------------------------------
    def core_arrays(self) -> dict[str, np.ndarray]:
        """A copy of the flat arrays handed to the Rust core (also the JSON schema of ModelDesc)."""
        return {k: (np.array(v) if isinstance(v, np.ndarray) else v) for k, v in self._arrays.items()}
