"""Straight-line moves (profrobot.plan_cartesian, python/profrobot/exact/cartesian.py): the frame
stays on the line (MuJoCo's forward kinematics every 0.1 mm of its travel, measured here
independently of the implementation), every segment is certified, and where the line cannot
be followed the fraction and the reason say how far and why."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

import profrobot
from profrobot import InputError, plan_cartesian

from conftest import scene
from test_timing import puck


def _frame(robot, q, body):
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_adr] = q
    mujoco.mj_kinematics(m, d)
    b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body)
    return d.xpos[b].copy(), d.xquat[b].copy()


def _check_on_line(robot, res, body, a, b, ra, rb, pos_tol=1e-3, rot_tol=0.01):
    """Every 0.1 mm of the frame's travel along the returned path: within the tolerances of the
    segment a → b (orientation: the slerp ra → rb at the nearest point); every segment certified."""
    q = res.path
    if len(q) > 1:
        assert profrobot.certify_motions(robot, q[:-1], q[1:]).certified.all()
    slerp = Slerp([0, 1], Rotation.concatenate([ra, rb]))
    d = b - a
    worst = 0.0
    for qa, qb in zip(q[:-1], q[1:]):
        pa, pb = _frame(robot, qa, body)[0], _frame(robot, qb, body)[0]
        n = int(np.ceil(np.linalg.norm(pb - pa) / 1e-4)) + 2
        for x in profrobot.interpolate(robot, qa, qb, n):
            p, quat = _frame(robot, x, body)
            u = np.clip((p - a) @ d / (d @ d), 0, 1)
            dist = np.linalg.norm(a + u * d - p)
            ang = (slerp([u]).inv() * Rotation.from_quat(quat[[1, 2, 3, 0]])).magnitude()[0]
            assert dist <= pos_tol and ang <= rot_tol, (dist, ang)
            worst = max(worst, dist)
    return worst


@pytest.mark.parametrize("name, body, n", [("panda_blocks", "hand", 12), ("ur5e_wall_box", "wrist_3_link", 16)])
def test_approach_moves_stay_on_the_line_and_are_certified(name, body, n):
    """(ur5e's 15th start: the batch solves one waypoint on the other elbow branch, 1.8 rad
    away in the joints but beside its neighbour in space; a check spaced by the frame's travel
    alone passed it, and the frame swung 9 mm off the line between the two)"""
    robot = scene(name)
    qs = profrobot.sample_poses(robot, 2000, seed=3)
    qs = qs[profrobot.certify_poses(robot, qs)][:n]
    rng = np.random.default_rng(0)
    reached = 0
    for q in qs:
        p, quat = _frame(robot, q, body)
        r = Rotation.from_quat(quat[[1, 2, 3, 0]])
        target = p + r.as_matrix()[:, 2] * rng.uniform(0.05, 0.10)
        res = plan_cartesian(robot, q, target, frame=body)
        np.testing.assert_array_equal(res.path[0], q)
        _check_on_line(robot, res, body, p, target, r, r)
        end = _frame(robot, res.path[-1], body)[0]
        if res.reached:
            reached += 1
            assert res.fraction == 1 and not res.reason
            assert np.linalg.norm(end - target) < 1e-4
        else:
            assert res.reason and 0 <= res.fraction < 1
            # the fraction is how far along the line the last pose is
            assert abs(np.linalg.norm(end - p) / np.linalg.norm(target - p) - res.fraction) < 0.02
    assert reached >= 6


def test_a_line_into_an_obstacle_or_past_a_limit_stops_and_says_why():
    robot = puck()
    into = plan_cartesian(robot, [0.0, 0.15], [1.0, 0.15, 0.0], frame="puck")
    # the block's face is at x = 0.8, the puck's radius 0.05: contact at x = 0.75
    x_end = into.path[-1, 0]
    assert not into.reached and ("collides" in into.reason or "blocked" in into.reason), into.reason
    assert 0.74 - 0.006 <= x_end < 0.75 and into.fraction == pytest.approx(x_end, abs=0.006)
    past = plan_cartesian(robot, [0.0, 0.5], [1.5, 0.5, 0.0], frame="puck")
    assert not past.reached and "reach" in past.reason and past.path[-1, 0] <= 1.2
    assert past.path[-1, 0] > 1.2 - 0.006
    assert past.fraction == pytest.approx(past.path[-1, 0] / 1.5, abs=0.005)
    for res in (into, past):
        assert profrobot.certify_motions(robot, res.path[:-1], res.path[1:]).certified.all()


def test_several_legs_in_one_move():
    robot = puck()
    corners = np.array([[0.5, 0.0, 0.0], [0.5, 0.5, 0.0], [1.0, 0.5, 0.0]])
    res = plan_cartesian(robot, [0.0, 0.0], corners, frame="puck")
    assert res.reached, res.reason
    # every corner is a waypoint, and between them the puck is on its leg
    for c in corners[:, :2]:
        assert np.min(np.linalg.norm(res.path - c, axis=1)) < 1e-6
    assert np.abs(np.diff(res.path, axis=0)).max() <= 0.005 + 1e-6       # (IK to 1e-7 m)


def test_bad_input_refused_by_name(panda):
    q = profrobot.sample_poses(panda, 50, seed=1)
    q = q[profrobot.certify_poses(panda, q)][0]
    cases = [
        (dict(frame="nowhere"), "frame 'nowhere'"),
        (dict(frame="hand", step=0), "step"),
        (dict(frame="hand", position_tolerance=-1), "position_tolerance"),
        (dict(frame="hand", rotation_tolerance=np.nan), "rotation_tolerance"),
        (dict(frame="hand", locked=["nope"]), "locked"),
    ]
    for kwargs, words in cases:
        with pytest.raises(profrobot.ProfrobotError) as e:
            plan_cartesian(panda, q, [0.3, 0.0, 0.5], **kwargs)
        assert words in str(e.value)
    with pytest.raises(InputError, match="targets"):
        plan_cartesian(panda, q, [[0.3, 0.0]], frame="hand")
    with pytest.raises(InputError, match="start"):
        plan_cartesian(panda, q[:4], [0.3, 0.0, 0.5], frame="hand")
    with pytest.raises(InputError, match="start collides"):
        plan_cartesian(puck(), [0.85, 0.15], [0.3, 0.0, 0.0], frame="puck")


# An arm whose hinges sit off their bodies' origins, two and three to a body, one unlimited, with
# turned bodies and a `ref`: the lever arms' anchor terms (cartesian._lever_arms), which the
# bundled arms (every hinge at its body's origin) never exercise.
_OFFSET_ARM = """
<mujoco model="offset_arm">
  <worldbody>
    <body name="l1" pos="0 0 0.1">
      <joint name="a" type="hinge" axis="0 0 1" pos="0.05 0 0" range="-2 2"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.04" contype="0" conaffinity="0"/>
      <body name="l2" pos="0 0.02 0.3" quat="0.9239 0.3827 0 0">
        <joint name="b" type="hinge" axis="0 1 0" pos="0 0 0.04" range="-2 2"/>
        <joint name="c" type="hinge" axis="1 0 0" pos="0.03 -0.02 0" ref="0.3"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.035" contype="0" conaffinity="0"/>
        <body name="tip" pos="0.3 0 0" quat="0.7071 0 0.7071 0">
          <joint name="d" type="hinge" axis="0 0 1" pos="0 0.05 0.02" range="-2.5 2.5"/>
          <joint name="e" type="hinge" axis="0 1 0" pos="0.02 0 0" range="-2 2"/>
          <joint name="f" type="hinge" axis="1 0 0" pos="0 0 -0.03" range="-2 2"/>
          <geom type="box" size="0.03 0.02 0.06" pos="0 0 0.08" contype="0" conaffinity="0"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def _offset_arm():
    return profrobot.Robot.from_spec(mujoco.MjSpec.from_string(_OFFSET_ARM), name="offset_arm")


