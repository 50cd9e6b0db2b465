"""Certified collision-free inverse kinematics and motion to a pose (issue 34).

Targets are made by MuJoCo's own FK of certified free poses, so a collision-free answer exists;
every answer is checked against MuJoCo independently: the frame's pose (``mj_kinematics``) within
0.1 mm and 1 mrad of the target, and no contact (``mj_collision``)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot.exact import problems

from conftest import scene

# (scene, frame): the bundled arms' end effectors
ARMS = [("panda_blocks", "hand"), ("ur5e_wall_box", "attachment_site"), ("xarm7_table", "link_tcp"),
        ("vx300s_clutter", "pinch"), ("panda_shelf", "hand")]

URDF_ARM = """<?xml version="1.0"?>
<robot name="ik_arm">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><box size="0.3 0.3 0.1"/></geometry></collision></link>
  <link name="l1"><collision><origin xyz="0 0 0.16"/><geometry><cylinder radius="0.05" length="0.3"/></geometry></collision></link>
  <link name="l2"><collision><origin xyz="0 0 0.17"/><geometry><box size="0.06 0.06 0.34"/></geometry></collision></link>
  <link name="l3"><collision><origin xyz="0 0 0.14"/><geometry><box size="0.05 0.05 0.28"/></geometry></collision></link>
  <link name="wrist"><collision><origin xyz="0 0 0.04"/><geometry><box size="0.05 0.05 0.08"/></geometry></collision></link>
  <link name="flange"><collision><origin xyz="0 0 0.02"/><geometry><cylinder radius="0.035" length="0.04"/></geometry></collision></link>
  <link name="tool0"/>
  <link name="post"><collision><origin xyz="0 0 0.3"/><geometry><box size="0.1 0.1 0.6"/></geometry></collision></link>
  <joint name="post_fixed" type="fixed"><parent link="base"/><child link="post"/><origin xyz="0.45 0.25 0"/></joint>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-2.9" upper="2.9" effort="10" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.32"/>
    <axis xyz="0 1 0"/><limit lower="-2.0" upper="2.0" effort="10" velocity="1"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0 0 0.34"/>
    <axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5" effort="10" velocity="1"/></joint>
  <joint name="j4" type="continuous"><parent link="l3"/><child link="wrist"/><origin xyz="0 0 0.28"/>
    <axis xyz="0 0 1"/></joint>
  <joint name="j5" type="revolute"><parent link="wrist"/><child link="flange"/><origin xyz="0 0 0.08"/>
    <axis xyz="0 1 0"/><limit lower="-2.0" upper="2.0" effort="10" velocity="1"/></joint>
  <joint name="j6" type="continuous"><parent link="flange"/><child link="tool0"/><origin xyz="0 0 0.04"/>
    <axis xyz="0 0 1"/></joint>
</robot>
"""


@pytest.fixture(scope="module")
def urdf_arm(tmp_path_factory):
    path = tmp_path_factory.mktemp("ik_urdf") / "arm.urdf"
    path.write_text(URDF_ARM)
    return profrobot.Robot.from_urdf(path, collision_matrix="auto")


def fk_targets(robot, frame: str, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(poses (n, K) certified free, the frame's world transforms (n, 4, 4)) by MuJoCo's FK."""
    q = problems.free_poses(robot, 3 * n, seed=seed)
    q = q[profrobot.certify_poses(robot, q)][:n]
    assert len(q) == n
    return q, frame_poses(robot, frame, q)


def frame_poses(robot, frame: str, poses: np.ndarray) -> np.ndarray:
    m = robot.mj_model
    d = mujoco.MjData(m)
    out = np.tile(np.eye(4), (len(poses), 1, 1))
    for i, q in enumerate(poses):
        d.qpos[robot.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, frame) >= 0:
            out[i, :3, :3], out[i, :3, 3] = d.site(frame).xmat.reshape(3, 3), d.site(frame).xpos
        else:
            out[i, :3, :3], out[i, :3, 3] = d.body(frame).xmat.reshape(3, 3), d.body(frame).xpos
    return out


