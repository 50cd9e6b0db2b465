"""``first_contact``: where a straight motion first stops being free, exact to its tolerance (the
continuous certificate bisected), checked against MuJoCo's contacts along a dense replay."""

from __future__ import annotations

import numpy as np
import pytest

import profrobot
from profrobot.exact import problems


@pytest.fixture(scope="module")
def robot():
    return profrobot.scenes.load("panda_blocks")


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_first_contact_of_a_motion_into_an_obstacle(robot, seed):
    a = problems.free_poses(robot, 1, seed=10 + seed)[0]
    b = problems.colliding_poses(robot, 1, seed=20 + seed)[0]
    fc = profrobot.first_contact(robot, a, b, tolerance=1e-6)
    assert not fc.certified and 0.0 <= fc.free_until <= fc.t <= 1.0 and fc.t - fc.free_until <= 1e-6
    # proven free up to free_until; the pose at t is not certified free
    assert profrobot.certify_motions(robot, a, fc.before).certified[0]
    # the certificate's blocked pose is a blocked pose, not necessarily the first
    cert = profrobot.certify_motions(robot, a, b)
    assert cert.blocked_at[0] >= fc.t - 1e-9
    # MuJoCo along a dense replay of the same motion: no contact before free_until, one soon after t
    n = 20_000
    dense = profrobot.interpolate(robot, a, b, n + 1)
    hit = profrobot.mujoco_labels(robot, dense, progress=False).collides
    first = np.flatnonzero(hit)[0] / n
    assert fc.free_until - 1e-12 <= first <= fc.t + 5e-3, (fc.free_until, fc.t, first)
    if fc.pairs:
        assert all(isinstance(g, str) for pair in fc.pairs for g in pair)


def test_a_free_motion_has_no_first_contact(robot):
    a, b = problems.free_poses(robot, 2, seed=3)
    b = a + 0.01 * (b - a)
    fc = profrobot.first_contact(robot, a, b)
    assert fc.certified and np.isnan(fc.t) and fc.free_until == 1.0 and fc.pose is None


def test_first_contact_refuses_bad_input_by_name(robot):
    a, b = problems.free_poses(robot, 2, seed=4)
    with pytest.raises(profrobot.InputError, match="tolerance"):
        profrobot.first_contact(robot, a, b, tolerance=0.0)
    with pytest.raises(profrobot.InputError, match="start and goal must each be one pose"):
        profrobot.first_contact(robot, np.stack([a, b]), np.stack([a, b]))
