"""A live 3-D view in the browser, on viser: the robot's collision geometry at a pose, its
obstacles (a family at a layout), point clouds, camera frusta and their images, paths animated
with every segment coloured by its certificate, a field slice, and the exact verdict, updated as
joint sliders or a target gizmo (through :func:`profrobot.ik`) move the robot.

What is drawn is what the labeller checks: MuJoCo's collision geoms (``contype`` or
``conaffinity`` set, or named by an explicit ``<pair>``), primitives tessellated and meshes as
MuJoCo stores them, placed by ``mj_kinematics`` at the pose; the robot's geoms in orange, those in
contact in red, obstacles in grey. Colours:

- a pose: the exact labeller's verdict (:func:`profrobot.label_poses` with the colliding pairs,
  and :func:`profrobot.certify_poses` for the clearance), shown in the panel;
- a path: each segment by :func:`profrobot.certify_motions` (:data:`VERDICT_COLOURS`: certified
  green, blocked red, unproven amber), the traced frame drawn through the interpolated poses.

``Viewer(robot)`` starts the server at once (``viewer.url``); ``with Viewer(...) as v:`` stops it
on exit. ``profrobot view`` is the command line.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, cast

import mujoco
import numpy as np
import numpy.typing as npt

from ..exact.certification import certify_motions, certify_poses
from ..errors import BackendUnavailableError, InputError, InputTypeError
from ..exact.ik import IKResult, frame_of, ik
from ..exact.labels import interpolate, label_poses
from ..robot.margin import obstacle_bodies
from ..robot.robot import Robot
from ..exact.timing import TimedPath
from ..robot.gate import Layout, as_poses, positive
from ..robot.pointcloud import PointCloud

if TYPE_CHECKING:   # viser (an optional extra) loads with the first Viewer; the slice with torch
    import viser
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from .slices import SlicedField

__all__ = ["Viewer", "VERDICT_COLOURS", "ROBOT_COLOUR", "CONTACT_COLOUR", "OBSTACLE_COLOUR"]

VERDICT_COLOURS = {"certified": (30, 160, 60), "blocked": (215, 30, 30), "unproven": (235, 165, 0)}
"""RGB (0-255) of a path segment in the viewer by its certificate's verdict."""
ROBOT_COLOUR = (255, 120, 0)
CONTACT_COLOUR = (215, 0, 0)
OBSTACLE_COLOUR = (140, 145, 160)
_PLANE_HALF = 2.0   # metres: an infinite plane is drawn this far out
NOTICE_SECONDS = 5.0
"""How long viser's software-WebGL notice stays over the view before it fades (the panel keeps
a line saying so)."""
# viser's client shows a notice (id "webgl-software-rendering") when the browser draws WebGL in
# software (SwiftShader, llvmpipe: no GPU, a remote desktop); it stays until closed, over the
# view's top-left corner. A stylesheet in the panel fades it after NOTICE_SECONDS and shows the
# same fact as a line in the panel instead, only while the notice exists (CSS ``:has``).
_WEBGL_NOTICE = f"""<style>
#webgl-software-rendering {{ animation: profrobot-notice 0.4s ease-in {NOTICE_SECONDS}s forwards; }}
@keyframes profrobot-notice {{ to {{ opacity: 0; visibility: hidden; }} }}
.profrobot-webgl {{ display: none; font-size: 0.8em; color: #a65200; padding: 0 0.75em 0.4em; }}
body:has(#webgl-software-rendering) .profrobot-webgl {{ display: block; }}
</style><div class="profrobot-webgl">This browser draws WebGL in software (no GPU): the view is
slower; what it shows is the same.</div>"""


class _GeomHandle(Protocol):
    """What the viewer sets on a geom's viser mesh handle."""

    position: np.ndarray
    wxyz: np.ndarray
    color: tuple[int, int, int]
    visible: bool


class CameraSet(Protocol):
    """Calibrated cameras as :meth:`Viewer.show_cameras` draws them: a
    :class:`profrobot.render.Cameras`, or anything with its ``K`` (C, 3, 3), ``world_to_cam``
    (C, 4, 4) OpenCV, ``width`` and ``height`` (pixels)."""

    @property
    def K(self) -> npt.ArrayLike: ...

    @property
    def world_to_cam(self) -> npt.ArrayLike: ...

    @property
    def width(self) -> int: ...

    @property
    def height(self) -> int: ...


