"""IK and planning the way arms are used: joints held where they are (``locked=``), a gripper's
jaw left alone by ``plan_to_pose``, a result whose ``reached`` never contradicts its outcome, and a
joint range ``[v, v]`` refused by name instead of read (as MuJoCo does) as no range."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot.exact import problems


@pytest.fixture(scope="module")
def robot():
    return profrobot.scenes.load("panda_blocks")


def hand_poses(robot, q: np.ndarray) -> np.ndarray:
    """(N, 4, 4) world transforms of the hand at poses ``q`` (N, K), by MuJoCo's FK."""
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    out = np.tile(np.eye(4), (len(q), 1, 1))
    for i, x in enumerate(q):
        d.qpos[robot.qpos_adr] = x
        mujoco.mj_kinematics(m, d)
        out[i, :3, :3], out[i, :3, 3] = d.body("hand").xmat.reshape(3, 3), d.body("hand").xpos
    return out


def test_locked_joints_stay_where_they_start(robot):
    truth = problems.free_poses(robot, 60, seed=11)
    targets = hand_poses(robot, truth)
    start = truth.copy()
    start[:, :6] += np.random.default_rng(0).normal(0, 0.3, (60, 6))    # the arm elsewhere, joint7 as in truth
    start = np.clip(start, robot.joint_limits[:, 0], robot.joint_limits[:, 1])
    sol = profrobot.ik(robot, targets, frame="hand", start=start, locked=["joint7"])
    j7 = robot.joint_names.index("joint7")
    assert np.abs(sol.poses[:, j7] - start[:, j7]).max() <= 1e-12
    assert sol.certified.mean() >= 0.9, sol.summary()
    # the answers reach their targets as MuJoCo places the hand
    got = hand_poses(robot, sol.poses[sol.certified])
    assert np.abs(got[:, :3, 3] - targets[sol.certified, :3, 3]).max() <= 1e-4
    # unlocked, the solver is free to turn joint7 (and does, for some)
    free = profrobot.ik(robot, targets, frame="hand", start=start)
    assert np.abs(free.poses[:, j7] - start[:, j7]).max() > 1e-6


def test_reached_and_outcome_never_disagree(robot):
    """Few LM iterations and a loose tolerance: many seeds stop between the hundredth of the
    tolerance the solver aims for and the tolerance itself. Those reach the target."""
    truth = problems.free_poses(robot, 300, seed=12)
    targets = hand_poses(robot, truth)
    far = targets[:20].copy()
    far[:, :3, 3] += 3.0                                    # out of reach
    sol = profrobot.ik(robot, np.concatenate([targets, far]), frame="hand", iterations=3, seeds=4,
                       position_tolerance=2e-2, rotation_tolerance=2e-1)
    within = (sol.position_error <= 2e-2) & (sol.rotation_error <= 2e-1)
    np.testing.assert_array_equal(sol.reached, within)
    np.testing.assert_array_equal(sol.reached, sol.outcome != 1)
    assert sol.certified[sol.outcome == 0].all() and not sol.certified[sol.outcome != 0].any()
    assert not sol.reached[-20:].any() and (sol.outcome[-20:] == 1).all()
    # the case this guards: errors within the tolerance, above the hundredth the solver aims for
    stalled = within & (sol.position_error > 2e-4)
    assert stalled.any() and (sol.outcome[stalled] != 1).all()


def test_plan_path_keeps_locked_joints_on_every_waypoint(robot):
    (a, b), = [problems.hard_pairs(robot, 1, seed=4)]
    a, b = a[0].copy(), b[0].copy()
    fingers = [n for n in robot.joint_names if n.startswith("finger")]
    idx = [robot.joint_names.index(n) for n in fingers]
    b[idx] = a[idx]
    res = profrobot.plan_path(robot, a, b, locked=fingers, seed=1)
    assert res.found and res.certified
    assert (res.path[:, idx] == a[idx]).all()
    b2 = b.copy()
    b2[idx] = a[idx] + 0.005
    with pytest.raises(profrobot.InputError, match="locked joints must keep one value: .*finger_joint1"):
        profrobot.plan_path(robot, a, b2, locked=fingers)


def test_plan_to_pose_leaves_the_jaw_alone(robot):
    start = problems.free_poses(robot, 1, seed=21)[0]
    fingers = [robot.joint_names.index(n) for n in robot.joint_names if n.startswith("finger")]
    target = hand_poses(robot, problems.free_poses(robot, 1, seed=22))[0]
    motion = profrobot.plan_to_pose(robot, start, target, frame="hand", candidates=4)
    assert motion.certified
    np.testing.assert_array_equal(motion.goal[fingers], start[fingers])     # not asked to move: it did not
    held = profrobot.plan_to_pose(robot, start, target, frame="hand", locked=["finger_joint1", "finger_joint2"])
    assert held.certified and (held.path[:, fingers] == start[fingers]).all()


