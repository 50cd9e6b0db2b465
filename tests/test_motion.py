"""The continuous certificate of motions (rust/planning/motion.rs, profrobot.certify_motions): what it
proves holds under MuJoCo on a fine re-interpolation, on every bundled scene; a thin obstacle
that a sampled check steps over is refused; the planner uses it."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot.exact.certification import CLEARANCE, certify_motions, check_path
from profrobot.errors import InputError
from profrobot.exact.labels import so2_steps
from profrobot.exact.planning import plan_path

from conftest import scene

FINE = 0.0005  # rad / m: the re-interpolation MuJoCo checks (issue 23)


def fine_poses(robot, a: np.ndarray, b: np.ndarray, step: float = FINE) -> np.ndarray:
    """The SO(2) motion a -> b at no more than ``step`` per joint between poses."""
    d = so2_steps(robot, np.stack([a, b]))[0]
    n = max(int(np.ceil(np.abs(d).max() / step)) + 1, 2)
    return profrobot.interpolate(robot, a, b, n)


def mujoco_contacts(robot, poses: np.ndarray) -> np.ndarray:
    """(N,) int: MuJoCo's contact count (mj_kinematics + mj_collision) at each pose."""
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    out = np.empty(len(poses), dtype=int)
    for i, q in enumerate(poses):
        d.qpos[robot.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        out[i] = d.ncon
    return out


def grazing_motions(robot, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, K) starts and goals: from a free pose toward a random pose, stopped just short of
    the first contact on the way (so the motions come close to contact), or whole when free."""
    rng = np.random.default_rng(seed)
    a = profrobot.exact.problems.free_poses(robot, n, seed=seed)
    b = profrobot.sample_poses(robot, n, seed=seed + 1)
    goals = []
    for qa, qb in zip(a, b):
        qb = qa + (qb - qa) * rng.uniform(0.05, 0.5)  # shorter motions: fewer of them blocked
        path = fine_poses(robot, qa, qb, 0.002)
        hit = np.flatnonzero(profrobot.collides(robot, path))
        goals.append(path[max(hit[0] - 3, 1)] if len(hit) else qb)
    return a, np.array(goals)


@pytest.mark.parametrize("name", profrobot.scenes.names())
def test_certified_motions_are_free_under_mujoco_on_a_fine_interpolation(name):
    robot = scene(name)
    a, b = grazing_motions(robot, 24, seed=7)
    cert = certify_motions(robot, a, b)
    assert cert.certified.sum() >= 6, (name, cert.certified.sum())
    assert (cert.certified ^ cert.blocked ^ cert.unproven).all()
    for qa, qb in zip(a[cert.certified], b[cert.certified]):
        poses = fine_poses(robot, qa, qb)
        assert not mujoco_contacts(robot, poses).any(), name
        # ... and the exact labeller's certification holds at every fine pose
        assert profrobot.certify_poses(robot, poses).all(), name
    # a blocked motion names a pose that is in contact or within the clearance (up to GJK's
    # relative tolerance, 1e-7)
    for qa, qb, t in zip(a[cert.blocked], b[cert.blocked], cert.blocked_at[cert.blocked]):
        d = so2_steps(robot, np.stack([qa, qb]))[0]
        q = qa + t * d
        lab = profrobot.label_poses(robot, q[None], distance=True)
        margin = max(float(robot.core.pairs()[2].max(initial=0.0)), CLEARANCE)
        assert lab.collides[0] or lab.min_distance[0] <= margin * (1 + 1e-6) + 1e-7, (name, t, lab.min_distance[0])


def test_same_certificate_on_one_and_two_threads():
    robot = scene("panda_blocks")
    a, b = grazing_motions(robot, 40, seed=3)
    one, two = certify_motions(robot, a, b, threads=1), certify_motions(robot, a, b, threads=2)
    for f in ("certified", "blocked", "unproven", "blocked_at", "states"):
        np.testing.assert_array_equal(getattr(one, f), getattr(two, f))


# A thin blade turning about z through a thin plate: at 0.01 rad steps the blade's samples fall
# either side of the plate (its contact window is under 4 mrad wide), so a sampled check passes
# the motion; the continuous certificate refuses it. The slide lifts the blade over the plate.
_BLADE = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <geom name="plate" type="box" pos="0.5 0.0025 0" size="0.1 0.00025 0.05"/>
    <body name="blade">
      <joint name="turn" type="hinge" axis="0 0 1" range="-1 1"/>
      <joint name="lift" type="slide" axis="0 0 1" range="0 0.3"/>
      <geom type="box" pos="0.35 0 0" size="0.25 0.0005 0.01"/>
    </body>
  </worldbody>
</mujoco>
"""


def blade():
    return profrobot.Robot.from_spec(mujoco.MjSpec.from_string(_BLADE), name="blade")


def test_thin_plate_passes_a_sampled_check_and_is_refused_continuously():
    robot = blade()
    a, b = np.array([-0.5, 0.0]), np.array([0.5, 0.0])
    # the plate sits at 0.005 rad, between the 0.01 rad samples
    sampled = check_path(robot, np.stack([a, b]), density=100, method="sampled")
    assert sampled.certified
    assert np.abs(np.diff(sampled.dense, axis=0)[:, 0]).max() <= 0.01 + 1e-12
    cont = certify_motions(robot, a, b)
    assert cont.blocked[0] and not cont.certified[0]
    assert not check_path(robot, np.stack([a, b])).certified
    # MuJoCo agrees the motion collides, on the fine re-interpolation
    hits = mujoco_contacts(robot, fine_poses(robot, a, b))
    assert hits.any()
    # the blocked pose is where MuJoCo finds the contact window (within its 3.8 mrad)
    assert abs(-0.5 + cont.blocked_at[0] - 0.005) < 0.004
    # lifted over the plate the same turn is certified
    assert certify_motions(robot, a + [0, 0.1], b + [0, 0.1]).certified[0]


def test_planner_goes_over_the_plate_with_the_continuous_certificate():
    robot = blade()
    a, b = [-0.5, 0.0], [0.5, 0.0]
    sampled = plan_path(robot, a, b, check="sampled", verify=1, seed=0)
    assert sampled.status == "direct"  # straight through the plate, between samples
    assert mujoco_contacts(robot, fine_poses(robot, *sampled.path)).any()
    cont = plan_path(robot, a, b, seed=0)
    assert cont.found and cont.certified and cont.status == "connected"
    for qa, qb in zip(cont.path[:-1], cont.path[1:]):
        assert not mujoco_contacts(robot, fine_poses(robot, qa, qb)).any()
    assert check_path(robot, cont.path).certified


def test_bad_input():
    robot = scene("ur5e_wall_box")
    q = profrobot.exact.problems.free_poses(robot, 2, seed=1)
    with pytest.raises(InputError, match="same shape"):
        certify_motions(robot, q, q[:1])
    bad = q.copy()
    bad[1, 2] = np.nan
    with pytest.raises(InputError, match=r"goals\[1, 2\]"):
        certify_motions(robot, q, bad)
    with pytest.raises(InputError, match="method"):
        check_path(robot, q, method="exact")
    with pytest.raises(InputError, match="check"):
        plan_path(robot, q[0], q[1], check="dense")
    with pytest.raises(ValueError, match="clearance"):
        robot.core.certify_motions(q, q, 0.0)


def test_a_slide_outside_its_limits_is_unproven_not_certified():
    """Issue 23 review: the levers bound slides by their limits, so a motion with a limited slide
    outside them proves nothing (it was certified through the plate)."""
    robot = blade()
    a, b = np.array([-0.5, 0.0]), np.array([0.5, 0.0])
    lifted = certify_motions(robot, a + [0, 0.1], b + [0, 0.1])
    assert lifted.certified[0]
    out = certify_motions(robot, a + [0, 0.5], b + [0, 0.5])  # above the slide's 0.3 m limit
    assert out.unproven[0] and not out.certified[0]
    huge = certify_motions(robot, np.array([-0.5, 0.1]), np.array([2e6, 0.1]))
    assert huge.unproven[0]
    assert not check_path(robot, np.stack([a + [0, 0.5], b + [0, 0.5]])).certified


@pytest.mark.parametrize("name", ["panda_shelf", "xarm7_table"])
def test_planner_proves_what_it_returns_after_exploring(name):
    """The search explores with sampled edges and proves only the path it returns (repairing
    segments that fail): every returned path passes the certificate again on its own, and
    MuJoCo finds no contact along it at FINE; found or not, the same for 1 and 2 threads."""
    robot = scene(name)
    starts, goals = profrobot.exact.problems.hard_pairs(robot, 8, seed=21)
    for i, (a, b) in enumerate(zip(starts, goals)):
        r = plan_path(robot, a, b, seed=i)
        assert r.found and r.certified and r.status == "connected", r.summary()
        assert check_path(robot, r.path).certified
        for qa, qb in zip(r.path[:-1], r.path[1:]):
            assert not mujoco_contacts(robot, fine_poses(robot, qa, qb)).any()
        assert np.array_equal(r.path, plan_path(robot, a, b, seed=i, threads=1).path)