def _quat(mat: np.ndarray) -> np.ndarray:
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(mat, dtype=np.float64).reshape(9))
    return q


def geom_triangles(m: mujoco.MjModel, g: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Geom ``g`` as triangles in its own frame: vertices (V, 3) metres and faces (F, 3); None
    for kinds not drawn (height fields, SDF plugins)."""
    import trimesh

    t, size = int(m.geom_type[g]), np.asarray(m.geom_size[g], dtype=np.float64)
    G = mujoco.mjtGeom
    if t == G.mjGEOM_MESH:
        mid = int(m.geom_dataid[g])
        va, vn = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
        fa, fn = int(m.mesh_faceadr[mid]), int(m.mesh_facenum[mid])
        return np.asarray(m.mesh_vert[va:va + vn], dtype=np.float64), np.asarray(m.mesh_face[fa:fa + fn])
    if t == G.mjGEOM_BOX:
        mesh = trimesh.creation.box(extents=2 * size)
    elif t == G.mjGEOM_SPHERE:
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=size[0])
    elif t == G.mjGEOM_ELLIPSOID:
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
        mesh.vertices *= size
    elif t == G.mjGEOM_CAPSULE:
        mesh = trimesh.creation.capsule(height=2 * size[1], radius=size[0], count=[16, 16])
    elif t == G.mjGEOM_CYLINDER:
        mesh = trimesh.creation.cylinder(radius=size[0], height=2 * size[1], sections=24)
    elif t == G.mjGEOM_PLANE:
        hx, hy = (s if s > 0 else _PLANE_HALF for s in size[:2])
        v = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]], dtype=np.float64)
        return v, np.array([[0, 1, 2], [0, 2, 3]])
    else:
        return None
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)


def robot_bodies(robot: Robot) -> np.ndarray:
    """(nbody,) bool: bodies of the robot (moved by its joints, or carrying a body that is),
    not of the world or of the scene (a family's scene joints move obstacles, not the robot):
    the complement of :func:`profrobot.robot.margin.obstacle_bodies`."""
    return ~obstacle_bodies(robot.mj_model, robot.scene_joints)


def robot_pixels(rgb: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of an (H, W, 3) uint8 screenshot in :data:`ROBOT_COLOUR` under
    any shading (red well above green, green above blue)."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return (r > 90) & (r - g > 45) & (g - b > 15) & (r - b > 110)


def _decode(png: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def tool_body(robot: Robot) -> int:
    """The body a gripper's frame is on by default: the deepest body that every leaf of the
    robot hangs from (a Panda's hand, above its two fingers; a serial arm's last link)."""
    m = robot.mj_model
    mine = robot_bodies(robot)
    parent = np.asarray(m.body_parentid)
    has_child = np.zeros(m.nbody, dtype=bool)
    for b in range(1, m.nbody):
        if mine[b]:
            has_child[parent[b]] = True
    leaves = [b for b in range(1, m.nbody) if mine[b] and not has_child[b]]
    if not leaves:
        return 0

    def chain(b: int) -> list[int]:
        out = [b]
        while b > 0:
            b = int(parent[b])
            out.append(b)
        return out[::-1]   # world first

    common = chain(leaves[0])
    for leaf in leaves[1:]:
        c = chain(leaf)
        n = 0
        while n < min(len(c), len(common)) and c[n] == common[n]:
            n += 1
        common = common[:n]
    return int(common[-1])


class Viewer:
    """A viser server showing ``robot`` at ``pose`` (module docs).

    ``robot``: a :class:`~profrobot.Robot`; a family needs ``layout`` (δ, (D,) or a dict), and is
    shown and checked as ``robot.at(layout)``. ``pose``: (K,) radians / metres (default: the middle
    of the joint limits). ``frame``: the site, body or geom the target gizmo moves through
    :func:`~profrobot.ik` and paths are traced by (default: the last robot body). ``port``: the
    port to serve on (``viewer.url``); ``host="0.0.0.0"`` to be seen from other machines.
    ``sliders``/``gizmo``: the panel's joint sliders and the target gizmo.
    """

    def __init__(self, robot: Robot, pose: npt.ArrayLike | None = None, *, layout: Layout | None = None,
                 frame: str | None = None, host: str = "127.0.0.1", port: int = 8080, sliders: bool = True,
                 gizmo: bool = True, verbose: bool = False):
        try:
            import viser
        except ImportError as e:
            raise BackendUnavailableError("profrobot.viz.Viewer needs viser: pip install 'profrobot[viewer]'") from e
        if not isinstance(robot, Robot):
            raise InputTypeError(f"Viewer needs a profrobot.Robot; got {type(robot).__name__}")
        if robot.is_family:
            if layout is None:
                raise InputError(f"{robot.name} is a family of scenes: pass layout=δ, the layout to show "
                                 f"({', '.join(robot.scene_joints)})")
            robot = robot.at(layout)
        elif layout is not None:
            raise InputError(f"layout= is for a family of scenes; {robot.name} has no scene joints")
        self.robot = robot
        self._lock = threading.RLock()
        self._quiet = False   # set while the viewer moves its own sliders
        self.frame = frame if frame is not None else robot.body_names[tool_body(robot)]
        frame_of(robot, self.frame)   # (refused by name here, before a server starts)
        self.server = viser.ViserServer(host=host, port=int(port), verbose=verbose)
        self.server.scene.set_up_direction("+z")
        self.server.gui.configure_theme(show_share_button=False)
        self.server.gui.main_panel.dock_right()   # the panel beside the view, not over it
        self._geoms: dict[int, _GeomHandle] = {}
        self._is_robot: dict[int, bool] = {}
        self._drawn: dict[str, tuple] = {}   # fingerprint → (robot, model, data, geom handles, is-robot)
        self._m: mujoco.MjModel
        self._d: mujoco.MjData
        self._frame: tuple[int, np.ndarray, np.ndarray]
        self._paths: dict[str, dict] = {}
        self._playing = threading.Event()
        self._closed = False
        self.verdict = ""
        self.last_ik: IKResult | None = None
        self._add_geoms()
        if robot.cloud is not None:
            self.show_cloud(robot.cloud)
        self._status = self.server.gui.add_markdown("", order=0)
        self.server.gui.add_html(_WEBGL_NOTICE, order=0.5)
        self.pose = robot.joint_limits.mean(1) if pose is None else as_poses(robot, pose, name="pose").reshape(-1)
        self._sliders = []
        if sliders:
            with self.server.gui.add_folder("Joints", order=1):
                for k, (name, (lo, hi)) in enumerate(zip(robot.joint_names, robot.joint_limits)):
                    s = self.server.gui.add_slider(name, float(lo), float(hi), step=float(hi - lo) / 1000,
                                                   initial_value=float(np.clip(self.pose[k], lo, hi)))
                    s.on_update(lambda _e, k=k, s=s: self._from_slider(k, s.value))
                    self._sliders.append(s)
        self._gizmo = None
        if gizmo:
            pos, quat = self.frame_pose(self.pose)
            self._gizmo = self.server.scene.add_transform_controls("/target", scale=0.15, position=pos, wxyz=quat)
            self._gizmo.on_update(lambda _e: self.follow(self._gizmo.position, self._gizmo.wxyz))
        self.set_pose(self.pose)
        self.look(*self.framing())

    # ---- the scene -------------------------------------------------------------------------------
    def _add_geoms(self, robot: Robot | None = None, prefix: str = "/geoms", visible: bool = True) -> None:
        """Draw ``robot``'s collision geoms (default: the viewer's) under ``prefix`` and make them
        the ones :meth:`set_pose` moves (:meth:`_use` switches between robots' sets)."""
        robot = self.robot if robot is None else robot
        m = robot.mj_model
        bodies = robot_bodies(robot)
        paired = {int(g) for g in np.asarray(robot.pair_geoms).reshape(-1) if g >= 0}
        geoms: dict[int, _GeomHandle] = {}
        is_robot: dict[int, bool] = {}
        for g in range(m.ngeom):
            if not (m.geom_contype[g] or m.geom_conaffinity[g] or g in paired):
                continue
            tri = geom_triangles(m, g)
            if tri is None:
                continue
            mine = bool(bodies[int(m.geom_bodyid[g])])
            plane = int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_PLANE
            is_robot[g] = mine
            geoms[g] = self.server.scene.add_mesh_simple(
                f"{prefix}/{'robot' if mine else 'scene'}/g{g}", tri[0].astype(np.float32), tri[1].astype(np.uint32),
                color=ROBOT_COLOUR if mine else OBSTACLE_COLOUR, opacity=0.35 if plane else None,
                side="double" if plane else "front", visible=visible)
        self._drawn[robot.fingerprint] = (robot, m, mujoco.MjData(m), geoms, is_robot)
        self._use(robot)

    def _use(self, robot: Robot) -> None:
        """Show ``robot``'s geoms (drawn by :meth:`_add_geoms`) and hide the others: the robot a
        stage of :meth:`show_stages` holds (an object attached, or left in the world)."""
        with self._lock:
            if robot.fingerprint == getattr(self, "_fingerprint", None):
                return
            old = self._geoms
            self.robot, self._m, self._d, self._geoms, self._is_robot = self._drawn[robot.fingerprint]
            self._fingerprint = robot.fingerprint
            self._frame = frame_of(self.robot, self.frame)
            with self.server.atomic():
                for h in old.values():
                    h.visible = False
                for h in self._geoms.values():
                    h.visible = True

    def _place(self, pose: np.ndarray) -> None:
        m, d = self._m, self._d
        d.qpos[self.robot.qpos_adr] = pose
        mujoco.mj_kinematics(m, d)

    def frame_pose(self, pose: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """World position (3,) metres and quaternion (w, x, y, z) of :attr:`frame` at ``pose``."""
        with self._lock:
            self._place(np.asarray(pose, dtype=np.float64))
            body, lpos, lquat = self._frame
            R = self._d.xmat[body].reshape(3, 3)
            pos = self._d.xpos[body] + R @ lpos
            q = np.empty(4)
            mujoco.mju_mulQuat(q, self._d.xquat[body], lquat)
            return pos.copy(), q

    def set_pose(self, pose: npt.ArrayLike) -> str:
        """Show the robot at ``pose`` (K,) and the exact verdict; returns the verdict's text."""
        pose = as_poses(self.robot, pose, name="pose").reshape(-1)
        with self._lock:
            labels = label_poses(self.robot, pose[None], pairs=True)
            certified = bool(certify_poses(self.robot, pose[None])[0])
            assert labels.colliding_pairs is not None   # asked for: pairs=True
            pairs = np.asarray(self.robot.pair_geoms)[labels.colliding_pairs[:, 1]] if labels.collides[0] else []
            touching = {int(g) for pair in pairs for g in pair}
            self._place(pose)
            d = self._d
            with self.server.atomic():
                for g, h in self._geoms.items():
                    h.position = d.geom_xpos[g].copy()
                    h.wxyz = _quat(d.geom_xmat[g])
                    if self._is_robot[g]:
                        h.color = CONTACT_COLOUR if g in touching else ROBOT_COLOUR
            self.pose = pose
            self.colliding_pairs = [tuple(self._geom_name(int(g)) for g in pair) for pair in pairs]
            if labels.collides[0]:
                listed = ", ".join(f"{a} – {b}" for a, b in self.colliding_pairs[:8])
                more = f" (+{len(self.colliding_pairs) - 8})" if len(self.colliding_pairs) > 8 else ""
                self.verdict = f"colliding: {listed}{more}"
            else:
                self.verdict = "free, certified" if certified else "free, not certified (within the clearance)"
            self._status.content = f"**{self.robot.name}**: {self.verdict}"
            if self._sliders and not self._quiet:
                self._quiet = True
                try:
                    for s, v in zip(self._sliders, pose):
                        s.value = float(v)
                finally:
                    self._quiet = False
            return self.verdict

    def _geom_name(self, g: int) -> str:
        if g < 0:
            return "point cloud"
        return mujoco.mj_id2name(self._m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom {g} ({self.robot.body_names[int(self._m.geom_bodyid[g])]})"

    def _from_slider(self, k: int, value: float) -> None:
        if self._quiet:
            return
        pose = self.pose.copy()
        pose[k] = value
        pose = self.robot.couplings.apply(pose[None])[0]   # dependent joints follow their independent ones
        self.set_pose(pose)

    def follow(self, position: npt.ArrayLike, wxyz: npt.ArrayLike | None = None) -> IKResult:
        """Move :attr:`frame` to ``position`` (3,) metres (and orientation ``wxyz``): the nearest
        certified :func:`~profrobot.ik` answer from the current pose, shown; the
        :class:`~profrobot.IKResult` is returned (and kept as ``last_ik``). An unreachable
        target leaves the pose and says so."""
        target = np.eye(4)
        target[:3, 3] = np.asarray(position, dtype=np.float64)
        if wxyz is not None:
            R = np.empty(9)
            mujoco.mju_quat2Mat(R, np.asarray(wxyz, dtype=np.float64))
            target[:3, :3] = R.reshape(3, 3)
        res = ik(self.robot, (target if wxyz is not None else target[:3, 3])[None], frame=self.frame, start=self.pose,
                 seeds=16)
        self.last_ik = res
        if res.certified[0]:
            self.set_pose(res.poses[0])
        else:
            why = "reached only in collision" if res.outcome[0] == 2 else "unreachable"
            self._status.content = f"**{self.robot.name}**: {self.verdict}; target {why} (no certified pose)"
        return res

    # ---- what else is shown ----------------------------------------------------------------------
    def show_cloud(self, cloud: PointCloud, name: str = "cloud") -> viser.PointCloudHandle:
        """A :class:`~profrobot.PointCloud` (default: the robot's), coloured by height."""
        pts = np.asarray(cloud.points, dtype=np.float32)
        z = pts[:, 2] if len(pts) else np.zeros(0)
        t = (z - z.min()) / max(float(np.ptp(z)), 1e-9) if len(z) else z
        colours = np.stack([40 + 200 * t, 90 + 60 * (1 - t), 230 - 180 * t], 1).astype(np.uint8)
        size = 2 * float(np.median(cloud.radius)) if len(pts) else 0.01
        return self.server.scene.add_point_cloud(f"/{name}", pts, colours, point_size=max(size, 0.004))

    def show_cameras(self, cameras: CameraSet, images: np.ndarray | Sequence[npt.ArrayLike] | None = None,
                     name: str = "cameras", scale: float = 0.15) -> list:
        """Camera frusta of calibrated ``cameras`` (:class:`profrobot.render.Cameras`, or
        anything with ``K`` (C, 3, 3), ``world_to_cam`` (C, 4, 4) OpenCV, ``width``, ``height``),
        with ``images`` (C, H, W, 3) uint8 on them where given."""
        K, T = np.asarray(cameras.K, dtype=np.float64), np.asarray(cameras.world_to_cam, dtype=np.float64)
        W, H = int(cameras.width), int(cameras.height)
        out = []
        for c in range(len(K)):
            c2w = np.linalg.inv(T[c])
            img = None if images is None else np.asarray(images[c])
            out.append(self.server.scene.add_camera_frustum(
                f"/{name}/cam{c}", fov=float(2 * np.arctan(H / (2 * K[c, 1, 1]))), aspect=W / H, scale=scale,
                image=img, wxyz=_quat(c2w[:3, :3]), position=c2w[:3, 3]))
        return out

    def show_path(self, path: npt.ArrayLike | TimedPath, *, name: str = "path", steps: int = 12,
                  fps: float = 20.0) -> dict:
        """Waypoints ``path`` (S, K): each segment certified by :func:`~profrobot.certify_motions`
        and the frame's trace drawn coloured by its verdict (:data:`VERDICT_COLOURS`); a slider
        and a play button animate the robot along it (``steps`` poses per segment). A
        :class:`~profrobot.TimedPath` (:func:`profrobot.time_path`) plays in real time instead,
        ``fps`` poses a second, its blends included, coloured by its own certificate. Returns
        ``{"verdicts": [...] (one per segment), "certified": bool}``."""
        if isinstance(path, TimedPath):
            if path.joint_names and list(path.joint_names) != list(self.robot.joint_names):
                raise InputError(f"path was timed for {path.robot_name!r}, whose joints differ from {self.robot.name}'s")
            fps = positive("fps", fps)
            times, poses = path.at_rate(fps)[:2]
            poses[:, :] = self.robot.project(poses)
            verdicts = ["certified" if path.certified else "unproven"]
            runs = [poses]
        else:
            path = as_poses(self.robot, path, name="path")
            if path.ndim != 2 or len(path) < 2:
                raise InputError(f"path must be (S, K) waypoints with S >= 2; got shape {path.shape}")
            cert = certify_motions(self.robot, path[:-1], path[1:])
            verdicts = ["certified" if c else "blocked" if b else "unproven"
                        for c, b in zip(cert.certified, cert.blocked)]
            dense = interpolate(self.robot, path[:-1], path[1:], steps)   # (S - 1, steps, K)
            runs = list(dense)
            poses = np.concatenate([dense[:, :-1].reshape(-1, path.shape[1]), path[-1:]])
            times = np.arange(len(poses), dtype=np.float64)
        trace = [np.array([self.frame_pose(q)[0] for q in run]) for run in runs]
        segs = np.concatenate([np.stack([t[:-1], t[1:]], 1) for t in trace])
        colours = np.concatenate([np.repeat([VERDICT_COLOURS[v]], len(t) - 1, axis=0) for v, t in zip(verdicts, trace)])
        lines = self.server.scene.add_line_segments(f"/{name}", segs.astype(np.float32),
                                                    np.repeat(colours[:, None], 2, 1).astype(np.uint8), thickness=0.012)
        with self.server.gui.add_folder(f"Path '{name}'", order=2):
            n_ok = verdicts.count("certified")
            timing = f" ({path.duration:.2f} s timed)" if isinstance(path, TimedPath) else ""
            self.server.gui.add_markdown(f"{n_ok}/{len(verdicts)} segments certified{timing}"
                                         + "".join(f"; segment {i}: {v}" for i, v in enumerate(verdicts) if v != "certified"))
            slider = self.server.gui.add_slider("t", 0, len(poses) - 1, 1, 0)
            play = self.server.gui.add_button("Play / pause")
        slider.on_update(lambda _e: self.set_pose(poses[int(slider.value)]))
        play.on_click(lambda _e: self._toggle(slider, len(poses), fps))
        info = dict(verdicts=verdicts, certified=n_ok == len(verdicts), poses=poses, times=times, lines=lines,
                    slider=slider)
        self._paths[name] = info
        return {"verdicts": verdicts, "certified": n_ok == len(verdicts)}

    def show_stages(self, stages: Sequence[tuple[Robot, TimedPath]], *, name: str = "stages",
                    fps: float = 20.0) -> dict:
        """Play timed stages one after another, each ``(robot, timed)`` with its own robot: the
        viewer's with an object attached (:meth:`profrobot.Robot.attach`) while it is held, or
        left in the world after :meth:`~profrobot.Robot.detach`, as a pick-and-place's stages
        are (``examples/pick_and_place.py --view``). Every robot has the viewer's joints; each
        one's geoms are drawn once and shown while its stage plays. ``fps`` poses a second of
        each :class:`~profrobot.TimedPath`, the frame's trace coloured by each stage's
        certificate. Returns ``{"verdicts": [...] (one per stage), "certified": bool,
        "duration": seconds}``."""
        fps = positive("fps", fps)
        if isinstance(stages, (str, bytes)) or not isinstance(stages, Sequence) or not len(stages):
            raise InputError(f"stages must be a non-empty sequence of (robot, timed path) pairs; got {stages!r}")
        for i, st in enumerate(stages):
            if not (isinstance(st, tuple) and len(st) == 2 and isinstance(st[0], Robot)
                    and isinstance(st[1], TimedPath)):
                raise InputError(f"stages[{i}] must be a (profrobot.Robot, profrobot.TimedPath) pair; got {st!r}")
            robot, timed = st
            if list(robot.joint_names) != list(self.robot.joint_names):
                raise InputError(f"stages[{i}]: {robot.name}'s joints differ from {self.robot.name}'s")
            if timed.joint_names and list(timed.joint_names) != list(robot.joint_names):
                raise InputError(f"stages[{i}]: the path was timed for {timed.robot_name!r}, whose joints differ")
        shown = self.robot
        frames, owner, clock, trace_segs, colours, verdicts = [], [], [], [], [], []
        start = 0.0
        for i, (robot, timed) in enumerate(stages):
            if robot.fingerprint not in self._drawn:
                self._add_geoms(robot, prefix=f"/{name}/robot{len(self._drawn)}", visible=False)
            t, poses = timed.at_rate(fps)[:2]
            poses = robot.project(poses)
            frames.append(poses)
            clock.append(start + t)
            start += timed.duration
            owner += [i] * len(poses)
            verdict = "certified" if timed.certified else "unproven"
            verdicts.append(verdict)
            self._use(robot)
            trace = np.array([self.frame_pose(q)[0] for q in poses])
            if len(trace) > 1:
                trace_segs.append(np.stack([trace[:-1], trace[1:]], 1))
                colours.append(np.repeat([VERDICT_COLOURS[verdict]], len(trace) - 1, axis=0))
        self._use(shown)
        poses = np.concatenate(frames)
        if trace_segs:
            self.server.scene.add_line_segments(f"/{name}/trace", np.concatenate(trace_segs).astype(np.float32),
                                                np.repeat(np.concatenate(colours)[:, None], 2, 1).astype(np.uint8),
                                                thickness=0.012)
        duration = float(sum(t.duration for _, t in stages))
        certified = verdicts.count("certified") == len(verdicts)

        def show(k: int) -> None:
            self._use(stages[owner[k]][0])
            self.set_pose(poses[k])

        with self.server.gui.add_folder(f"Stages '{name}'", order=2):
            self.server.gui.add_markdown(
                f"{verdicts.count('certified')}/{len(verdicts)} stages certified, {duration:.2f} s"
                + "".join(f"; stage {i}: {v}" for i, v in enumerate(verdicts) if v != "certified"))
            slider = self.server.gui.add_slider("t", 0, len(poses) - 1, 1, 0)
            play = self.server.gui.add_button("Play / pause")
        slider.on_update(lambda _e: show(int(slider.value)))
        play.on_click(lambda _e: self._toggle(slider, len(poses), fps))
        self._paths[name] = dict(verdicts=verdicts, certified=certified, poses=poses, stage=np.asarray(owner),
                                 times=np.concatenate(clock), slider=slider)
        return {"verdicts": verdicts, "certified": certified, "duration": duration}

    def seek(self, name: str, t: float) -> np.ndarray:
        """Show the path or stages ``name`` (:meth:`show_path`, :meth:`show_stages`) at ``t``
        seconds from its start (timed) or at pose number ``t`` (waypoints drawn ``steps`` per
        segment): the frame nearest, as its slider would. Returns the pose shown (K,)."""
        if name not in self._paths:
            raise InputError(f"name {name!r} is not a path or stages shown here (shown: {sorted(self._paths)})")
        info = self._paths[name]
        t = float(t)
        if not np.isfinite(t):
            raise InputError(f"t must be a finite number of seconds; got {t!r}")
        k = int(np.argmin(np.abs(info["times"] - t)))
        info["slider"].value = k
        return info["poses"][k]

    def _toggle(self, slider, n: int, fps: float) -> None:
        if self._playing.is_set():
            self._playing.clear()
            return
        self._playing.set()

        def run():
            while self._playing.is_set() and not self._closed:
                slider.value = (int(slider.value) + 1) % n
                time.sleep(1.0 / fps)

        threading.Thread(target=run, daemon=True).start()

    def show_field_slice(self, sdf: SlicedField, joints: tuple[int, int] = (1, 3),
                         resolution: int = 60) -> viser.GuiImageHandle:
        """The field's slice over two joints (:func:`profrobot.viz.sdf_slice`, at the current
        pose), with the exact boundary over it, as an image in the panel (needs torch)."""
        from .slices import sdf_slice

        fig = sdf_slice(sdf, self.robot, joints=joints, base_pose=self.pose, resolution=resolution)
        fig.canvas.draw()
        img = np.asarray(cast("FigureCanvasAgg", fig.canvas).buffer_rgba())[..., :3].copy()   # sdf_slice draws with Agg
        import matplotlib.pyplot as plt

        plt.close(fig)
        with self.server.gui.add_folder("Field slice", order=3):
            return self.server.gui.add_image(img, label=f"g over {self.robot.joint_names[joints[0]]}, "
                                                        f"{self.robot.joint_names[joints[1]]}")

    def framing(self, fov: float = 50.0) -> tuple[np.ndarray, np.ndarray, float]:
        """``(position, look_at, fov)`` of the default camera: the robot at its pose and every
        obstacle within its reach (but infinite planes) in view, their bounding sphere filling
        the vertical field of view ``fov`` degrees, seen from the front right and above.
        :meth:`look` takes it. The reach: the robot's bodies over 64 poses spread over its
        limits (an obstacle no link can come near is left out of the frame, not of the scene)."""
        m, d, robot = self._m, self._d, self.robot
        xpos, _ = robot.core.forward_kinematics(np.ascontiguousarray(np.concatenate(
            [self.pose[None], robot.core.sample(64, 0)])))
        mine = robot_bodies(robot)
        bodies = xpos[:, mine].reshape(-1, 3)
        base = xpos[0, mine].mean(0)
        reach = float(np.linalg.norm(bodies - base, axis=1).max()) + 0.15
        with self._lock:
            self._place(self.pose)
            pts = []
            for g in self._geoms:
                if int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_PLANE:
                    continue
                tri = geom_triangles(m, g)
                if tri is None:
                    continue
                v = tri[0] @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
                if self._is_robot[g] or (np.linalg.norm(v - base, axis=1) <= reach).any():
                    pts.append(v)
        if not pts:
            return np.array([1.5, -1.5, 1.2]), np.zeros(3), fov
        pts_all = np.concatenate(pts)
        centre = (pts_all.min(0) + pts_all.max(0)) / 2
        back = np.array([1.6, -1.1, 0.9]) / np.linalg.norm([1.6, -1.1, 0.9])   # from the centre to the eye
        right = np.cross(-back, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, -back)
        # the nearest eye on that line that sees every point within the field of view (taken as
        # square, whatever the window's shape): |x|, |y| <= depth · tan(fov / 2)
        rel = pts_all - centre
        tan = np.tan(np.radians(fov) / 2)
        distance = float((np.maximum(np.abs(rel @ right), np.abs(rel @ up)) / tan + rel @ back).max())
        distance = max(distance, 0.3) * 1.04
        return centre + back * distance, centre, fov

    def look(self, position: Iterable[float], look_at: Iterable[float], fov: float = 50.0) -> None:
        """Point the browser's camera: from ``position`` (3,) at ``look_at`` (3,), metres, with
        a vertical field of view of ``fov`` degrees (pages open there, and "Reset View" returns
        there; pages already open are moved too). World +z is up."""
        cam = self.server.initial_camera
        cam.position, cam.look_at, cam.fov = tuple(map(float, position)), tuple(map(float, look_at)), np.radians(fov)
        for client in self.server.get_clients().values():
            client.camera.position, client.camera.look_at = cam.position, cam.look_at
            client.camera.fov = cam.fov

    def screenshot(self, path: str | os.PathLike[str], *, width: int = 960, height: int = 640,
                   browser: str | None = None, timeout: float = 60.0) -> Path:
        """Save the 3-D view as a browser draws it to the PNG ``path``, from a headless
        Chromium (playwright, the system browser ``browser``, default ``chromium`` on PATH;
        nothing is downloaded). Waits until the robot is on the page. Returns the path."""
        import shutil
        from pathlib import Path

        from ..files import atomic_path

        try:
            from playwright.sync_api import sync_playwright
        except ImportError as e:
            raise BackendUnavailableError("Viewer.screenshot needs playwright: pip install playwright") from e
        exe = browser or shutil.which("chromium") or shutil.which("chromium-browser")
        if exe is None:
            raise BackendUnavailableError("Viewer.screenshot needs Chromium (Debian: apt-get install chromium), "
                                          "or browser= its path")
        path = Path(path)
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=exe, args=["--no-sandbox", "--use-angle=swiftshader",
                                                             "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"])
            try:
                page = b.new_page(viewport={"width": int(width), "height": int(height)})
                page.goto(self.url)
                page.add_style_tag(content=".mantine-Notifications-root { display: none !important; }")
                canvas = page.locator("canvas").first
                canvas.wait_for(state="visible", timeout=timeout * 1000)
                deadline = time.time() + timeout
                with atomic_path(path, suffix=".png") as tmp:
                    while True:   # the scene streams in after the page loads: wait for the robot's colour
                        png = canvas.screenshot(path=str(tmp))
                        if robot_pixels(_decode(png)).sum() > 500 or time.time() > deadline:
                            break
                        page.wait_for_timeout(500)
                    page.wait_for_timeout(500)
                    canvas.screenshot(path=str(tmp))
            finally:
                b.close()
        return path

    # ---- lifetime --------------------------------------------------------------------------------
    @property
    def url(self) -> str:
        host = self.server.get_host()
        return f"http://{'127.0.0.1' if host in ('0.0.0.0', '::') else host}:{self.server.get_port()}"

    def close(self) -> None:
        """Stop the server (and any animation)."""
        self._closed = True
        self._playing.clear()
        self.server.stop()

    def __reduce__(self):
        raise InputTypeError("a Viewer is a live server and does not pickle: pickle its robot (viewer.robot) and pose "
                        "(viewer.pose), and start a Viewer from them where they are unpickled")

    def __enter__(self) -> "Viewer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Viewer({self.robot.name!r}, url={self.url!r}, verdict={self.verdict!r})"
