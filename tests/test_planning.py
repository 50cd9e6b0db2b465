"""Global planning over the exact labeller (issue 12): plan_path, resampling, certification."""

from __future__ import annotations

import re

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot.exact.planning import plan_path, resample_path, so2_length
from profrobot.exact.problems import hard_pairs

from conftest import scene
from profrobot.robot.angles import wrap
from profrobot.exact.labels import so2_steps


def _dense_free(robot, path, resolution=0.01, factor=10) -> bool:
    """Every segment re-interpolated ``factor``x denser than the planner's checks."""
    for a, b in zip(path[:-1], path[1:]):
        d = so2_steps(robot, np.stack([a, b]))[0]
        steps = int(np.ceil(np.abs(d).max() / resolution * factor)) + 1
        if profrobot.label_poses(robot, profrobot.interpolate(robot, a, b, max(steps, 2))).collides.any():
            return False
    return True


def _mujoco_free(robot, poses) -> bool:
    m = robot.mj_model
    d = mujoco.MjData(m)
    for q in poses:
        d.qpos[robot.qpos_adr] = q
        mujoco.mj_forward(m, d)
        if d.ncon:
            return False
    return True


@pytest.mark.parametrize("name", ["ur5e_wall_box", "panda_blocks"])
def test_hard_problems_are_solved_and_certified(name):
    robot = scene(name)
    starts, goals = hard_pairs(robot, 4, seed=11)
    for i, (s, g) in enumerate(zip(starts, goals)):
        res = plan_path(robot, s, g, seed=i, max_time=20.0)
        assert res.found, res.summary()
        np.testing.assert_allclose(res.path[0], s, atol=1e-12)
        wrapped = wrap(res.path[-1] - g)
        np.testing.assert_allclose(np.where(robot.continuous, wrapped, res.path[-1] - g), 0, atol=1e-12)
        assert _dense_free(robot, res.path)
        dense = resample_path(robot, res.path, max(100, len(res.path)))
        assert _mujoco_free(robot, dense)
        assert so2_length(robot, dense) == pytest.approx(so2_length(robot, res.path), rel=1e-9)


def test_same_seed_same_path_on_one_and_two_threads():
    robot = scene("ur5e_wall_box")
    starts, goals = hard_pairs(robot, 2, seed=12)
    for s, g in zip(starts, goals):
        one = plan_path(robot, s, g, seed=3, threads=1)
        two = plan_path(robot, s, g, seed=3, threads=2)
        assert one.found and two.found
        np.testing.assert_array_equal(one.path, two.path)
        assert (one.checks, one.iterations, one.tree_sizes) == (two.checks, two.iterations, two.tree_sizes)


def test_straight_path_is_returned_when_free():
    robot = scene("panda_blocks")
    q = profrobot.exact.problems.free_poses(robot, 1, seed=5)[0]
    res = plan_path(robot, q, q + 1e-3 * np.sign(robot.joint_limits.mean(axis=1) - q))
    assert res.status == "direct" and len(res.path) == 2


_WALLED = """
<mujoco>
  <worldbody>
    <geom name="wall" type="box" pos="0 0 0" size="0.05 2 2"/>
    <body name="ball" pos="0 0 0">
      <joint name="x" type="slide" axis="1 0 0" range="-1 1"/>
      <joint name="y" type="slide" axis="0 1 0" range="-1 1"/>
      <geom type="sphere" size="0.1"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_enclosed_goal_reports_none_found_within_max_time():
    robot = profrobot.Robot.from_spec(mujoco.MjSpec.from_string(_WALLED), name="walled")
    # the budget ends it (status time_out), not a hang; no wall-clock assertion in a test
    res = plan_path(robot, [-0.5, 0.0], [0.5, 0.0], max_time=0.5)
    assert not res.found and res.status == "time_out" and "enclosed" in res.reason and res.path.shape == (0, 2)
    res = plan_path(robot, [-0.5, 0.0], [0.5, 0.0], iterations=200, max_time=60)
    assert not res.found and res.status == "iteration_limit"
    assert plan_path(robot, [-0.5, 0.0], [-0.5, 0.9]).found


def test_bad_input():
    robot = scene("ur5e_wall_box")
    free = profrobot.exact.problems.free_poses(robot, 2, seed=1)
    coll = profrobot.exact.problems.colliding_poses(robot, 1, seed=1)[0]
    # (the core refuses the end; the message names a pair in contact, as the labeller finds it)
    pair = " / ".join(robot.pair_names(int(profrobot.label_poses(robot, coll[None], pairs=True).colliding_pairs[0, 1])))
    with pytest.raises(profrobot.errors.InputError, match=f"start collides .*{re.escape(pair)}"):
        plan_path(robot, coll, free[0])
    with pytest.raises(profrobot.errors.InputError, match=f"goal collides .*{re.escape(pair)}"):
        plan_path(robot, free[0], coll)
    bad = free[1].copy()
    bad[1] = 10.0
    with pytest.raises(ValueError, match="outside the limits"):
        plan_path(robot, free[0], bad)
    with pytest.raises(ValueError, match=r"shape \(B, 6\)"):
        plan_path(robot, free[0], free[1][:5])
    nan = free[1].copy()
    nan[2] = np.nan
    with pytest.raises(ValueError, match=r"goal\[0, 2\]"):
        plan_path(robot, free[0], nan)
    with pytest.raises(ValueError, match="max_time must be a positive number"):
        plan_path(robot, free[0], free[1], max_time=0)
    with pytest.raises(ValueError, match="resolution"):
        plan_path(robot, free[0], free[1], resolution=-1.0)
    with pytest.raises(ValueError, match="one pose"):
        plan_path(robot, free, free)
    with pytest.raises(ValueError, match="steps"):
        resample_path(robot, free, 1)


def test_plan_trajectory_falls_back_to_the_planner_and_smooths_without_losing_certification():
    robot = scene("ur5e_wall_box")
    starts, goals = hard_pairs(robot, 3, seed=13)
    exact = profrobot.plan_trajectories(None, starts, goals, robot=robot, steps=60)
    assert all(r.certified and r.init == "planner" and r.method == "planner" for r in exact)
    sdf = profrobot.train_sdf(robot, hidden=(64, 64), n_poses=20_000, iterations=60, batch_size=1024,
                              progress=False, seed=0)
    smoothed = profrobot.plan_trajectories(sdf, starts, goals, steps=60, smooth_iterations=60, penalty=profrobot.optim.PenaltyOptions(check_every=10))
    for r, e in zip(smoothed, exact):
        assert r.certified and r.init == "planner" and r.planner.found
        assert r.length <= r.length_before + 1e-9          # the shortest certified iterate, never longer
        assert _mujoco_free(robot, r.path)
        np.testing.assert_allclose(r.path[0], e.path[0]) and np.testing.assert_allclose(r.path[-1], e.path[-1])
    with pytest.raises(ValueError, match="needs robot="):
        profrobot.plan_trajectory(None, starts[0], goals[0])
    with pytest.raises(ValueError, match="init must be one of"):
        profrobot.plan_trajectory(sdf, starts[0], goals[0], init="global")
