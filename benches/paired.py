"""Two builds timed side by side, paired: the same calls sent in alternation to two long-lived
worker processes, one importing this checkout's profrobot, the other another checkout's (its
``python/`` folder, with its extension built in place). Both meet the same machine noise, call for
call, which wall-clock runs of two builds one after the other on a shared VM do not.

    python benches/paired.py --other ../old/python [--rounds 5] [--problems 40] [--targets 300]

Prints, per scene, the median wall time of ``plan_path`` (defaults, hard pairs), of ``ik`` (FK
targets of free poses) and of ``plan_cartesian`` (5-10 cm approach moves along the frame's z axis
from certified poses, as ``benches/cartesian.py`` makes them) for each build, and their ratio
(this / other). The load average is
printed beside the table. Build the other checkout's extension first, e.g. in a git worktree:
``PYO3_PYTHON=python cargo build --release --features python --lib`` then copy
``target/release/libprofrobot.so`` to ``python/profrobot/_core.abi3.so``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

#: the frame IK solves for, per bundled arm
ARMS = {"panda_blocks": "hand", "ur5e_wall_box": "wrist_3_link", "xarm7_table": "link7",
        "vx300s_clutter": "gripper_link", "panda_shelf": "hand"}

WORKER = r'''
import sys, time
import numpy as np
import profrobot
exact = getattr(profrobot, "exact", None)
data, arms = sys.argv[1], dict(a.split("=") for a in sys.argv[2].split(","))
robots, probs, targets = {}, {}, {}
for name in profrobot.scenes.names():
    robots[name] = profrobot.scenes.load(name)
    d = np.load(f"{data}/{name}.npz")
    probs[name] = (d["starts"], d["goals"])
    if "targets" in d:
        targets[name] = d["targets"]
        probs[name] += (d["move_starts"], d["move_ends"])
    profrobot.plan_path(robots[name], d["starts"][0], d["goals"][0])   # warm
print("ready", flush=True)
for line in sys.stdin:
    kind, name, i = line.split()
    robot = robots[name]
    t0 = time.perf_counter()
    if kind == "plan":
        found = profrobot.plan_path(robot, probs[name][0][int(i)], probs[name][1][int(i)]).found
    elif kind == "cart":
        profrobot.plan_cartesian(robot, probs[name][2][int(i)], probs[name][3][int(i)][None], frame=arms[name])
        found = True   # (a move stopped short is an answer too)
    else:
        found = profrobot.ik(robot, targets[name], frame=arms[name]).certified.any()
    print(time.perf_counter() - t0 if found else "nan", flush=True)
'''


def make_problems(folder: Path, problems: int, n_targets: int) -> None:
    """The same problems for both builds, made once by this checkout."""
    import mujoco
    import numpy as np

    import profrobot

    for name in profrobot.scenes.names():
        robot = profrobot.scenes.load(name)
        s, g = profrobot.exact.problems.hard_pairs(robot, problems, seed=21)
        out = dict(starts=s, goals=g)
        if name in ARMS:
            q = profrobot.exact.problems.free_poses(robot, n_targets, seed=5)
            m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
            T = np.tile(np.eye(4), (len(q), 1, 1))
            for i, x in enumerate(q):
                d.qpos[robot.qpos_adr] = x
                mujoco.mj_kinematics(m, d)
                body = d.body(ARMS[name])
                T[i, :3, :3], T[i, :3, 3] = body.xmat.reshape(3, 3), body.xpos
            out["targets"] = T
            # straight approach moves: 5-10 cm along the frame's z from certified poses
            q = profrobot.sample_poses(robot, 20 * problems, seed=3)
            q = q[profrobot.certify_poses(robot, q)][:problems]
            rng = np.random.default_rng(0)
            ends = np.empty((len(q), 3))
            for i, x in enumerate(q):
                d.qpos[robot.qpos_adr] = x
                mujoco.mj_kinematics(m, d)
                body = d.body(ARMS[name])
                ends[i] = body.xpos + body.xmat.reshape(3, 3)[:, 2] * rng.uniform(0.05, 0.10)
            out["move_starts"], out["move_ends"] = q, ends
        np.savez(folder / f"{name}.npz", **out)


def worker(pythonpath: str | None, data: Path) -> subprocess.Popen:
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    arms = ",".join(f"{k}={v}" for k, v in ARMS.items())
    # run from the data folder: neither checkout's python/ is on the path unless asked
    p = subprocess.Popen([sys.executable, "-c", WORKER, str(data), arms], cwd=data, env=env, text=True,
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    assert p.stdin is not None and p.stdout is not None
    if p.stdout.readline().strip() != "ready":
        raise SystemExit(f"the worker for {pythonpath or 'this checkout'} did not start")
    return p


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--other", required=True, help="the other checkout's python/ folder (its extension built there)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--problems", type=int, default=40, help="plan_path problems per scene (and straight-line moves per arm)")
    ap.add_argument("--targets", type=int, default=300, help="IK targets per arm (one call)")
    ap.add_argument("--calls", default="plan,ik,cart", help="which calls to pair (comma-separated: plan, ik, cart)")
    args = ap.parse_args()
    here = str(Path(__file__).resolve().parents[1] / "python")
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp)
        make_problems(data, args.problems, args.targets)
        workers = {"this": worker(here, data), "other": worker(str(Path(args.other).resolve()), data)}
        times: dict[tuple[str, str, str], list[float]] = {}

        def ask(tag: str, cmd: str) -> float:
            p = workers[tag]
            assert p.stdin is not None and p.stdout is not None
            p.stdin.write(cmd + "\n")
            p.stdin.flush()
            return float(p.stdout.readline())

        import profrobot

        calls = [("plan", name, str(i)) for name in profrobot.scenes.names() for i in range(args.problems)]
        calls += [("ik", name, "0") for name in ARMS for _ in range(5)]
        calls += [("cart", name, str(i)) for name in ARMS for i in range(args.problems)]
        kinds = set(args.calls.split(","))
        if not kinds <= {"plan", "ik", "cart"}:
            raise SystemExit(f"--calls takes plan, ik and cart; got {args.calls}")
        calls = [c for c in calls if c[0] in kinds]
        for r in range(args.rounds):
            for j, (kind, name, i) in enumerate(calls):
                for tag in (("this", "other") if (j + r) % 2 == 0 else ("other", "this")):
                    times.setdefault((kind, name, tag), []).append(ask(tag, f"{kind} {name} {i}"))
        for p in workers.values():
            p.terminate()
    print(f"load average {' '.join(open('/proc/loadavg').read().split()[:3])}; {args.rounds} rounds, calls alternated")
    print("| call | scene | this: median ms | other: median ms | this / other |")
    print("|---|---|---|---|---|")
    for kind, name, tag in sorted(times):
        if tag == "this":
            a = statistics.median(times[(kind, name, "this")]) * 1e3
            b = statistics.median(times[(kind, name, "other")]) * 1e3
            what = {"plan": "plan_path", "cart": "plan_cartesian"}.get(kind, f"ik, {args.targets} targets")
            print(f"| {what} | {name} | {a:.3f} | {b:.3f} | {a / b:.3f} |")


if __name__ == "__main__":
    main()
