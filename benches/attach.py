"""Grasped objects: what ``Robot.attach`` costs beside replacing a scene's obstacles.

    python benches/attach.py [--scenes 50]

The Menagerie Panda (its ``panda`` entry, as ``benches/mbm.py``) in MotionBenchMaker's
``table_pick`` scenes (``../shared/mbm/``, or ``--mbm DIR``), each with a mug-sized cylinder
added 12 cm in front of the hand at the problem's start pose. Timed per scene (medians and p95;
run it alone on the machine): replacing the obstacles (``with_obstacles``), attaching the
cylinder to the hand there (``attach``: the arrays written, no compile), letting go
(``detach``, likewise) and, for comparison, both through a compile of the edited MjSpec (how
they worked before); the three operations on each scene in turn, with nothing compiled between
them (the compiled ones after all the others). Every
attached robot's first use of ``mj_model`` compiles it and checks it against the robot's
fingerprint (a mismatch raises), and the compiled attach gives the same fingerprint. Markdown
in ``benches/attach_results.md``.
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

import profrobot
from profrobot import Cylinder
from profrobot.robot import world as _world

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mbm import FINGERS, OPEN, read_request, read_scene  # noqa: E402
from results import write_results  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "attach_results.md"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=50)
    ap.add_argument("--mbm", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "mbm")
    args = ap.parse_args(argv)
    folder = args.mbm / "table_pick_panda"
    base = profrobot.Robot.from_menagerie("franka_emika_panda", "panda")
    hand = base.body_names.index("hand")
    times: dict[str, list[float]] = {"with_obstacles": [], "attach": [], "detach": [], "attach, compiled": [],
                                     "detach, compiled": []}
    jobs = []
    for i in range(1, 10 * args.scenes):
        if len(jobs) == args.scenes or not (folder / f"scene{i:04d}.yaml").exists():
            break
        q = read_request(folder / f"request{i:04d}.yaml", base)[0]
        q[[base.joint_names.index(f) for f in FINGERS]] = OPEN
        if not base.feasible(q[None])[0]:
            continue
        xpos, xquat = base.core.body_frames(q[None], hand)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, xquat[0])
        mug = Cylinder(pos=tuple(xpos[0] + R.reshape(3, 3) @ [0.0, 0.0, 0.12]), radius=0.025, half_length=0.05,
                       name="mug")
        jobs.append((read_scene(folder / f"scene{i:04d}.yaml") + [mug], q))
    done = len(jobs)

    def timed(key, call, *args):
        gc.collect()   # (not inside the timings: compiles leave garbage behind)
        t = time.perf_counter()
        out = call(*args)
        times[key].append(time.perf_counter() - t)
        return out

    def grasp(w, q):
        return w.attach("mug", to="hand", at=q)

    def let_go(h, q):
        return h.detach("mug", at=q)

    # the three operations on one scene, one after another (paired); the held robots compiled and
    # checked after all of them (a compile between two timings would leave the second cold), then
    # dropped before the compiled path (MuJoCo's MjSpec.delete, which the compiled attach calls,
    # slows down with every live spec: 50 held robots with their specs made it ~2 s)
    held = []
    for scene, q in jobs:
        w = timed("with_obstacles", base.with_obstacles, scene)
        h = timed("attach", grasp, w, q)
        timed("detach", let_go, h, q)
        held.append(h)
    prints = []
    for h in held:
        assert h._mj_model is None and h.mj_model is not None   # (compiled and checked here)
        prints.append(h.fingerprint)
    del held, h
    keep = _world.held_geom, _world.put_geom
    _world.held_geom = _world.put_geom = lambda robot, name: None     # the compile path, as before
    try:
        for k, (scene, q) in enumerate(jobs):
            w = base.with_obstacles(scene)
            assert w.mj_model is not None   # (compiled before: with_obstacles compiled at once then)
            h = timed("attach, compiled", grasp, w, q)
            assert h.fingerprint == prints[k]
            timed("detach, compiled", let_go, h, q)
            del h
    finally:
        _world.held_geom, _world.put_geom = keep
    load = os.getloadavg()[0]
    rows = "\n".join(f"| {k} | {len(v)} | {np.median(v) * 1e3:.2f} | {np.percentile(v, 95) * 1e3:.2f} |"
                     for k, v in times.items())
    text = ("# Grasped objects: attach beside a scene update\n\n`python benches/attach.py`\n\n"
            f"The Menagerie Panda in {done} MotionBenchMaker `table_pick` scenes, a mug-sized cylinder 12 cm in front "
            f"of the hand at each problem's start; load average {load:.2f}.\n\n"
            "| operation | n | ms (median) | ms (p95) |\n|---|---|---|---|\n" + rows + "\n")
    write_results(RESULTS, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
