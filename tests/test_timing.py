"""Timed paths (profrobot.time_path, python/profrobot/exact/timing.py): within the limits at
1 kHz, every sample free (MuJoCo's own collision), the derivatives what finite differences of
the positions give, blends proven or turned into stops, bad input refused by name."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot import InputError, mujoco_labels, time_path
from profrobot.exact.problems import hard_pairs
from profrobot.exact.timing import TimedPath

from conftest import scene

# A puck on two slides and a box inside the corner of an L-shaped path: the path's segments keep
# 5 cm from the box; a slow blend (a = 1 m/s², τ = 1 s) cuts the corner through it, a quick one
# (a = 10 m/s²) passes 3.75 cm away.
_PUCK = """
<mujoco>
  <worldbody>
    <geom name="block" type="box" pos="0.85 0.15 0" size="0.05 0.05 0.05"/>
    <body name="puck">
      <joint name="x" type="slide" axis="1 0 0" range="-0.2 1.2"/>
      <joint name="y" type="slide" axis="0 1 0" range="-0.2 1.2"/>
      <geom type="sphere" size="0.05"/>
    </body>
  </worldbody>
</mujoco>
"""
_L = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])


def puck():
    return profrobot.Robot.from_spec(mujoco.MjSpec.from_string(_PUCK), name="puck")


def _wrapped(d):
    return (d + np.pi) % (2 * np.pi) - np.pi


def _check_timed(robot, tp: TimedPath, v, a):
    t, q, qd, qdd = tp.at_rate(1000)
    assert t[0] == 0 and t[-1] == pytest.approx(tp.duration)
    assert (np.abs(qd) <= v * (1 + 1e-9)).all() and (np.abs(qdd) <= a * (1 + 1e-9)).all()
    assert np.abs(qd[0]).max() == 0 and np.abs(qd[-1]).max() < 1e-9          # at rest at both ends
    assert np.abs(_wrapped(q[0] - tp.waypoints[0])).max() < 1e-12
    assert np.abs(_wrapped(q[-1] - tp.waypoints[-1])).max() < 1e-9
    # The derivatives are those of the positions (central differences, 0.1 ms).
    mid = t[1:-1][::7]
    h = 1e-4
    qp, qm = tp.sample(mid + h)[0], tp.sample(mid - h)[0]
    assert np.abs(_wrapped(qp - qm) / (2 * h) - tp.sample(mid)[1]).max() < 1e-3 * (1 + v.max())
    # Each stop is reached at rest, on its waypoint.
    for i in np.flatnonzero(tp.stops):
        q_i, qd_i, _ = tp.sample(tp.times[i])
        assert np.abs(_wrapped(q_i - tp.waypoints[i])).max() < 1e-9 and np.abs(qd_i).max() < 1e-9
    # Free at every sample, by MuJoCo's collision and by the certificate.
    assert not mujoco_labels(robot, q).collides.any()
    assert profrobot.certify_poses(robot, q).all()


@pytest.mark.parametrize("name", ["panda_blocks", "ur5e_wall_box", "vx300s_clutter"])
def test_planned_paths_timed_within_limits_and_free(name):
    robot = scene(name)
    fresh = profrobot.scenes.load(name)     # (another model of the scene: it planned nothing)
    starts, goals = hard_pairs(robot, 6, seed=3)
    rng = np.random.default_rng(0)
    v = rng.uniform(0.5, 2.0, robot.njoint)
    a = rng.uniform(1.0, 5.0, robot.njoint)
    shorter = cut = 0
    for s, g in zip(starts, goals):
        res = profrobot.plan_path(robot, s, g)
        assert res.found and res.certified
        tp = time_path(robot, res.path, velocity=v, acceleration=a)
        stop = time_path(robot, res.path, velocity=v, acceleration=a, blend=False)
        assert tp.certified and stop.certified and stop.stops.all()
        _check_timed(robot, tp, v, a)
        _check_timed(robot, stop, v, a)
        assert tp.duration <= stop.duration * (1 + 1e-12)
        shorter += tp.duration < stop.duration * 0.999
        # corners cut: every waypoint timed lies on the planned path, the ends on its ends
        w = tp.waypoints
        assert _on_path(w, stop.waypoints).all() and (w[[0, -1]] == stop.waypoints[[0, -1]]).all()
        own = time_path(robot, res.path, velocity=v, acceleration=a, cut=0.0)
        assert own.certified and len(own.waypoints) == len(stop.waypoints)
        # the waypoints timed are the path's, bit for bit (but for continuous hinges, unwrapped)
        fixed = ~np.asarray(robot.continuous, dtype=bool)
        assert (own.waypoints[:, fixed] == res.path[:, fixed]).all()
        # a model that did not plan the path proves its parts itself: the same timed motions
        for mine, kw in ((tp, {}), (own, dict(cut=0.0))):
            theirs = time_path(fresh, res.path, velocity=v, acceleration=a, **kw)
            for f in ("waypoints", "starts", "q0", "v0", "acc", "times", "stops"):
                assert np.array_equal(getattr(mine, f), getattr(theirs, f)), f
            assert (mine.duration, mine.certified) == (theirs.duration, theirs.certified)
        assert tp.duration <= own.duration * (1 + 1e-12)
        cut += len(w) > len(stop.waypoints)
    assert shorter >= 1 and cut >= 1        # a corner blended saves time, a corner is cut


def test_a_blend_through_an_obstacle_becomes_a_stop():
    robot = puck()
    assert profrobot.check_path(robot, _L).certified
    slow = time_path(robot, _L, velocity=1.0, acceleration=1.0, cut=0.0)
    assert slow.certified and slow.stops.tolist() == [True, True, True]
    # (the blend it refused does cross the block)
    w, vin, vout, tau = _L[1], np.array([1.0, 0]), np.array([0, 1.0]), 1.0
    cut = profrobot.certify_motions(robot, w - vin * tau / 2, w + vout * tau / 2, via=w)
    assert cut.blocked[0]
    quick = time_path(robot, _L, velocity=1.0, acceleration=10.0, cut=0.0)
    assert quick.certified and quick.stops.tolist() == [True, False, True]
    for tp, a in ((slow, 1.0), (quick, 10.0)):
        _check_timed(robot, tp, np.ones(2), np.full(2, a))
    # The quick blend leaves the corner: it does not pass through the waypoint.
    q_corner = quick.sample(quick.times[1])[0]
    assert np.linalg.norm(q_corner - _L[1]) > 1e-3
    # Durations, by hand: the stop at the corner costs v/a = 1 s more than the blend.
    assert slow.duration == pytest.approx(1 + 1 + 1 + 1)          # two segments of 1 m, each 1 s + v/a
    assert quick.duration == pytest.approx(2 + 0.1)


def _on_path(q, w, tol=1e-12):
    """Whether each pose of ``q`` (N, K) lies on a segment of the polyline ``w`` (M, K)."""
    out = []
    for p in q:
        best = np.inf
        for a, b in zip(w[:-1], w[1:]):
            d = b - a
            s = np.clip((p - a) @ d / (d @ d), 0.0, 1.0)
            best = min(best, np.abs(a + s * d - p).max())
        out.append(best <= tol)
    return np.array(out)


def test_a_corner_is_cut_by_the_widest_proven_chord():
    # The L's corner cut: joint x leads the first segment and y the second, so the chord from
    # (0.5, 0) to (1, 0.5) takes 0.5 s at v = 1 where the two half-segments take 1 s.
    robot = puck()
    cut = time_path(robot, _L, velocity=1.0, acceleration=10.0)
    own = time_path(robot, _L, velocity=1.0, acceleration=10.0, cut=0.0)
    assert cut.certified and cut.waypoints.tolist() == [[0, 0], [0.5, 0], [1, 0.5], [1, 1]]
    assert cut.duration < own.duration - 0.4
    _check_timed(robot, cut, np.ones(2), np.full(2, 10.0))
    # A block on that chord (and 7 cm from the quarter's): the corner is cut by a quarter.
    spec = mujoco.MjSpec.from_string(_PUCK.replace('pos="0.85 0.15 0"', 'pos="0.78 0.28 0"'))
    blocked = profrobot.Robot.from_spec(spec, name="puck2")
    half = profrobot.certify_motions(blocked, [0.5, 0.0], [1.0, 0.5])
    assert half.blocked[0]
    tp = time_path(blocked, _L, velocity=1.0, acceleration=10.0)
    assert tp.certified and tp.waypoints.tolist() == [[0, 0], [0.75, 0], [1, 0.25], [1, 1]]
    _check_timed(blocked, tp, np.ones(2), np.full(2, 10.0))
    assert tp.duration < time_path(blocked, _L, velocity=1.0, acceleration=10.0, cut=0.0).duration
    # With a jerk limit, or without blends, nothing is cut.
    assert len(time_path(robot, _L, velocity=1.0, acceleration=10.0, jerk=100.0).waypoints) == 3
    assert len(time_path(robot, _L, velocity=1.0, acceleration=10.0, blend=False).waypoints) == 3


def test_a_blocked_corner_the_chords_bypass_is_certified():
    # A block on the L's corner: both segments run into it, while the chord between their
    # middles passes 0.35 m from it. What the robot crosses is proven, not the path given.
    spec = mujoco.MjSpec.from_string(_PUCK.replace('pos="0.85 0.15 0"', 'pos="1.0 0.0 0"'))
    robot = profrobot.Robot.from_spec(spec, name="puck3")
    assert not profrobot.check_path(robot, _L).certified
    tp = time_path(robot, _L, velocity=1.0, acceleration=10.0)
    assert tp.certified and tp.waypoints.tolist() == [[0, 0], [0.5, 0], [1, 0.5], [1, 1]]
    _check_timed(robot, tp, np.ones(2), np.full(2, 10.0))
    own = time_path(robot, _L, velocity=1.0, acceleration=10.0, cut=0.0)
    assert not own.certified and "segment 0" in own.reason and "blocked" in own.reason


def test_jerk_limited_moves_are_the_textbook_double_s_and_stay_on_the_path():
    # Biagiotti & Melchiorri, Trajectory Planning for Automatic Machines and Robots, example
    # 3.9: 10 units at v 5, a 10, j 30 take T = 2.8333 s (T_j = 1/3, T_a = 0.8333, T_v = 1.1667).
    robot = puck()
    line = np.array([[0.0, 0.0], [1.0, 0.0]])
    tp = time_path(robot, line, velocity=0.5, acceleration=1.0, jerk=3.0)
    assert tp.duration == pytest.approx(17 / 6, abs=1e-12)
    assert np.diff(tp.starts).round(12).tolist()[:3] == [round(1 / 3, 12), round(1 / 6, 12), round(1 / 3, 12)]
    # Too short to reach v (then a): the peak speed solves the distance (checked by sampling).
    for length, v, a, j in ((0.1, 1.0, 1.0, 3.0), (0.01, 1.0, 1.0, 3.0), (1.0, 0.5, 1.0, 1000.0)):
        seg = np.array([[0.0, 0.0], [length, 0.0]])
        tp = time_path(robot, seg, velocity=v, acceleration=a, jerk=j)
        t, q, qd, qdd = tp.at_rate(20000)
        assert q[-1, 0] == pytest.approx(length, abs=1e-12) and (np.diff(q[:, 0]) >= -1e-15).all()
        assert qd[:, 0].max() <= v * (1 + 1e-12) and np.abs(qdd).max() <= a * (1 + 1e-12)
        # time-optimal: a bang-bang profile touches a limit in every phase; the jerk limit at the start
        assert np.abs(tp.jrk[0, 0]) == pytest.approx(j)
    # A huge jerk limit gives the trapezoid's duration back.
    assert time_path(robot, _L, velocity=1.0, acceleration=1.0, jerk=1e9).duration == pytest.approx(
        time_path(robot, _L, velocity=1.0, acceleration=1.0, blend=False).duration, abs=1e-6)
    # On planned paths: within every limit at 1 kHz, jerk by finite differences of acceleration,
    # stopping at every waypoint, on the certified segments.
    arm = scene("panda_blocks")
    starts, goals = hard_pairs(arm, 3, seed=5)
    rng = np.random.default_rng(1)
    v, a, j = rng.uniform(0.5, 2.0, arm.njoint), rng.uniform(1.0, 5.0, arm.njoint), rng.uniform(5.0, 40.0, arm.njoint)
    for s, g in zip(starts, goals):
        res = profrobot.plan_path(arm, s, g)
        tp = time_path(arm, res.path, velocity=v, acceleration=a, jerk=j)
        assert tp.certified and tp.stops.all() and tp.duration > time_path(arm, res.path, velocity=v,
                                                                            acceleration=a).duration
        _check_timed(arm, tp, v, a)
        t, q, qd, qdd = tp.at_rate(1000)
        assert (np.abs(np.diff(qdd, axis=0)) * 1000 <= j * (1 + 1e-9)).all()
        np.testing.assert_array_equal(tp.jerk, j)
        # every sample on the segment between its waypoints: q = W_i + D_i·s, s in [0, 1]
        seg = np.clip(np.searchsorted(tp.times, t, side="right") - 1, 0, len(tp.times) - 2)
        d = tp.waypoints[seg + 1] - tp.waypoints[seg]
        s_ = np.einsum("tk,tk->t", q - tp.waypoints[seg], d) / np.einsum("tk,tk->t", d, d)
        assert (s_ >= -1e-9).all() and (s_ <= 1 + 1e-9).all()
        assert np.abs(q - tp.waypoints[seg] - s_[:, None] * d).max() < 1e-9


def test_an_uncertified_path_is_timed_and_says_so():
    robot = puck()
    through = np.array([[0.6, 0.15], [1.1, 0.15]])
    tp = time_path(robot, through, velocity=1.0, acceleration=1.0)
    assert not tp.certified and "segment 0" in tp.reason


def test_saved_loaded_pickled_and_refused_for_another_robot(tmp_path, panda):
    robot = puck()
    for jerk in (None, 7.0):
        tp = time_path(robot, _L, velocity=[1.0, 0.5], acceleration=10.0, jerk=jerk)
        path = tp.save(tmp_path / "l.npz")
        back = TimedPath.load(path, robot)
        t = np.linspace(0, tp.duration, 57)
        for x, y in zip(tp.sample(t), back.sample(t)):
            np.testing.assert_array_equal(x, y)
        for x, y in zip(tp.sample(t), pickle.loads(pickle.dumps(tp)).sample(t)):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(back.jerk, tp.jerk)
    with pytest.raises(profrobot.RobotMismatchError):
        TimedPath.load(path, panda)
    assert not list(tmp_path.glob(".*tmp*"))


@pytest.mark.parametrize("kwargs, words", [
    (dict(acceleration=1.0), "velocity is required"),
    (dict(velocity=1.0), "acceleration is required"),
    (dict(velocity=-1.0, acceleration=1.0), "velocity[0] (x)"),
    (dict(velocity=[1.0, 0.0], acceleration=1.0), "velocity[1] (y)"),
    (dict(velocity=1.0, acceleration=[1.0, np.nan]), "acceleration[1] (y)"),
    (dict(velocity=[1.0, 1.0, 1.0], acceleration=1.0), "velocity must be a number or 2 numbers"),
    (dict(velocity="fast", acceleration=1.0), "velocity must be a number"),
    (dict(velocity=1.0, acceleration=1.0, blend="yes"), "blend must be True or False"),
    (dict(velocity=1.0, acceleration=1.0, cut=0.6), "cut must be a share of each segment in [0, 0.5]"),
    (dict(velocity=1.0, acceleration=1.0, cut=-0.1), "cut must be a non-negative number"),
    (dict(velocity=1.0, acceleration=1.0, cut="half"), "cut must be a non-negative number"),
    (dict(velocity=1.0, acceleration=1.0, jerk=0.0), "jerk[0] (x)"),
    (dict(velocity=1.0, acceleration=1.0, jerk=[1.0, np.inf]), "jerk[1] (y)"),
    (dict(velocity=1.0, acceleration=1.0, threads=0), "threads must be a positive integer"),
])
def test_bad_input_refused_by_name(kwargs, words):
    with pytest.raises(InputError) as e:
        time_path(puck(), _L, **kwargs)
    assert words in str(e.value)


def test_the_crew_woken_ahead_changes_no_timing(panda):
    # time_path wakes the crew's helpers before its checks (_core.crew_awake); a guard held
    # across calls, on the thread counts it wakes for and those it does not, times every path
    # as a call on one thread does, bit for bit.
    from profrobot._core import crew_awake

    starts, goals = hard_pairs(panda, 3, seed=4)
    path = np.concatenate([profrobot.plan_path(panda, s, g).path for s, g in zip(starts, goals)])
    one = time_path(panda, path, velocity=1.5, acceleration=3.0, threads=1)
    for n in (2, 3, 1, None):
        held = crew_awake(n)
        for threads in (2, 1):
            tp = time_path(panda, path, velocity=1.5, acceleration=3.0, threads=threads)
            assert tp.duration == one.duration and np.array_equal(tp.q0, one.q0) and np.array_equal(tp.acc, one.acc)
        del held
    with pytest.raises(InputError, match="threads must be at least 1"):
        crew_awake(0)


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="the crew's helpers are steered off the caller's CPU only with two CPUs or more")
def test_a_refused_call_leaves_no_helper_steered(panda):
    # time_path wakes the crew before its checks, steering the helpers off its CPU; a call
    # refused after that, its traceback (which keeps the call's frame) held, gives them back.
    allowed = os.sched_getaffinity(0)
    q = panda.joint_limits.mean(axis=1)
    time_path(panda, [q, q + np.eye(panda.njoint)[0] * 0.1], velocity=1.5, acceleration=3.0, threads=2)
    with pytest.raises(InputError) as refused:
        time_path(panda, [[0.0] * panda.njoint] * 2, velocity=-1.0, acceleration=3.0, threads=2)
    helpers = [int(t.name) for t in Path("/proc/self/task").iterdir()
               if (t / "comm").read_text().startswith("profrobot-crew")]
    assert helpers and refused.value
    assert all(os.sched_getaffinity(t) == allowed for t in helpers)


def test_zero_length_segments_are_dropped():
    # Repeated waypoints (0.0 and -0.0 are one value) time as the path without them, bit for bit.
    robot = puck()
    ref = time_path(robot, _L, velocity=1.0, acceleration=10.0)
    dup = time_path(robot, [[0.0, 0.0], [-0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 1.0], [1.0, 1.0]],
                    velocity=1.0, acceleration=10.0)
    assert dup.duration == ref.duration and dup.certified
    assert np.array_equal(dup.waypoints, ref.waypoints) and np.array_equal(dup.q0, ref.q0)


def test_bad_path_and_times_refused_by_name():
    robot = puck()
    with pytest.raises(InputError, match="path"):
        time_path(robot, [[0.0, 0.0], [np.inf, 0.0]], velocity=1.0, acceleration=1.0)
    with pytest.raises(InputError, match="path"):
        time_path(robot, [[0.0, 0.0], [5.0, 0.0]], velocity=1.0, acceleration=1.0)   # beyond the slide's range
    tp = time_path(robot, _L, velocity=1.0, acceleration=1.0)
    with pytest.raises(InputError, match="t must be"):
        tp.sample([0.0, np.nan])
    with pytest.raises(InputError, match="hz"):
        tp.at_rate(0)
    one = time_path(robot, _L[:1], velocity=1.0, acceleration=1.0)
    assert one.duration == 0 and one.certified