@pytest.mark.parametrize("name, body", [("panda_blocks", "hand"), ("ur5e_wall_box", "wrist_3_link"), ("offset", "tip")])
def test_the_bound_between_samples_holds_on_segments_that_stray(name, body):
    """plan_cartesian shows a segment on the line from a few samples and a bound on how far the
    frame can go between them (cartesian._bounded): MuJoCo's forward kinematics every 1/4000 of
    segments large and small (0.01-0.6 rad per joint), measured from the chord of the frame's
    own motion, never finds the frame farther from it, or turned farther from its slerp, than the
    bound, also with loose tolerances (few samples: the bound between them carries it)."""
    from profrobot.exact.cartesian import _bounded, _lever_arms, _Line

    robot = _offset_arm() if name == "offset" else scene(name)
    b = robot.mj_model.body(body).id
    arms = _lever_arms(robot, b, np.zeros(3))
    assert arms is not None and len(arms[0]) >= 6

    def frames(q):
        return robot.core.body_frames(np.ascontiguousarray(q), b)

    rng = np.random.default_rng(7)
    data = mujoco.MjData(robot.mj_model)
    qs = profrobot.sample_poses(robot, 36, seed=11)
    for i, qa in enumerate(qs):
        scale = (0.01, 0.1, 0.6)[(i // 2) % 3]
        qb = np.clip(qa + rng.normal(0, scale, robot.njoint), *robot.joint_limits.T)
        # the leg is the chord of the frame's own motion, as plan_cartesian's waypoints are on
        # the line: the ends are on it, and all the deviation is between the samples
        (pa, ra), (pb, rb) = _frame(robot, qa, body), _frame(robot, qb, body)
        line = _Line(np.stack([pa, pb]), np.stack([ra, rb]), 0.005)
        q = np.stack([qa, qb])
        # (the tolerances plan_cartesian uses, and loose ones: a single interval, the bound alone)
        tols = ((1e-3, 0.01), (1.0, 1.0))[i % 2]
        bound_p, bound_r = _bounded(line, frames, q, np.diff(q, axis=0), np.array([0]), arms, tols)
        a, d = line.pos[0], line.pos[1] - line.pos[0]
        slerp = Slerp([0, 1], Rotation.from_quat(line.quats[:, [1, 2, 3, 0]]))
        p, quat = np.empty((4001, 3)), np.empty((4001, 4))
        for k, w in enumerate(np.linspace(0, 1, 4001)):
            data.qpos[robot.qpos_adr] = qa + w * (qb - qa)
            mujoco.mj_kinematics(robot.mj_model, data)
            p[k], quat[k] = data.xpos[b], data.xquat[b]
        u = np.clip((p - a) @ d / (d @ d), 0, 1)
        worst_p = np.linalg.norm(a + u[:, None] * d - p, axis=1).max()
        worst_r = (slerp(u).inv() * Rotation.from_quat(quat[:, [1, 2, 3, 0]])).magnitude().max()
        assert worst_p <= bound_p[0] + 1e-12 and worst_r <= bound_r[0] + 1e-12, (i, worst_p, bound_p, worst_r, bound_r)


def test_turning_in_place_with_the_target_where_mujoco_puts_the_frame():
    """A turn of the hand in place, its target position read from MuJoCo (the last bits differ
    from the core's forward kinematics): measured as a turn, not along a chord of 1e-16 m; the
    hand stays within 1 mm of the point and ends at the target's orientation."""
    robot = scene("panda_blocks")
    qs = profrobot.sample_poses(robot, 2000, seed=3)
    qs = qs[profrobot.certify_poses(robot, qs)][:12]
    rng = np.random.default_rng(4)
    data = mujoco.MjData(robot.mj_model)
    hand = robot.mj_model.body("hand").id
    reached = 0
    for q in qs:
        p, quat = _frame(robot, q, "hand")
        turn = Rotation.from_rotvec(0.6 * Rotation.random(random_state=rng).apply([0.0, 0.0, 1.0]))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = (turn * Rotation.from_quat(quat[[1, 2, 3, 0]])).as_matrix(), p
        res = plan_cartesian(robot, q, T[None], frame="hand")
        reached += res.reached
        for qa, qb in zip(res.path[:-1], res.path[1:]):
            for w in np.linspace(0, 1, 50):
                data.qpos[robot.qpos_adr] = qa + w * (qb - qa)
                mujoco.mj_kinematics(robot.mj_model, data)
                assert np.linalg.norm(data.xpos[hand] - p) <= 1e-3
        if res.reached:
            end = Rotation.from_quat(_frame(robot, res.path[-1], "hand")[1][[1, 2, 3, 0]])
            assert (end.inv() * Rotation.from_matrix(T[:3, :3])).magnitude() < 1e-3
    assert reached >= 8
