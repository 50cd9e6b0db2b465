"""Every answer is a pose the robot can take (issue 33): within its limits and on its joint
couplings to 1e-9, or not certified. A certificate about a pose the mechanism cannot reach
certifies nothing.

Three kinds of coupling: the Panda's mirrored fingers (a MuJoCo joint equality), a URDF
``<mimic>`` (multiplier and offset), and an MJCF polynomial (``polycoef``) that is nonlinear, for
which a straight joint-space motion between coupled poses leaves the coupling: what the robot
does is the independent joints' straight motion with the dependent ones following, and that
curve is what is certified and checked against MuJoCo here.

The couplings are checked two ways: by :meth:`Robot.feasible` (our formula), and by MuJoCo's own
equality rows (``efc_pos`` of ``mj_fwdPosition``, :func:`equality_residual`), independent of it."""

import numpy as np
import pytest
import torch

import profrobot
from profrobot.exact import problems
from profrobot.robot.equalities import equality_residual

from conftest import scene

TOL = 1e-9

MIMIC_URDF = """<?xml version="1.0"?>
<robot name="mimic_arm">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><box size="0.3 0.3 0.1"/></geometry></collision></link>
  <link name="l1"><collision><origin xyz="0 0 0.16"/><geometry><cylinder radius="0.05" length="0.3"/></geometry></collision></link>
  <link name="l2"><collision><origin xyz="0 0 0.17"/><geometry><box size="0.06 0.06 0.34"/></geometry></collision></link>
  <link name="hand"><collision><origin xyz="0 0 0.03"/><geometry><box size="0.16 0.05 0.06"/></geometry></collision></link>
  <link name="finger_a"><collision><origin xyz="0 0 0.05"/><geometry><box size="0.02 0.02 0.1"/></geometry></collision></link>
  <link name="finger_b"><collision><origin xyz="0 0 0.05"/><geometry><box size="0.02 0.02 0.1"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-2.8" upper="2.8" effort="10" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.32"/>
    <axis xyz="0 1 0"/><limit lower="-2.2" upper="2.2" effort="10" velocity="1"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="hand"/><origin xyz="0 0 0.34"/>
    <axis xyz="0 1 0"/><limit lower="-2.0" upper="2.0" effort="10" velocity="1"/></joint>
  <joint name="fa" type="revolute"><parent link="hand"/><child link="finger_a"/><origin xyz="0.06 0 0.06"/>
    <axis xyz="0 1 0"/><limit lower="-0.6" upper="0.6" effort="1" velocity="1"/></joint>
  <joint name="fb" type="revolute"><parent link="hand"/><child link="finger_b"/><origin xyz="-0.06 0 0.06"/>
    <axis xyz="0 1 0"/><limit lower="-0.9" upper="0.9" effort="1" velocity="1"/>
    <mimic joint="fa" multiplier="-1.0" offset="0.1"/></joint>
</robot>
"""

# A 3-joint arm whose two hinged fingers are coupled by a cubic: fb = 0.1 - 0.8 d + 0.6 d^2 + 0.3 d^3
POLY_MJCF = """<mujoco model="poly">
  <compiler angle="radian"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="l1" pos="0 0 0.1">
      <joint name="j1" type="hinge" axis="0 0 1" range="-2.8 2.8"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.045"/>
      <body name="l2" pos="0 0 0.3">
        <joint name="j2" type="hinge" axis="0 1 0" range="-2.0 2.0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
        <body name="hand" pos="0.33 0 0">
          <joint name="j3" type="hinge" axis="0 1 0" range="-2.0 2.0"/>
          <geom type="box" size="0.03 0.07 0.02"/>
          <body name="fa" pos="0.03 0.05 0"><joint name="fa" type="hinge" axis="0 0 1" range="-0.8 0.8"/>
            <geom type="box" pos="0.05 0 0" size="0.05 0.008 0.008"/></body>
          <body name="fb" pos="0.03 -0.05 0"><joint name="fb" type="hinge" axis="0 0 1" range="-1.5 1.5"/>
            <geom type="box" pos="0.05 0 0" size="0.05 0.008 0.008"/></body>
        </body>
      </body>
    </body>
  </worldbody>
  <equality><joint joint1="fb" joint2="fa" polycoef="0.1 -0.8 0.6 0.3 0"/></equality>
</mujoco>
"""

OBSTACLES = [profrobot.Box(pos=(0.35, 0.2, 0.3), half_size=(0.06, 0.06, 0.3), name="post"),
             profrobot.Sphere(pos=(-0.1, -0.35, 0.45), radius=0.1, name="ball")]