def test_bad_locked_is_refused_by_name(robot):
    q = problems.free_poses(robot, 2, seed=3)
    t = hand_poses(robot, q[:1])
    with pytest.raises(profrobot.InputTypeError, match="locked must be a list of joint names"):
        profrobot.ik(robot, t, frame="hand", locked="joint7")
    with pytest.raises(profrobot.InputError, match="locked: 'elbow' is not a joint of panda_blocks"):
        profrobot.ik(robot, t, frame="hand", locked=["elbow"])
    with pytest.raises(profrobot.InputError, match="locked: 'joint1' is named twice"):
        profrobot.plan_path(robot, q[0], q[1], locked=["joint1", "joint1"])
    with pytest.raises(profrobot.InputError, match="locked"):
        profrobot.plan_to_pose(robot, q[0], t[0], frame="hand", locked=["nope"])


def test_a_range_with_equal_ends_is_refused_by_name(tmp_path):
    xml = """<mujoco><worldbody>
      <body name="a"><joint name="shoulder" type="hinge" axis="0 0 1" range="-1 1"/><geom size="0.05"/>
        <body name="b" pos="0.2 0 0"><joint name="jaw" type="slide" range="0.5 0.5"/><geom size="0.02"/></body>
      </body></worldbody></mujoco>"""
    assert not mujoco.MjModel.from_xml_string(xml).jnt_limited[1]      # MuJoCo: no range at all
    path = tmp_path / "pinned.xml"
    path.write_text(xml)
    with pytest.raises(profrobot.InputError, match=r"joint range with equal ends: 'jaw' \[0.5, 0.5\]"):
        profrobot.Robot.from_mjcf(path)