def check_mujoco(robot, frame, res, targets, position_only=False):
    """Every certified answer reaches its target in MuJoCo's FK and has no MuJoCo contact."""
    ok = res.certified
    got = frame_poses(robot, frame, res.poses[ok])
    perr = np.linalg.norm(got[:, :3, 3] - targets[ok][:, :3, 3], axis=1)
    assert perr.max(initial=0) <= 1e-4, perr.max()
    if not position_only:
        rel = np.einsum("nji,njk->nik", targets[ok][:, :3, :3], got[:, :3, :3])
        ang = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))
        assert ang.max(initial=0) <= 1e-3, ang.max()
    assert not profrobot.mujoco_labels(robot, res.poses[ok]).collides.any()
    assert robot.feasible(res.poses[ok]).all()


@pytest.mark.parametrize("name, frame", ARMS[:2])
def test_fk_targets_are_reached_certified_and_free_in_mujoco(name, frame):
    robot = scene(name)
    _, targets = fk_targets(robot, frame, 60, seed=1)
    res = profrobot.ik(robot, targets, frame=frame)
    assert res.certified.mean() >= 0.98, res.summary()
    assert (res.reached | ~res.certified).all()
    check_mujoco(robot, frame, res, targets)
    # position only
    res = profrobot.ik(robot, targets[:, :3, 3], frame=frame)
    assert res.certified.mean() >= 0.98, res.summary()
    check_mujoco(robot, frame, res, targets, position_only=True)


def test_a_urdf_arm_with_continuous_joints(urdf_arm):
    _, targets = fk_targets(urdf_arm, "tool0", 60, seed=2)
    res = profrobot.ik(urdf_arm, targets, frame="tool0")
    assert res.certified.mean() >= 0.98, res.summary()
    check_mujoco(urdf_arm, "tool0", res, targets)


def test_the_answer_stays_near_the_start_and_out_of_reach_is_reported():
    robot = scene("panda_blocks")
    q, targets = fk_targets(robot, "hand", 5, seed=3)
    res = profrobot.ik(robot, targets, frame="hand", start=q)         # started at a solution
    assert res.certified.all() and np.abs(res.poses - q).max() < 1e-3
    far = targets[:1].copy()
    far[0, :3, 3] = [3.0, 0.0, 0.5]                                    # 3 m away: beyond the arm
    res = profrobot.ik(robot, far, frame="hand", seeds=6)
    assert not res.reached[0] and not res.certified[0] and res.position_error[0] > 1.0
    assert res.reasons[0].startswith("unreachable")
    # a target inside a block: reachable only in collision
    block = [b for b in range(robot.mj_model.ngeom) if robot.mj_model.geom_bodyid[b] == 0
             and robot.mj_model.geom_type[b] == mujoco.mjtGeom.mjGEOM_BOX][0]
    inside = np.eye(4)
    inside[:3, 3] = robot.mj_model.geom_pos[block]
    res = profrobot.ik(robot, inside[:3, 3], frame="hand", seeds=8)
    assert not res.certified[0] and res.outcome[0] in (1, 2)


def test_same_seed_same_answers_on_one_and_two_threads():
    robot = scene("panda_blocks")
    _, targets = fk_targets(robot, "hand", 24, seed=4)
    a = profrobot.ik(robot, targets, frame="hand", threads=1, seed=5)
    b = profrobot.ik(robot, targets, frame="hand", threads=2, seed=5)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.certified, b.certified)