@pytest.fixture(scope="module", params=["panda_blocks", "vx300s_clutter", "ur5e_wall_box", "mimic_urdf", "polycoef_mjcf"])
def robot(request, tmp_path_factory):
    if request.param in ("panda_blocks", "vx300s_clutter", "ur5e_wall_box"):
        return scene(request.param)    # mirrored fingers (a joint equality); the UR5e: limits only
    folder = tmp_path_factory.mktemp(request.param)
    if request.param == "mimic_urdf":
        (folder / "arm.urdf").write_text(MIMIC_URDF)
        base = profrobot.Robot.from_urdf(folder / "arm.urdf", collision_matrix="auto")
    else:
        (folder / "arm.xml").write_text(POLY_MJCF)
        base = profrobot.Robot.from_mjcf(folder / "arm.xml")
    return base.with_obstacles(OBSTACLES)


def check_answers(robot, poses, certified=None, what: str = ""):
    """Every pose feasible (or, where ``certified`` is given, every certified one), by our
    formula and by MuJoCo's equality rows."""
    q = np.asarray(poses, dtype=np.float64).reshape(-1, robot.njoint)
    feasible = robot.feasible(q, atol=TOL)
    if certified is None:
        assert feasible.all(), f"{what}: {(~feasible).sum()} of {len(q)} poses the robot cannot take"
    else:
        c = np.broadcast_to(np.asarray(certified, dtype=bool).reshape(-1), feasible.shape)
        assert not (c & ~feasible).any(), f"{what}: a certified pose the robot cannot take"
    take = q[feasible][:: max(1, feasible.sum() // 40)]
    if len(take):
        assert equality_residual(robot.mj_model, take, robot.qpos_adr).max() <= TOL, what


def mujoco_free_along(robot, path, step=0.0005):
    """MuJoCo finds no contact along ``path``'s segments replayed as the robot moves them
    (independent joints straight, dependent ones following), at ``step`` rad."""
    d = profrobot.exact.labels.so2_steps(robot, path)
    dense = [path[:1]]
    for a, b, n in zip(path[:-1], path[1:], np.ceil(np.abs(d).max(axis=1) / step).astype(int)):
        dense.append(profrobot.interpolate(robot, a, b, max(int(n), 1) + 1)[1:])
    dense = np.concatenate(dense)
    check_answers(robot, dense, what="a replayed path")
    return not profrobot.mujoco_labels(robot, dense).collides.any()


def test_problems_and_the_oracle_answer_on_the_couplings(robot):
    free = problems.free_poses(robot, 40, seed=1)
    hit = problems.colliding_poses(robot, 40, seed=2)
    check_answers(robot, free, what="free_poses")
    check_answers(robot, hit, what="colliding_poses")
    starts, goals = problems.hard_pairs(robot, 4, seed=3)
    check_answers(robot, np.concatenate([starts, goals]), what="hard_pairs")
    near = profrobot.nearest_free(robot, hit[:20])
    found = np.isfinite(near.distance)
    assert found.mean() > 0.8
    check_answers(robot, near.poses[found], what="nearest_free")
    # the oracle's answers are free: certified where a clearance exists
    assert not profrobot.collides(robot, near.poses[found]).any()


def test_planned_paths_are_coupled_certified_and_free_in_mujoco(robot):
    starts, goals = problems.hard_pairs(robot, 3, seed=4)
    for a, b in zip(starts, goals):
        res = profrobot.plan_path(robot, a, b, max_time=20)
        assert res.certified, res.status
        check_answers(robot, res.path, what="plan_path")
        assert profrobot.check_path(robot, res.path).certified
        assert mujoco_free_along(robot, res.path)


# a field trained per robot (5-11 s each): the two hand-made couplings (the mimic URDF's, linear
# with an offset; the polycoef MJCF's, nonlinear) in the default run; the bundled scenes (mirrored
# fingers: the Panda, the vx300s; the UR5e: limits only) in the slow tier
@pytest.mark.parametrize("robot", [pytest.param(n, marks=pytest.mark.slow)
                                   for n in ("panda_blocks", "vx300s_clutter", "ur5e_wall_box")]
                         + ["mimic_urdf", "polycoef_mjcf"], indirect=True)
def test_field_answers_are_coupled(robot):
    sdf = profrobot.train_sdf(robot, hidden=(32,), n_poses=4000, iterations=60, batch_size=512, eikonal_batch=64,
                              progress=False, seed=0)
    hit = problems.colliding_poses(robot, 12, seed=5)
    res = profrobot.resolve(sdf, hit, robot=robot)
    check_answers(robot, res.poses, what="resolve")
    adam = profrobot.resolve(sdf, hit[:4], robot=robot, method="adam", iterations=20, refine=False)
    check_answers(robot, adam.poses, adam.certified, what="resolve(adam)")
    (a,), (b,) = problems.hard_pairs(robot, 1, seed=6)
    traj = profrobot.plan_trajectory(sdf, a, b, steps=16, robot=robot,
                                     penalty=profrobot.optim.PenaltyOptions(iterations=20))
    check_answers(robot, traj.path, what="plan_trajectory")
    if traj.certified:
        assert mujoco_free_along(robot, traj.path)


def test_inverse_answers_are_coupled(robot):
    from profrobot.inverse import actions_from_video, pose_from_images, trajectory_from_images
    from profrobot.render import GaussianRobot, ring_cameras

    torch.manual_seed(0)
    model = GaussianRobot.from_robot(robot, 800, seed=0)
    cams = ring_cameras(2, size=24, distance=1.6, lookat=(0.0, 0.0, 0.4))
    target = problems.free_poses(robot, 3, seed=7)
    with torch.no_grad():
        out = model.render_views(torch.as_tensor(target, dtype=torch.float32), cams)
    t = dict(rgb=out.rgb.reshape(3, 2, 24, 24, 3).numpy(), depth=out.depth.reshape(3, 2, 24, 24).numpy(),
             mask=(out.alpha > 0.5).reshape(3, 2, 24, 24).numpy())
    # starts off the coupling (as an optimiser's own iterate would be): the answers are on it
    init = target + 0.05
    r = pose_from_images(model, t, cams, init=init, image_iterations=4, robot=robot)
    check_answers(robot, r.poses, what="pose_from_images")
    one = {k: v[2:3] for k, v in t.items()}
    tr = trajectory_from_images(model, one, cams, start=target[0], goal=target[2], steps=6, robot=robot)
    check_answers(robot, tr.path, what="trajectory_from_images")
    v = actions_from_video(model, t, cams, init=target[0] + 0.01, iterations_per_frame=3, joint_iterations=2,
                           robot=robot)
    check_answers(robot, v.path, what="actions_from_video")


def test_certification_refuses_what_the_robot_cannot_take(robot):
    """A certified free pose, nudged off its coupling or past a limit by 1e-6: certify_poses,
    certify_motions and check_path (both methods) all refuse it."""
    q = problems.free_poses(robot, 30, seed=8)
    q = q[profrobot.certify_poses(robot, q)][:2]
    assert len(q) == 2
    off = q.copy()
    if not robot.couplings:      # the UR5e: limits only
        off[:, 0] = robot.joint_limits[0, 1] + 1e-6
    else:
        off[:, robot.couplings.dependent[0]] += 1e-6
    lim = robot.joint_limits
    limited = np.flatnonzero(~robot.continuous)
    out = q.copy()
    out[0, limited[0]] = lim[limited[0], 1] + 1e-6
    for bad, why in ((off, "off its coupling"), (out, "outside its limits")):
        assert not robot.feasible(bad[0]).any(), why
        assert not profrobot.certify_poses(robot, bad[:1])[0], why
        m = profrobot.certify_motions(robot, q[1:], bad[:1])
        assert m.unproven[0] and not m.certified[0], why
        m = profrobot.certify_motions(robot, bad[:1], q[1:])
        assert m.unproven[0], why
        for method in ("continuous", "sampled"):
            check = profrobot.check_path(robot, np.stack([q[1], bad[0]]), method=method)
            assert not check.certified and check.waypoint_uncertified[1], (why, method)
    # and the core itself, called directly, refuses them too
    assert not robot.core.certified(np.ascontiguousarray(off), profrobot.CLEARANCE).any()
    if robot.couplings:   # nearest_free puts an off-coupling input on the coupling; plan_path refuses one
        assert robot.feasible(profrobot.nearest_free(robot, off).poses).all()
        with pytest.raises(profrobot.InputError, match="couplings"):
            profrobot.plan_path(robot, off[0], q[1])


def test_a_nonlinear_coupling_is_certified_along_the_curve_the_robot_moves(tmp_path):
    """Between two coupled poses, the straight line leaves a nonlinear coupling (by up to
    ~0.25 rad here); interpolate and the certificate both follow the coupling, and the motion
    certified is free in MuJoCo along that curve."""
    (tmp_path / "arm.xml").write_text(POLY_MJCF)
    robot = profrobot.Robot.from_mjcf(tmp_path / "arm.xml")
    assert not robot.couplings.linear
    a = robot.project(np.array([0.3, 0.4, 0.2, -0.3, 0.0]))
    b = robot.project(np.array([0.5, 0.3, 0.1, 0.8, 0.0]))
    assert profrobot.certify_poses(robot, np.stack([a, b])).all()
    mid_straight = (a + b) / 2
    assert robot.couplings.residual(mid_straight[None])[0] > 0.2
    path = profrobot.interpolate(robot, a, b, 101)
    assert robot.couplings.residual(path).max() <= 1e-12
    assert profrobot.certify_motions(robot, a, b).certified[0]
    assert mujoco_free_along(robot, np.stack([a, b]))
