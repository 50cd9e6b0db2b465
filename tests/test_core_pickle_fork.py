"""The native RobotModel across processes (issue 9, part 4): pickled (serde state, exact to the
bit) and used in a child forked after the parent labelled poses (one rayon pool per thread
count, forgotten in a forked child). Regression tests are named after the bug they pin."""

from __future__ import annotations

import copy
import multiprocessing
import pickle

import numpy as np
import pytest

import profrobot
from profrobot import _core

from conftest import scene

N = 20_000
TIMEOUT_S = 60


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    """Byte-identical label dicts (keys, dtypes, shapes, bytes)."""
    return a.keys() == b.keys() and all(
        a[k].dtype == b[k].dtype and a[k].shape == b[k].shape and a[k].tobytes() == b[k].tobytes() for k in a)


@pytest.fixture(scope="module")
def panda_poses():
    robot = scene("panda_blocks")
    return robot, profrobot.sample_poses(robot, N, seed=11)


def test_pickle_round_trip_labels_byte_identical(panda_poses):
    robot, q = panda_poses
    core = robot.core
    want = core.label(q, pairs=True, distance=True)
    for protocol in (2, pickle.HIGHEST_PROTOCOL):
        back = pickle.loads(pickle.dumps(core, protocol=protocol))
        assert isinstance(back, _core.RobotModel) and back is not core
        assert _same(back.label(q, pairs=True, distance=True), want)
    back = pickle.loads(pickle.dumps(core))
    assert (back.njoint, back.nbody, back.ngeom, back.npair) == (core.njoint, core.nbody, core.ngeom, core.npair)
    for got, ref in zip(back.pairs(), core.pairs()):
        assert got.tobytes() == ref.tobytes()
    assert back.sampling_ranges().tobytes() == core.sampling_ranges().tobytes()
    for got, ref in zip(back.forward_kinematics(q[:500]), core.forward_kinematics(q[:500])):
        assert got.tobytes() == ref.tobytes()
    assert back.sample(100, 3).tobytes() == core.sample(100, 3).tobytes()
    assert _same(copy.deepcopy(core).label(q[:1000], distance=True), core.label(q[:1000], distance=True))


def test_pickle_keeps_non_finite_and_unrounded_floats():
    """The state is binary: an unlimited joint's range may hold inf/NaN, which JSON cannot."""
    arrays = scene("panda_blocks").core_arrays()
    arrays["jnt_range"] = arrays["jnt_range"].copy()
    arrays["jnt_limited"] = arrays["jnt_limited"].copy()
    arrays["jnt_limited"][0] = False
    arrays["jnt_range"][0] = [-np.inf, np.nan]
    arrays["body_pos"] = arrays["body_pos"] + 1e-17
    core = _core.RobotModel(arrays)
    _, (state,) = core.__reduce__()
    back = pickle.loads(pickle.dumps(core))
    assert back.__reduce__()[1][0] == state
    q = profrobot.sample_poses(scene("panda_blocks"), 2000, seed=1)
    assert _same(back.label(q, distance=True), core.label(q, distance=True))


def test_corrupt_pickle_state_raises_value_error_not_panic_regression():
    core = scene("ur5e_wall_box").core
    make, (state,) = core.__reduce__()
    assert make(state).npair == core.npair
    bad = {
        "empty": b"",
        "other_format": b'{"body_parent": [0]}',
        "truncated": state[: len(state) // 2],
        "one_byte_short": state[:-1],
        "trailing_byte": state + b"\0",
        "flipped_byte": state[:100] + bytes([state[100] ^ 0x40]) + state[101:],
    }
    for name, s in bad.items():
        with pytest.raises(ValueError) as info:
            make(s)
        assert isinstance(info.value, _core.ProfrobotError), name
        assert "model description" in str(info.value), (name, str(info.value))
    # Through pickle itself: the same bytes altered in place inside a pickle.
    blob = pickle.dumps(core, protocol=pickle.HIGHEST_PROTOCOL)
    assert blob.count(state) == 1
    with pytest.raises(_core.ProfrobotError, match="checksum"):
        pickle.loads(blob.replace(state, bad["flipped_byte"]))
    with pytest.raises(TypeError, match="must be bytes"):
        make("not bytes")


def _label_in_child(core, q):
    return {threads: core.label(q, pairs=True, distance=True, threads=threads) for threads in (None, 2)}


# What a forked child inherits (not pickled to it): set by the parent before it forks.
_INHERITED: tuple = ()


def _label_inherited():
    return _label_in_child(*_INHERITED)


def _in_forked_child(inherited: tuple, call, what: str):
    """``call()`` in a child forked now (after the parent's threads are up), which inherits
    ``inherited`` as ``_INHERITED`` rather than unpickling it; a hang fails the test."""
    global _INHERITED
    _INHERITED = inherited
    ctx = multiprocessing.get_context("fork")
    try:
        with ctx.Pool(1) as pool:  # forks now
            try:
                return pool.apply_async(call).get(timeout=TIMEOUT_S)
            except multiprocessing.TimeoutError:
                pool.terminate()
                pytest.fail(f"forked child did not {what} within {TIMEOUT_S} s (threads it does not have)")
    finally:
        _INHERITED = ()


def test_forked_child_labels_after_parent_used_the_pools_regression():
    """A child forked after its parent labelled poses (a torch DataLoader worker) waited forever
    on the parent's rayon pool, whose threads do not exist in the child."""
    robot = scene("panda_blocks")
    q = profrobot.sample_poses(robot, N, seed=5)
    want = {threads: robot.core.label(q, pairs=True, distance=True, threads=threads) for threads in (None, 2)}
    assert _same(want[None], want[2])
    got = _in_forked_child((robot.core, q), _label_inherited, f"label {N} poses")
    for threads in (None, 2):
        assert _same(got[threads], want[threads]), threads
    # The parent's pools still work after the fork.
    assert _same(robot.core.label(q, pairs=True, distance=True), want[None])


def _plan_and_time(robot, start, goal):
    plan = profrobot.plan_path(robot, start, goal, seed=0, threads=2)
    timed = profrobot.time_path(robot, plan.path, velocity=np.full(robot.njoint, 1.5),
                                acceleration=np.full(robot.njoint, 3.0), threads=2)
    return plan.path, timed.duration


def _plan_and_time_inherited():
    return _plan_and_time(*_INHERITED)


def test_forked_child_plans_after_parent_used_the_crew_regression():
    """plan_path and time_path run on the calling thread with helper threads of their own (the
    crew, ``rust/threads/crew.rs``): a child forked after its parent used them has none of the
    threads, builds its own, and answers as the parent did."""
    robot = scene("panda_blocks")
    start, goal = profrobot.exact.problems.free_poses(robot, 2, seed=3)
    want = _plan_and_time(robot, start, goal)
    got = _in_forked_child((robot, start, goal), _plan_and_time_inherited, "plan and time a path")
    assert np.array_equal(got[0], want[0]) and got[1] == want[1]
    # The parent's crew still works after the fork.
    again = _plan_and_time(robot, start, goal)
    assert np.array_equal(again[0], want[0]) and again[1] == want[1]


def test_spawned_worker_labels_an_unpickled_model_identically(panda_poses):
    robot, q = panda_poses
    q = q[:2000]
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(1) as pool:
        got = pool.apply_async(_label_in_child, (robot.core, q)).get(timeout=TIMEOUT_S)
    want = robot.core.label(q, pairs=True, distance=True)
    assert _same(got[None], want) and _same(got[2], want)