def rotate_about_own_z(T: np.ndarray, angles: np.ndarray) -> np.ndarray:
    c, s = np.cos(angles), np.sin(angles)
    Rz = np.zeros((len(angles), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    out = T.copy()
    out[:, :3, :3] = T[:, :3, :3] @ Rz
    return out


def test_a_free_axis_solves_what_a_full_pose_cannot(robot):
    """A symmetric part, grasped at any angle about the hand's z axis, by an arm with two joints
    held (five left: a full pose is out of their reach, the direction of an axis is not)."""
    truth = problems.free_poses(robot, 80, seed=31)
    turned = rotate_about_own_z(hand_poses(robot, truth), np.random.default_rng(1).uniform(0.6, 2.4, 80))
    held = ["joint5", "joint7"]
    full = profrobot.ik(robot, turned, frame="hand", start=truth, locked=held)
    free = profrobot.ik(robot, turned, frame="hand", start=truth, locked=held, free_axis="z")
    assert free.certified.mean() >= 0.9 and full.certified.mean() <= 0.2, (free.summary(), full.summary())
    ok = free.certified
    got = hand_poses(robot, free.poses[ok])
    assert np.abs(got[:, :3, 3] - turned[ok, :3, 3]).max() <= 1e-4
    cos = np.einsum("ni,ni->n", got[:, :3, 2], turned[ok, :3, 2])      # the z axes, as MuJoCo places the hand
    assert np.arccos(np.clip(cos, -1, 1)).max() <= 1e-3
    np.testing.assert_allclose(free.rotation_error[ok], np.arccos(np.clip(cos, -1, 1)), atol=1e-6)
    with pytest.raises(profrobot.InputError, match="free_axis needs orientation targets"):
        profrobot.ik(robot, turned[:1, :3, 3], frame="hand", free_axis="z")
    with pytest.raises(profrobot.InputError, match="free_axis must be"):
        profrobot.ik(robot, turned[:1], frame="hand", free_axis="w")


def test_a_tool_offset_moves_the_target_point(robot):
    truth = problems.free_poses(robot, 40, seed=41)
    T = hand_poses(robot, truth)
    tip = np.array([0.0, 0.0, 0.1034])                     # the Panda's fingertip centre in the hand frame
    tool_T = T.copy()
    tool_T[:, :3, 3] = T[:, :3, 3] + np.einsum("nij,j->ni", T[:, :3, :3], tip)
    sol = profrobot.ik(robot, tool_T, frame="hand", tool=tip, start=truth)
    assert sol.certified.mean() >= 0.9
    got = hand_poses(robot, sol.poses[sol.certified])
    np.testing.assert_allclose(got[:, :3, 3] + np.einsum("nij,j->ni", got[:, :3, :3], tip), tool_T[sol.certified, :3, 3],
                               atol=1e-4)
    with pytest.raises(profrobot.InputError, match="tool"):
        profrobot.ik(robot, tool_T[:1], frame="hand", tool=[[1.0, 2.0]])


def _frame_poses(robot, q: np.ndarray, body: str) -> np.ndarray:
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    out = np.tile(np.eye(4), (len(q), 1, 1))
    for i, x in enumerate(q):
        d.qpos[robot.qpos_adr] = x
        mujoco.mj_kinematics(m, d)
        out[i, :3, :3], out[i, :3, 3] = d.body(body).xmat.reshape(3, 3), d.body(body).xpos
    return out


def test_the_gripper_moves_when_asked_and_says_so_when_held():
    """vx300s_clutter: 1 000 targets made by forward kinematics of free poses. With the gripper's
    joints free to move every one is certified; held at their start values (the default), a
    target reached only with another jaw value says so, with the value, never only that every
    reaching pose collides."""
    robot = profrobot.scenes.load("vx300s_clutter")
    fingers = ["left_finger", "right_finger"]
    truth = problems.free_poses(robot, 1000, seed=0)     # (one of them is reached only with the jaw moved)
    targets = _frame_poses(robot, truth, "gripper_link")
    free = profrobot.ik(robot, targets, frame="gripper_link", moving=fingers)
    assert free.certified.all(), free.summary()
    np.testing.assert_array_equal(free.reached, free.outcome != 1)
    got = _frame_poses(robot, free.poses, "gripper_link")
    assert np.abs(got[:, :3, 3] - targets[:, :3, 3]).max() <= 1e-4
    held = profrobot.ik(robot, targets, frame="gripper_link")
    j = [robot.joint_names.index(n) for n in fingers]
    start = profrobot.ik(robot, targets[:1], frame="gripper_link").poses   # (the default start's jaw)
    np.testing.assert_array_equal(held.poses[:, j], np.repeat(start[:, j], len(targets), axis=0))
    stuck = np.flatnonzero(held.outcome == 2)
    assert len(stuck) >= 1
    for i in stuck:
        assert "another value of them reaches it certified" in held.reasons[i] and "moving=" in held.reasons[i]
        assert "every pose that reaches it collides" not in held.reasons[i]
    # the note is checked: what it says is what moving= finds
    again = profrobot.ik(robot, targets[stuck], frame="gripper_link", moving=fingers)
    assert again.certified.all()


def test_moving_refused_by_name(robot):
    with pytest.raises(profrobot.InputError, match="moving"):
        profrobot.ik(robot, np.eye(4), frame="hand", moving=["nope"])
    with pytest.raises(profrobot.InputError, match="both locked and moving: finger_joint1"):
        profrobot.ik(robot, np.eye(4), frame="hand", moving=["finger_joint1"], locked=["finger_joint1"])


def test_a_posture_pulls_the_answers_within_what_the_target_leaves_free(robot):
    """posture=: each answer moves towards it in the target's null space and stays on the target.
    Position-only targets leave a 7-joint arm four joints' worth of freedom: the answers come
    much nearer the posture; full poses leave one (the elbow): nearer, never off the target."""
    truth = problems.free_poses(robot, 100, seed=3)
    targets = hand_poses(robot, truth)
    posture = np.clip(robot.mj_model.key("home").qpos if robot.mj_model.nkey else robot.joint_limits.mean(1),
                      robot.joint_limits[:, 0], robot.joint_limits[:, 1])

    def dist(q):
        return np.linalg.norm(q[:, :7] - posture[:7], axis=1)

    for tgt, gain in ((targets[:, :3, 3], 0.8), (targets, 1.0)):
        plain = profrobot.ik(robot, tgt, frame="hand")
        near = profrobot.ik(robot, tgt, frame="hand", posture=posture)
        assert near.certified.mean() >= plain.certified.mean() - 0.01, near.summary()
        ok = plain.certified & near.certified
        assert np.median(dist(near.poses[ok])) < gain * np.median(dist(plain.poses[ok]))
        got = hand_poses(robot, near.poses[near.certified])
        pos = tgt[near.certified] if tgt.ndim == 2 else tgt[near.certified, :3, 3]
        assert np.abs(got[:, :3, 3] - pos).max() <= 1e-4
        assert profrobot.certify_poses(robot, near.poses[near.certified]).all()
    for bad in (posture[:3], np.full(robot.njoint, np.nan), posture + 10.0):
        with pytest.raises(profrobot.InputError, match="posture"):
            profrobot.ik(robot, targets[:2], frame="hand", posture=bad)
