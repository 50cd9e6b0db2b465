"""profrobot.collides, the booleans-only fast path: the same answer as label_poses, bit for bit."""

import numpy as np
import pytest

import profrobot
from conftest import scene


def check_same_as_labels(name: str, n: int, seed: int) -> None:
    robot = scene(name)
    poses = profrobot.sample_poses(robot, n, seed)
    want = profrobot.label_poses(robot, poses).collides
    got = profrobot.collides(robot, poses)
    assert got.dtype == np.bool_ and got.shape == (n,)
    bad = np.flatnonzero(got != want)
    assert bad.size == 0, f"{name}: {bad.size} poses differ, first {bad[:5]}"
    # Both classes are exercised.
    assert 0 < want.sum() < n


@pytest.mark.parametrize("name", profrobot.scenes.names())
def test_same_answer_as_label_poses(name):
    check_same_as_labels(name, 5000, seed=21)


@pytest.mark.parametrize("name", profrobot.scenes.names())
def test_same_answer_as_label_poses_on_100k_poses(name):
    check_same_as_labels(name, 100_000, seed=22)


def test_one_and_two_threads_agree_and_single_pose(panda):
    poses = profrobot.sample_poses(panda, 3000, seed=4)
    one = profrobot.collides(panda, poses, threads=1)
    two = profrobot.collides(panda, poses, threads=2)
    assert (one == two).all()
    assert (profrobot.collides(panda, poses) == one).all()
    # A single pose (K,) is a batch of one; any memory layout reads the same rows.
    assert profrobot.collides(panda, poses[7]).tolist() == [one[7]]
    assert (profrobot.collides(panda, np.asfortranarray(poses[::-2])) == one[::-2]).all()


def test_nearby_poses_along_a_path(panda):
    # Poses close together (the fast path tries the last hit pair first): still exact.
    a, b = profrobot.sample_poses(panda, 2, seed=9)
    path = a + np.linspace(0, 1, 2001)[:, None] * (b - a)
    assert (profrobot.collides(panda, path, threads=1) == profrobot.label_poses(panda, path).collides).all()


@pytest.mark.parametrize("poses, exc, match", [
    (np.zeros((4, 5)), ValueError, r"shape \(B, 9\)"),
    (np.zeros((0, 9)), ValueError, "empty"),
    (np.zeros((3, 9), dtype=np.complex128), TypeError, "floating-point"),
    (np.full((2, 9), np.nan), ValueError, r"poses\[0, 0\].*finite"),
])
def test_bad_poses(panda, poses, exc, match):
    with pytest.raises(exc, match=match):
        profrobot.collides(panda, poses)


def test_bad_threads_limits_and_robot(panda):
    mid = panda.joint_limits.mean(1)[None]
    with pytest.raises(ValueError, match="threads"):
        profrobot.collides(panda, mid, threads=0)
    pose = mid.copy()
    pose[0, 3] = 1.0  # outside joint4's range
    profrobot.collides(panda, pose, check_limits=False)   # asked for
    with pytest.raises(ValueError, match="outside the limits of joint 'joint4'"):
        profrobot.collides(panda, pose)
    with pytest.raises(TypeError, match="profrobot.Robot"):
        profrobot.collides("panda", np.zeros((1, 9)))


def test_native_binding_rejects_bad_arrays_without_panicking(panda):
    with pytest.raises(TypeError, match="float64"):
        panda.core.collides(np.zeros((2, 9), dtype=np.float32))
    with pytest.raises(ValueError, match=r"shape \(B, 9\)"):
        panda.core.collides(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="not finite"):
        panda.core.collides(np.full((1, 9), np.inf))
    with pytest.raises(ValueError, match="threads"):
        panda.core.collides(np.zeros((1, 9)), threads=0)