def test_bad_input_is_refused_by_name():
    robot = scene("panda_blocks")
    t = np.tile(np.eye(4), (2, 1, 1))
    t[:, :3, 3] = [0.4, 0.0, 0.5]
    nan = t.copy()
    nan[1, 0, 3] = np.nan
    with pytest.raises(profrobot.InputError, match=r"targets\[1, 0, 3\] is nan"):
        profrobot.ik(robot, nan, frame="hand")
    skew = t.copy()
    skew[0, :3, :3] *= 1.1
    with pytest.raises(profrobot.InputError, match=r"targets\[0\]'s rotation is not a rotation"):
        profrobot.ik(robot, skew, frame="hand")
    mirror = t.copy()
    mirror[1, :3, :3] = np.diag([1.0, 1.0, -1.0])
    with pytest.raises(profrobot.InputError, match=r"targets\[1\]'s rotation"):
        profrobot.ik(robot, mirror, frame="hand")
    with pytest.raises(profrobot.InputError, match=r"frame 'gripper' is not a site, body or geom.*hand"):
        profrobot.ik(robot, t, frame="gripper")
    with pytest.raises(profrobot.InputError, match=r"targets must be \(N, 4, 4\)"):
        profrobot.ik(robot, np.zeros((2, 5)), frame="hand")
    with pytest.raises(profrobot.InputError, match="start"):
        profrobot.ik(robot, t, frame="hand", start=np.zeros(4))
    with pytest.raises(profrobot.InputError, match="seeds"):
        profrobot.ik(robot, t, frame="hand", seeds=0)


def test_family_layouts():
    fam = scene("panda_blocks_moving")
    delta = np.zeros(len(fam.scene_index))
    layout = fam.at(delta)
    q, targets = fk_targets(layout, "hand", 10, seed=6)
    res = profrobot.ik(fam, targets, frame="hand", layout=delta)
    assert res.poses.shape == (10, len(fam.robot_index)) and res.certified.mean() >= 0.9
    assert profrobot.certify_poses(fam, res.poses[res.certified], layout=delta).all()


def test_motion_to_a_pose_is_certified_and_ends_at_the_target():
    robot = scene("panda_blocks")
    starts, goals = problems.hard_pairs(robot, 6, seed=7)
    targets = frame_poses(robot, "hand", goals)
    for a, t in zip(starts, targets):
        m = profrobot.plan_to_pose(robot, a, t, frame="hand")
        assert m.certified and m.plan.found and m.outcome == "certified"
        np.testing.assert_allclose(m.path[0], a)
        np.testing.assert_allclose(m.path[-1], m.goal)
        assert np.linalg.norm(frame_poses(robot, "hand", m.goal[None])[0, :3, 3] - t[:3, 3]) <= 1e-4
        assert profrobot.check_path(robot, m.path).certified


def test_motion_to_an_unreachable_pose_says_so_in_its_result():
    """No candidate reaching the target is a result, not bad input; and a time budget spent before
    the first plan still returns a PoseMotion (it returned None)."""
    robot = scene("panda_blocks")
    start = problems.free_poses(robot, 1, seed=3)[0]
    far = np.eye(4)
    far[:3, 3] = [5.0, 0.0, 0.5]   # 5 m away: out of the Panda's reach
    m = profrobot.plan_to_pose(robot, start, far, frame="hand", candidates=2)
    assert isinstance(m, profrobot.PoseMotion)
    assert m.outcome == "no candidate reached" and not m.certified
    assert m.plan is None and m.path is None and m.goal is None
    assert m.ik is not None and not m.ik.reached.any()
    goal = problems.free_poses(robot, 1, seed=4)
    near = frame_poses(robot, "hand", goal)[0]
    m = profrobot.plan_to_pose(robot, start, near, frame="hand", max_time=1e-12)
    assert isinstance(m, profrobot.PoseMotion) and not m.certified
    assert m.outcome in ("time ran out", "no path found", "no candidate reached")


