"""profrobot.nearest_free, the Δθ oracle: free answers, within limits, no farther than the
nearest free pose random sampling finds, deterministic."""

import numpy as np
import pytest

import profrobot
from conftest import scene


def colliding(robot, n, seed):
    poses = profrobot.sample_poses(robot, 20 * n, seed)
    return poses[profrobot.collides(robot, poses)][:n]


def nearest_sampled_free(robot, poses, seed=0, per_scale=300):
    """The nearest free pose among Gaussian perturbations of each pose at several scales."""
    lim, limited = robot.joint_limits, ~robot.continuous
    rng = np.random.default_rng(seed)
    best = np.full(len(poses), np.inf)
    for scale in (0.02, 0.05, 0.1, 0.2, 0.4, 0.8):
        c = poses[:, None, :] + scale * rng.standard_normal((len(poses), per_scale, poses.shape[1]))
        c = np.where(limited, np.clip(c, lim[:, 0], lim[:, 1]), c)
        free = ~profrobot.collides(robot, c.reshape(-1, poses.shape[1])).reshape(len(poses), -1)
        d = np.linalg.norm(c - poses[:, None, :], axis=2)
        best = np.minimum(best, np.where(free, d, np.inf).min(1))
    return best


@pytest.mark.parametrize("name", ["panda_blocks", "ur5e_wall_box"])
def test_answers_are_free_within_limits_and_beat_sampling(name):
    robot = scene(name)
    q = colliding(robot, 12, seed=31)
    out = profrobot.nearest_free(robot, q, seed=2)
    assert out.poses.shape == q.shape and out.distance.shape == out.checks.shape == (len(q),)
    # Every answer is a free pose, exactly (the labeller's word), at the distance reported.
    assert np.isfinite(out.distance).all() and (out.distance > 0).all()
    assert not profrobot.label_poses(robot, out.poses).collides.any()
    assert np.allclose(np.linalg.norm(out.poses - q, axis=1), out.distance, rtol=0, atol=1e-12)
    lim, limited = robot.joint_limits, ~robot.continuous
    assert (((out.poses >= lim[:, 0]) & (out.poses <= lim[:, 1])) | ~limited).all()
    # No farther than the nearest of 1800 sampled free perturbations, but for the odd pose.
    ratio = out.distance / nearest_sampled_free(robot, q)
    assert np.median(ratio) < 0.95 and (ratio <= 1.1).mean() >= 0.9, np.round(ratio, 3)
    assert (out.checks > 1).all()


def test_free_poses_are_their_own_answer_and_threads_do_not_matter(panda):
    poses = profrobot.sample_poses(panda, 60, seed=8)
    hit = profrobot.collides(panda, poses)
    assert hit.any() and (~hit).any()
    one = profrobot.nearest_free(panda, poses, directions=16, refine=32, threads=1, seed=5)
    two = profrobot.nearest_free(panda, poses, directions=16, refine=32, threads=2, seed=5)
    for a, b in ((one.distance, two.distance), (one.poses, two.poses), (one.checks, two.checks)):
        assert np.array_equal(a, b)
    assert (one.distance[~hit] == 0).all() and np.array_equal(one.poses[~hit], poses[~hit])
    assert (one.distance[hit] > 0).all()
    other = profrobot.nearest_free(panda, poses[hit], directions=16, refine=32, seed=6)
    assert not np.array_equal(other.distance, one.distance[hit])


def test_more_search_never_hurts_much_and_single_pose(panda):
    q = colliding(panda, 6, seed=41)
    quick = profrobot.nearest_free(panda, q, directions=8, refine=16)
    thorough = profrobot.nearest_free(panda, q, directions=128, refine=512)
    assert np.median(thorough.distance / quick.distance) <= 1.0
    assert thorough.checks.sum() > quick.checks.sum()
    single = profrobot.nearest_free(panda, q[0], directions=8, refine=16)
    assert single.poses.shape == (1, 9) and single.distance[0] == quick.distance[0]


@pytest.mark.parametrize("kwargs, match", [
    (dict(directions=0), "directions must be a positive integer"),
    (dict(directions=2.5), "directions"),
    (dict(refine=-1), "refine"),
    (dict(step=0.0), "step must be a positive"),
    (dict(tolerance=np.nan), "tolerance"),
    (dict(step=0.01, tolerance=0.02), "must not exceed step"),
    (dict(max_distance=-1.0), "max_distance"),
    (dict(seed=-1), "seed"),
    (dict(threads=0), "threads"),
])
def test_bad_arguments(panda, kwargs, match):
    mid = panda.joint_limits.mean(1)
    with pytest.raises(ValueError, match=match):
        profrobot.nearest_free(panda, mid, **kwargs)


def test_bad_poses(panda):
    pose = panda.joint_limits.mean(1)[None].copy()
    pose[0, 3] = 1.0  # outside joint4's range: the oracle moves poses within the limits only
    with pytest.raises(ValueError, match="outside the limits of joint 'joint4'"):
        profrobot.nearest_free(panda, pose)
    with pytest.raises(ValueError, match="finite"):
        profrobot.nearest_free(panda, np.full((1, 9), np.nan))
    with pytest.raises(TypeError, match="floating-point"):
        profrobot.nearest_free(panda, np.zeros((1, 9), dtype=complex))
    # The native layer names the problem too, rather than panicking.
    with pytest.raises(ValueError, match="outside its limits"):
        panda.core.nearest_free(pose)
    with pytest.raises(ValueError, match="directions"):
        panda.core.nearest_free(panda.joint_limits.mean(1)[None], directions=0)
