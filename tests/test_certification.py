"""One definition of "certified" (issue 19): no contact and every candidate pair more than
CLEARANCE apart, computed the cheap way (fast path first) with the same verdict as labelling
every pose with distances; paths, planner results and the oracle use the same rule."""

import numpy as np
import pytest

import profrobot
from profrobot.exact import certification
from profrobot.exact.certification import CLEARANCE, certify_poses, check_path, path_free_at


def _by_definition(robot, poses):
    lab = profrobot.label_poses(robot, poses, distance=True)
    return ~lab.collides & (lab.min_distance > CLEARANCE)


def test_certify_poses_is_the_definition(panda):
    poses = profrobot.sample_poses(panda, 3000, seed=3)
    got = certify_poses(panda, poses)
    assert got.dtype == bool and got.shape == (3000,)
    np.testing.assert_array_equal(got, _by_definition(panda, poses))
    assert got.any() and (~got).any()


@pytest.mark.parametrize("scene", profrobot.scenes.names())
def test_certify_poses_is_the_definition_near_contact(scene):
    """The fast path's verdict pair by pair (``RobotModel.certified``) against labelling with
    distances, on poses packed around contact in every bundled scene: each of 24 segments from a
    free to a colliding pose bisected to its contact point, then poses stepped from it so that
    their closest pair is from -1e-5 to 1e-5 m away, many within CLEARANCE."""
    robot = profrobot.scenes.load(scene)
    a = profrobot.exact.problems.free_poses(robot, 24, seed=7)
    b = profrobot.exact.problems.colliding_poses(robot, 24, seed=7)
    lo, hi = np.zeros(24), np.ones(24)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        hit = profrobot.collides(robot, a + mid[:, None] * (b - a))
        hi = np.where(hit, mid, hi)
        lo = np.where(hit, lo, mid)
    d = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    steps = np.concatenate([-np.geomspace(1e-4, 1e-9, 12), [0.0], np.geomspace(1e-9, 1e-4, 12)])
    poses = ((a + hi[:, None] * (b - a))[:, None, :] + steps[None, :, None] * d[:, None, :]).reshape(-1, robot.njoint)
    lim = robot.joint_limits
    poses = np.clip(poses, lim[:, 0], lim[:, 1])
    want = _by_definition(robot, poses)
    lab = profrobot.label_poses(robot, poses, distance=True)
    assert ((np.abs(lab.min_distance) <= CLEARANCE) & ~lab.collides).sum() >= 10   # free but within the clearance
    assert want.any() and (~want).any()
    np.testing.assert_array_equal(certify_poses(robot, poses), want)
    np.testing.assert_array_equal(certify_poses(robot, poses, threads=1), want)


def test_touching_is_not_certified(panda):
    """A pose the labels call free but whose closest pair is within CLEARANCE: bisect from a free
    to a colliding pose until the distance is below the clearance."""
    free = profrobot.exact.problems.free_poses(panda, 1, seed=0)[0]
    hit = profrobot.exact.problems.colliding_poses(panda, 1, seed=0)[0]
    a, b = free, hit
    for _ in range(80):
        m = 0.5 * (a + b)
        if profrobot.collides(panda, m[None])[0]:
            b = m
        else:
            a = m
    lab = profrobot.label_poses(panda, a[None], distance=True)
    assert not lab.collides[0] and lab.min_distance[0] <= CLEARANCE
    assert not certify_poses(panda, a[None])[0]          # free to the labels, not certified


def test_paths_use_the_same_rule(panda):
    s, g = profrobot.exact.problems.hard_pairs(panda, 1, seed=0, steps=20)
    path = profrobot.interpolate(panda, s[0], g[0], 20)
    chk = check_path(panda, path, density=5)
    np.testing.assert_array_equal(chk.dense_uncertified, ~_by_definition(panda, chk.dense))
    assert not chk.certified and chk.segment_uncertified.any()
    assert not path_free_at(panda, path, 0.01)


def test_planner_and_oracle_report_the_same_certificate(panda):
    s, g = profrobot.exact.problems.hard_pairs(panda, 1, seed=1, steps=20)
    res = profrobot.plan_path(panda, s[0], g[0], max_time=20.0, seed=0)
    assert res.found
    assert res.certified == path_free_at(panda, res.path, 0.01)
    hit = profrobot.exact.problems.colliding_poses(panda, 4, seed=5)
    near = profrobot.nearest_free(panda, hit, directions=32, refine=32)
    found = np.isfinite(near.distance)
    np.testing.assert_array_equal(near.certified[found], certify_poses(panda, near.poses[found]))
    assert not near.certified[~found].any()


def test_certified_summary_and_failures():
    assert "not checked" in certification.certified_summary(None)
    assert certification.failures_of(None) is None
    assert certification.failures_of(np.array([True, False, True])).tolist() == [1]
