"""Ctrl-C stops long native calls (``rust/cancel.rs``, ``rust/bindings/interrupt.rs``).

Each case runs in a child process that prepares a call which would take 20 s or more on this
machine kind (one thread), says ``ready``, and starts it; the test sends SIGINT half a second
later. The call must raise ``KeyboardInterrupt`` instead of finishing, leave no file behind, and
the next call in the same process must give the answer it gave before. (How soon it stops is a
figure, not an assertion: about 0.05 s after the signal on an idle 2-core machine.)
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

PRELUDE = """
import numpy as np
import profrobot
robot = profrobot.scenes.load("panda_blocks")
"""

#: name → (set-up, the long call, a short call whose answer must not change)
CASES = {
    "label_poses": ("q = profrobot.sample_poses(robot, 6_000_000, seed=0, threads=1)",
                    "profrobot.label_poses(robot, q, threads=1)",
                    "profrobot.label_poses(robot, q[:2000]).collides"),
    "collides": ("q = profrobot.sample_poses(robot, 12_000_000, seed=0, threads=1)",
                 "profrobot.collides(robot, q, threads=1)",
                 "profrobot.collides(robot, q[:2000])"),
    "make_dataset": ("",
                     "profrobot.make_dataset(robot, 20_000_000, seed=0, threads=1, progress=False)",
                     "profrobot.make_dataset(robot, 2000, seed=1, progress=False).poses"),
    "ik": ("far = np.tile([[4.0, 4.0, 4.0]], (200_000, 1))   # out of reach: every seed is tried\n"
           "near = profrobot.exact.problems.free_poses(robot, 1, seed=2)",
           "profrobot.ik(robot, far, frame='hand', threads=1)",
           "profrobot.ik(robot, np.array([[0.4, 0.1, 0.5]]), frame='hand').poses"),
    "plan_path": (
        "wall = profrobot.Robot.from_mjcf(write('wall.xml'))   # a slider behind a wall: no path exists",
        "profrobot.plan_path(wall, [-0.5], [0.5], max_time=3600.0, iterations=10**9, threads=1)",
        "profrobot.plan_path(robot, *profrobot.exact.problems.free_poses(robot, 2, seed=3), seed=0).path"),
    # (plan_path runs on the calling thread, its loops asking for signals: on two threads, too)
    "plan_path_two_threads": (
        "wall = profrobot.Robot.from_mjcf(write('wall.xml'))",
        "profrobot.plan_path(wall, [-0.5], [0.5], max_time=3600.0, iterations=10**9, threads=2)",
        "profrobot.plan_path(robot, *profrobot.exact.problems.free_poses(robot, 2, seed=3), seed=0, threads=2).path"),
}

#: seconds the child may take after the signal before the test calls it hung: a guard, not a speed
#: goal (uninterrupted, each call runs longer than this on this machine kind: tens of seconds to
#: an hour)
HANG = 60

WALL = """<mujoco><worldbody>
  <body name="cart"><joint name="x" type="slide" axis="1 0 0" range="-1 1"/><geom type="sphere" size="0.05"/></body>
  <geom name="wall" type="box" pos="0 0 0" size="0.02 1 1"/>
</worldbody></mujoco>"""


def child_script(setup: str, call: str, check: str, workdir: str) -> str:
    return PRELUDE + textwrap.dedent(f"""
        import os, tempfile
        def write(name):   # the model file lives outside the watched folder
            path = os.path.join(tempfile.mkdtemp(), name)
            open(path, "w").write({WALL!r})
            return path
        {setup}
        before = {check}
        os.chdir({workdir!r})
        print("ready", flush=True)
        try:
            {call}
            print("finished", flush=True)
        except KeyboardInterrupt:
            print("interrupted", flush=True)
        after = {check}
        assert np.array_equal(np.asarray(before), np.asarray(after)), "the next call answered differently"
        print("next call correct", flush=True)
        """)


@pytest.mark.skipif(sys.platform == "win32", reason="SIGINT to a child process is POSIX")
@pytest.mark.parametrize("case", sorted(CASES))
def test_ctrl_c_stops_a_long_call(case, tmp_path):
    setup, call, check = CASES[case]
    watched = tmp_path / "cwd"
    watched.mkdir()
    script = child_script(textwrap.indent(setup, " " * 8).strip(), call, check, str(watched))
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, env=env)
    try:
        ready = child.stdout.readline().strip()
        assert ready == "ready", (ready, child.stderr.read()[-3000:] if child.poll() is not None else "")
        time.sleep(0.5)
        child.send_signal(signal.SIGINT)
        out, err = child.communicate(timeout=HANG)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 0, err[-3000:]
    lines = out.split("\n")
    assert "interrupted" in lines and "finished" not in lines, f"the call was not interrupted: {out!r}"
    assert "next call correct" in out
    assert list(watched.iterdir()) == [], "a file was left behind"