@pytest.mark.slow
@pytest.mark.parametrize("name, frame", ARMS)
def test_thousand_targets_per_arm(name, frame):
    """Issue 34's acceptance: >= 99.5 % of 1000 FK targets reached (0.1 mm, 1 mrad) and certified,
    with no MuJoCo contact, on every bundled arm scene; position-only likewise."""
    robot = scene(name)
    _, targets = fk_targets(robot, frame, 1000, seed=11)
    res = profrobot.ik(robot, targets, frame=frame)
    assert res.certified.mean() >= 0.995, res.summary()
    check_mujoco(robot, frame, res, targets)
    res = profrobot.ik(robot, targets[:, :3, 3], frame=frame)
    assert res.certified.mean() >= 0.995, res.summary()
    check_mujoco(robot, frame, res, targets, position_only=True)


@pytest.mark.slow
def test_thousand_targets_urdf_arm(urdf_arm):
    _, targets = fk_targets(urdf_arm, "tool0", 1000, seed=12)
    res = profrobot.ik(urdf_arm, targets, frame="tool0")
    assert res.certified.mean() >= 0.995, res.summary()
    check_mujoco(urdf_arm, "tool0", res, targets)


# ---- end-effector terms where poses are optimised ------------------------------------------------

def test_plan_trajectory_through_frame_targets():
    """A waypoint in the middle pinned to a hand pose: the path passes through it (0.1 mm) and is
    certified; targets at the end points or an unknown frame are refused."""
    import torch

    robot = scene("panda_blocks")
    torch.manual_seed(0)
    sdf = profrobot.PoseSDF(robot, hidden=(16,))
    (a,), (b,) = problems.hard_pairs(robot, 1, seed=8)
    via = problems.free_poses(robot, 20, seed=9)
    via = via[profrobot.certify_poses(robot, via)][0]
    target = frame_poses(robot, "hand", via[None])[0]
    res = profrobot.plan_trajectory(sdf, a, b, steps=21, robot=robot, frame="hand", frame_targets={10: target},
                                    penalty=profrobot.optim.PenaltyOptions(iterations=30))
    assert res.certified and res.path.shape == (21, robot.njoint)
    np.testing.assert_allclose(res.path[0], a)
    np.testing.assert_allclose(res.path[-1], b)
    got = frame_poses(robot, "hand", res.path[10:11])[0]
    assert np.linalg.norm(got[:3, 3] - target[:3, 3]) <= 1e-4 and "frames" in res.method
    with pytest.raises(profrobot.InputError, match="interior"):
        profrobot.plan_trajectory(sdf, a, b, steps=21, robot=robot, frame="hand", frame_targets={0: target})
    with pytest.raises(profrobot.InputError, match="frame 'nope'"):
        profrobot.plan_trajectory(sdf, a, b, steps=21, robot=robot, frame="nope", frame_targets={5: target})


def test_actions_from_video_with_end_effector_targets_on_operation_frames():
    """The paper's real-robot demo: a video of the arm reaching, with the hand's pose given on the
    operation frames (as a grasp would be): those frames put the hand within 5 mm of its target,
    the movement frames follow the images, and every frame and segment is certified."""
    import torch

    from profrobot.inverse import actions_from_video
    from profrobot.render import GaussianRobot, ring_cameras

    robot = scene("panda_blocks")
    torch.manual_seed(0)
    model = GaussianRobot.from_robot(robot, 1500, seed=0)
    cams = ring_cameras(2, size=32, distance=1.6, lookat=(0.0, 0.0, 0.45))
    a, b = problems.free_poses(robot, 2, seed=21)
    truth = profrobot.interpolate(robot, a, b, 8)
    with torch.no_grad():
        out = model.render_views(torch.as_tensor(truth, dtype=torch.float32), cams)
    video = dict(rgb=out.rgb.reshape(8, 2, 32, 32, 3).numpy(), depth=out.depth.reshape(8, 2, 32, 32).numpy(),
                 mask=(out.alpha > 0.5).reshape(8, 2, 32, 32).numpy())
    ops = [5, 6, 7]                                               # the hand holds its grasp pose
    grasp = frame_poses(robot, "hand", truth[ops])
    sdf = profrobot.PoseSDF(robot, hidden=(16,))
    r = actions_from_video(model, video, cams, init=truth[0] + 0.01, iterations_per_frame=4, joint_iterations=5,
                           sdf=sdf, robot=robot, frame="hand", frame_targets=dict(zip(ops, grasp)))
    assert r.method.endswith("+frames")
    got = frame_poses(robot, "hand", r.path[ops])
    assert np.linalg.norm(got[:, :3, 3] - grasp[:, :3, 3], axis=1).max() <= 5e-3
    assert r.certified and not r.waypoint_uncertified.any() and not r.segment_uncertified.any()
    assert not profrobot.mujoco_labels(robot, r.path).collides.any()


