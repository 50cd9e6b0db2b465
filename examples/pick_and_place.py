"""A pick-and-place a robot can execute, certified end to end, then played in MuJoCo.

The Menagerie Panda, a table, a wall in the way and a mug-sized cylinder. Stages:

    pre-grasp (plan_to_pose, the mug's axis free: any yaw grasps it)
    → approach, 8 cm straight down (plan_cartesian)
    → attach the mug to the hand (Robot.attach), close the fingers
    → lift, 10 cm straight up, holding it
    → carry over the wall to above the place (plan_to_pose, holding it)
    → place, straight down
    → open the fingers, detach (Robot.detach)
    → retreat, 8 cm straight up

Every stage's joint path is certified free (the held mug included) and timed within the
Panda's velocity and acceleration limits (time_path, blends proven). Then the timed motion is
executed: MuJoCo steps the Panda's own position actuators tracking it (mj_step), the mug a free
body welded to the hand while held; every contact is counted.

    python examples/pick_and_place.py            # prints the stages and the execution report
    python examples/pick_and_place.py --view     # then plays them in the browser (viewer extra)
    python examples/pick_and_place.py --shot pick.png   # a picture of the carry, from the browser
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field

import mujoco
import numpy as np

import profrobot
from profrobot import Box, Cylinder

TABLE_TOP = 0.2
MUG_RADIUS, MUG_HALF = 0.025, 0.05
HOVER = 0.002            # the planning model's mug floats 2 mm above the table (a pose touching it is not free)
PICK = np.array([0.45, -0.3])
PLACE = np.array([0.45, 0.3])
TCP = np.array([0.0, 0.0, 0.1034])              # the fingertips' centre in the hand's frame
DOWN = np.diag([1.0, -1.0, -1.0])               # the hand pointing down
OPEN, CLOSED = 0.04, MUG_RADIUS - 0.001         # finger joint values (m); closed presses 1 mm into the mug
ARM_V = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61]) * 0.5   # rad/s: half the Panda's limits
ARM_A = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0]) * 0.3         # rad/s²
FINGER_V, FINGER_A = 0.05, 0.5                  # m/s, m/s²
SETTLE = 0.3                                     # s held still after each stage in the simulation


@dataclass
class Stage:
    name: str
    robot: profrobot.Robot
    path: np.ndarray
    timed: profrobot.TimedPath
    certified: bool
    seconds: float
    holding: bool                 # planned with the mug attached
    grip: bool = False            # the fingers move, the arm does not


@dataclass
class Execution:
    tracking_error: float                 # rad: the largest |q − q_desired| of the arm joints
    contacts: dict = field(default_factory=dict)   # (geom, geom) → steps, every contact seen
    forbidden: dict = field(default_factory=dict)  # the contacts that are not allowed touches
    place_error: float = np.nan           # m: the mug's centre from its place pose at the end
    duration: float = 0.0


def world(panda: profrobot.Robot | None = None) -> profrobot.Robot:
    """The Panda (built here unless given) with the table, the wall and the mug."""
    if panda is None:
        panda = profrobot.Robot.from_menagerie("franka_emika_panda", "panda")
    return panda.with_obstacles([
        Box(pos=(0.5, 0.0, TABLE_TOP / 2), half_size=(0.3, 0.6, TABLE_TOP / 2), name="table"),
        Box(pos=(0.45, 0.0, TABLE_TOP + 0.125), half_size=(0.12, 0.02, 0.125), name="wall"),
        Cylinder(pos=(*PICK, TABLE_TOP + MUG_HALF + HOVER), radius=MUG_RADIUS, half_length=MUG_HALF, name="mug"),
    ])


def _pose(xy, z) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = DOWN, (*xy, z)
    return t


def _fingers(robot, q, value) -> np.ndarray:
    out = q.copy()
    for n in ("finger_joint1", "finger_joint2"):
        out[robot.joint_names.index(n)] = value
    return out


def _limits(robot):
    v = np.full(robot.njoint, FINGER_V)
    a = np.full(robot.njoint, FINGER_A)
    v[:7], a[:7] = ARM_V, ARM_A
    return v, a


def plan(seed: int = 0) -> list[Stage]:
    panda = profrobot.Robot.from_menagerie("franka_emika_panda", "panda")
    home = panda.mj_model.key("home").qpos.copy()
    robot = world(panda)     # (the scene, the grasp and the release are written without compiling MuJoCo)
    grasp_z = TABLE_TOP + MUG_HALF + HOVER + 0.02          # the fingertips 3 cm below the mug's top
    place_z = grasp_z
    fingers = ("finger_joint1", "finger_joint2")
    stages: list[Stage] = []

    def add(name, r, path, certified, t0, holding, grip=False, line=False):
        v, a = _limits(r)
        # (a straight-line move keeps its corners: a cut would leave the line)
        keep = {"cut": 0.0} if line else {}
        timed = profrobot.time_path(r, path, velocity=v, acceleration=a, **keep)
        if not (certified and timed.certified):
            raise RuntimeError(f"stage {name}: not certified ({timed.reason})")
        stages.append(Stage(name, r, np.asarray(path), timed, certified and timed.certified,
                            time.perf_counter() - t0, holding, grip))
        return np.asarray(path)[-1]

    def cartesian(name, r, q, dz, holding):
        t0 = time.perf_counter()
        p = tcp(r, q)
        move = profrobot.plan_cartesian(r, q, p + [0.0, 0.0, dz], frame="hand", tool=TCP, locked=fingers)
        if not move.reached:
            raise RuntimeError(f"stage {name}: {move.reason}")
        return add(name, r, move.path, True, t0, holding, line=True)

    def to_pose(name, r, q, target, holding):
        t0 = time.perf_counter()
        motion = profrobot.plan_to_pose(r, q, target, frame="hand", tool=TCP, free_axis="z", locked=fingers,
                                        seed=seed)
        if motion.outcome != "certified":
            raise RuntimeError(f"stage {name}: {motion.outcome}")
        return add(name, r, motion.path, True, t0, holding)

    def grip(name, r, q, value, holding):
        t0 = time.perf_counter()
        path = np.stack([q, _fingers(r, q, value)])
        ok = bool(profrobot.certify_motions(r, path[:1], path[1:]).certified[0])
        return add(name, r, path, ok, t0, holding, grip=True)

    q = to_pose("pre-grasp", robot, home, _pose(PICK, grasp_z + 0.08), False)
    q = cartesian("approach", robot, q, -0.08, False)
    held = robot.attach("mug", to="hand", at=q)
    q = grip("close", held, q, CLOSED, True)
    q = cartesian("lift", held, q, 0.10, True)
    q = to_pose("carry", held, q, _pose(PLACE, place_z + 0.10), True)
    q = cartesian("place", held, q, -0.10, True)
    q = grip("open", held, q, OPEN, True)
    put = held.detach("mug", at=q)
    cartesian("retreat", put, q, 0.08, False)
    return stages


def tcp(r, q) -> np.ndarray:
    """Where the fingertips' centre is at pose ``q`` (the core's forward kinematics)."""
    xpos, xquat = r.core.body_frames(np.asarray(q, dtype=np.float64)[None], r.body_names.index("hand"), threads=1)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, xquat[0])
    return xpos[0] + rot.reshape(3, 3) @ TCP


def robot_frame(r, q) -> np.ndarray:
    """The same by MuJoCo's ``mj_kinematics`` (the tests' independent check)."""
    m = r.mj_model
    d = mujoco.MjData(m)
    d.qpos[r.qpos_adr] = q
    mujoco.mj_kinematics(m, d)
    b = m.body("hand").id
    return d.xpos[b] + d.xmat[b].reshape(3, 3) @ TCP


def simulation(robot: profrobot.Robot) -> tuple[mujoco.MjModel, int]:
    """The planning world with the mug a free body resting on the table, and a weld (off) that
    holds it to the hand."""
    spec = robot.spec.copy()
    spec.delete(spec.geom("mug"))
    body = spec.worldbody.add_body(name="mug", pos=(*PICK, TABLE_TOP + MUG_HALF))
    body.add_freejoint()
    body.add_geom(name="mug", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=(MUG_RADIUS, MUG_HALF, 0), mass=0.2,
                  rgba=(0.8, 0.3, 0.2, 1))
    weld = spec.add_equality(type=mujoco.mjtEq.mjEQ_WELD, name="hold", name1="hand", name2="mug",
                             objtype=mujoco.mjtObj.mjOBJ_BODY)
    weld.active = False
    # the controller a Panda runs: gravity compensated (the arm's links), position targets with
    # the trajectory's velocity fed forward through the actuators' damping (see `execute`)
    for name in [f"link{i}" for i in range(1, 8)] + ["hand", "left_finger", "right_finger"]:
        spec.body(name).gravcomp = 1.0
    m = spec.compile()
    return m, m.equality("hold").id


def execute(stages: list[Stage]) -> Execution:
    m, weld = simulation(stages[0].robot)
    d = mujoco.MjData(m)
    robot = stages[0].robot
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id) if m.nkey else None
    adr = np.array([m.jnt_qposadr[m.joint(n).id] for n in robot.joint_names])
    d.qpos[adr] = stages[0].timed.sample(0.0)[0]
    d.ctrl[:7] = d.qpos[adr[:7]]
    d.ctrl[7] = d.qpos[adr[7]] / 0.04 * 255
    mujoco.mj_forward(m, d)
    mug = m.body("mug").id
    hand = m.body("hand").id
    names = {g: mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"{m.body(m.geom_bodyid[g]).name}/{g}"
             for g in range(m.ngeom)}
    allowed_bodies = {m.body("left_finger").id, m.body("right_finger").id, hand}
    table = m.geom("table").id
    out = Execution(tracking_error=0.0)
    dt = m.opt.timestep
    clock = 0.0
    for st in stages:
        # The weld holds the mug while the arm moves it: on once the fingers have closed on it
        # (they centre it, as a real gripper does), off before they open.
        if st.holding and not st.grip and not d.eq_active[weld]:
            # weld the mug where it is now: its pose relative to the hand (body1 = hand, body2 = mug)
            rq, rp = np.zeros(4), np.zeros(3)
            inv = np.zeros(4)
            mujoco.mju_negQuat(inv, d.xquat[hand])
            mujoco.mju_mulQuat(rq, inv, d.xquat[mug])
            mujoco.mju_rotVecQuat(rp, d.xpos[mug] - d.xpos[hand], inv)
            m.eq_data[weld, 3:6], m.eq_data[weld, 6:10] = rp, rq
            m.eq_data[weld, 0:3] = 0
            d.eq_active[weld] = 1
        if (st.grip or not st.holding) and d.eq_active[weld]:
            d.eq_active[weld] = 0
        steps = int(np.ceil((st.timed.duration + SETTLE) / dt))
        t = np.minimum(np.arange(1, steps + 1) * dt, st.timed.duration)
        q_des, qd_des, _ = st.timed.sample(t)
        # an actuator's force is kp·(ctrl − q) − kv·q̇: ctrl = q_d + (kv / kp)·q̇_d tracks q_d with q̇_d
        ff = m.actuator_biasprm[:7, 2] / m.actuator_biasprm[:7, 1]
        for k in range(steps):
            d.ctrl[:7] = q_des[k, :7] + ff * qd_des[k, :7]
            d.ctrl[7] = q_des[k, 7] / 0.04 * 255
            mujoco.mj_step(m, d)
            err = np.abs(d.qpos[adr[:7]] - q_des[k, :7]).max()
            out.tracking_error = max(out.tracking_error, float(err))
            for c in d.contact[: d.ncon]:
                g1, g2 = int(c.geom1), int(c.geom2)
                key = tuple(sorted((names[g1], names[g2])))
                out.contacts[key] = out.contacts.get(key, 0) + 1
                b1, b2 = m.geom_bodyid[g1], m.geom_bodyid[g2]
                mug_touch = mug in (b1, b2) and ({b1, b2} - {mug}) <= (allowed_bodies | {0}) and \
                    (table in (g1, g2) or ({b1, b2} - {mug}) <= allowed_bodies)
                if not mug_touch:
                    out.forbidden[key] = out.forbidden.get(key, 0) + 1
        clock += steps * dt
    place = np.array([*PLACE, TABLE_TOP + MUG_HALF])
    out.place_error = float(np.linalg.norm(d.xpos[mug] - place))
    out.duration = clock
    return out


def view(stages: list[Stage], *, shot: str | None = None, port: int = 8080) -> None:
    """Play the stages in the browser viewer, each with its own robot (the mug held, or left in
    the world); with ``shot``, save a picture of the carry instead of serving until Ctrl-C."""
    from profrobot.viz import Viewer

    with Viewer(stages[0].robot, stages[0].timed.sample(0.0)[0], port=port, frame="hand", gizmo=False) as viewer:
        shown = viewer.show_stages([(st.robot, st.timed) for st in stages], name="pick and place", fps=30)
        print(f"viewer: {shown['duration']:.2f} s of stages, {'all certified' if shown['certified'] else 'NOT all certified'}")
        if shot is not None:
            carry = [i for i, st in enumerate(stages) if st.name == "carry"][0]
            viewer.seek("pick and place", sum(st.timed.duration for st in stages[:carry])
                        + stages[carry].timed.duration / 2)
            print("saved", viewer.screenshot(shot))
            return
        print(f"open {viewer.url} and press Play (Ctrl-C stops)")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--view", action="store_true", help="play the stages in the browser viewer (viewer extra)")
    ap.add_argument("--shot", help="save a PNG of the carry from the browser viewer (and Chromium)")
    ap.add_argument("--port", type=int, default=8080)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    stages = plan()
    print(f"planned in {time.perf_counter() - t0:.2f} s:")
    for st in stages:
        print(f"  {st.name:10s} {len(st.path):3d} waypoints, {st.timed.duration:5.2f} s timed, "
              f"{'certified' if st.certified else 'NOT certified'}, planned in {st.seconds * 1e3:.1f} ms"
              f"{' (holding the mug)' if st.holding else ''}")
    ex = execute(stages)
    print(f"executed in MuJoCo ({ex.duration:.2f} s simulated): tracking error {ex.tracking_error * 1e3:.2f} mrad, "
          f"mug placed {ex.place_error * 1e3:.2f} mm from its place, "
          f"{sum(ex.forbidden.values())} forbidden contact steps {sorted(ex.forbidden)}")
    print("contacts seen (allowed):", sorted(ex.contacts))
    if args.view or args.shot:
        view(stages, shot=args.shot, port=args.port)
    return 0 if not ex.forbidden and ex.place_error <= 0.005 else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