def test_trajectory_from_images_through_a_frame_target():
    import torch

    from profrobot.inverse import trajectory_from_images
    from profrobot.render import GaussianRobot, ring_cameras

    robot = scene("panda_blocks")
    torch.manual_seed(0)
    model = GaussianRobot.from_robot(robot, 1200, seed=0)
    cams = ring_cameras(2, size=32, distance=1.6, lookat=(0.0, 0.0, 0.45))
    a, b = problems.free_poses(robot, 2, seed=11)
    with torch.no_grad():
        out = model.render_views(torch.as_tensor(b[None], dtype=torch.float32), cams)
    t = dict(rgb=out.rgb.numpy(), depth=out.depth.numpy(), mask=(out.alpha > 0.5).numpy())
    target = frame_poses(robot, "hand", b[None])[0]               # the last frame: the hand where the image has it
    r = trajectory_from_images(model, t, cams, start=a, goal=b, steps=10, robot=robot, frame="hand",
                               frame_targets={9: target})
    assert r.method.endswith("+frames")
    got = frame_poses(robot, "hand", r.path[9:10])[0]
    assert np.linalg.norm(got[:3, 3] - target[:3, 3]) <= 1e-4
    assert r.certified == (not r.waypoint_uncertified.any() and not r.segment_uncertified.any())


def test_ik_command(urdf_arm, tmp_path, capsys):
    """``profrobot ik --robot FILE --frame NAME --targets targets.npy`` writes poses and a report."""
    from profrobot.cli.main import main

    path = tmp_path / "arm.urdf"
    path.write_text(URDF_ARM)
    _, targets = fk_targets(urdf_arm, "tool0", 20, seed=13)
    np.save(tmp_path / "t.npy", targets)
    out = tmp_path / "poses.npz"
    code = main(["ik", "--robot", str(path), "--frame", "tool0", "--targets", str(tmp_path / "t.npy"),
                 "--out", str(out)])
    printed = capsys.readouterr()
    assert code in (0, 1), printed.err
    with np.load(out) as z:
        assert z["poses"].shape == (20, urdf_arm.njoint) and z["certified"].mean() >= 0.9
        assert list(z["joint_names"]) == urdf_arm.joint_names
    assert "certified" in printed.out
    assert main(["ik", "--robot", str(path), "--frame", "nope", "--targets", str(tmp_path / "t.npy")]) == 2
    assert "frame 'nope'" in capsys.readouterr().err


def test_distance_rows_take_a_reached_pose_out_of_contact():
    """One seed per target (the start): where the pose it reaches collides, the linearised
    distance rows move it out along the redundancy the target leaves; every pose so certified is
    free in MuJoCo and still on its target."""
    robot = scene("ur5e_wall_box")
    _, targets = fk_targets(robot, "attachment_site", 150, seed=14)
    plain = profrobot.ik(robot, targets[:, :3, 3], frame="attachment_site", seeds=1, escape=False)
    rows = profrobot.ik(robot, targets[:, :3, 3], frame="attachment_site", seeds=1)
    assert (plain.outcome == 2).sum() >= 3, plain.summary()            # reached, but only in contact
    assert rows.certified.sum() > plain.certified.sum(), (plain.summary(), rows.summary())
    assert (rows.certified | ~plain.certified).all()                   # nothing certified is lost
    check_mujoco(robot, "attachment_site", rows, targets, position_only=True)
