"""Labelling throughput: our Rust labeller (``label_poses``, the four labels) and its
booleans-only fast path (``collides``) against MuJoCo's mj_kinematics + mj_collision loop, on
the same poses, in one run. Prints poses/s and the ratios.

    python benches/labelling.py                 # panda_blocks
    python benches/labelling.py --all           # every bundled scene

Ours runs on all cores and on one thread. MuJoCo is timed as a tight Python loop (one core, the
usual way to label with it) and as one loop per core in separate processes (its best use of the
same cores). Wall-clock ratios need a quiet machine: the load average is printed beside them.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time

import mujoco
import numpy as np

import profrobot


def mujoco_loop(scene: str, poses: np.ndarray) -> float:
    """Seconds MuJoCo takes to label ``poses`` one by one (returns elapsed time)."""
    robot = profrobot.scenes.load(scene)
    m, adr = robot.mj_model, robot.qpos_adr
    d = mujoco.MjData(m)
    ncon = np.empty(len(poses), dtype=np.int32)
    t = time.perf_counter()
    for i in range(len(poses)):
        d.qpos[adr] = poses[i]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        ncon[i] = d.ncon
    return time.perf_counter() - t


def best_of(fn, repeat: int) -> float:
    return min(fn() for _ in range(repeat))


def bench_scene(scene: str, n_ours: int, n_mujoco: int, cores: int) -> dict:
    robot = profrobot.scenes.load(scene)
    poses = profrobot.sample_poses(robot, n_ours, seed=0)
    # Warm up the thread pools, and the fast path's likely pairs (computed once per model).
    profrobot.label_poses(robot, poses[:1000])
    profrobot.collides(robot, poses[:1000], threads=1)
    profrobot.collides(robot, poses[:1000], threads=cores)

    def timed(fn, threads):
        t = time.perf_counter()
        fn(robot, poses, threads=threads)
        return time.perf_counter() - t

    r = dict(scene=scene)
    for key, fn in (("label", profrobot.label_poses), ("collides", profrobot.collides)):
        r[f"{key}_1"] = n_ours / best_of(lambda fn=fn: timed(fn, 1), 3)
        r[f"{key}_all"] = n_ours / best_of(lambda fn=fn: timed(fn, cores), 3)
    sub = poses[:n_mujoco]
    r["mj_1"] = n_mujoco / best_of(lambda: mujoco_loop(scene, sub), 2)
    with mp.get_context("spawn").Pool(cores) as pool:
        parts = np.array_split(sub, cores)
        # Each worker times its own loop (model loading excluded); they run side by side.
        r["mj_procs"] = n_mujoco / max(pool.starmap(mujoco_loop, [(scene, p) for p in parts]))
    r["collide"] = float(profrobot.collides(robot, sub).mean())
    return r


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--all", action="store_true", help="every bundled scene (default: panda_blocks)")
    p.add_argument("-n", type=int, default=200_000, help="poses for our labeller")
    p.add_argument("--n-mujoco", type=int, default=30_000, help="poses for MuJoCo's loop")
    args = p.parse_args()
    cores = os.cpu_count() or 1
    scenes = profrobot.scenes.names() if args.all else ["panda_blocks"]
    print(f"{cores} cores; ours on {args.n} poses, MuJoCo {mujoco.__version__} on {args.n_mujoco}; "
          f"load average {load()} at the start")
    print(f"{'scene':16} {'collide':>8} {'':9} {'ours 1T':>10} {f'ours {cores}T':>10} {'MuJoCo':>10} "
          f"{f'MuJoCo {cores}P':>10} {'ratio':>7} {'ratio xP':>9} {'per core':>9}")
    for s in scenes:
        r = bench_scene(s, args.n, args.n_mujoco, cores)
        for key in ("label", "collides"):
            ours_1, ours_all = r[f"{key}_1"], r[f"{key}_all"]
            print(f"{s:16} {r['collide']:8.1%} {key:9} {ours_1:10,.0f} {ours_all:10,.0f} {r['mj_1']:10,.0f} "
                  f"{r['mj_procs']:10,.0f} {ours_all / r['mj_1']:6.1f}x {ours_all / r['mj_procs']:8.1f}x "
                  f"{ours_1 / r['mj_1']:8.1f}x")
    print(f"ratio: ours on {cores} threads / MuJoCo's loop in one process; ratio xP: / MuJoCo in one process "
          f"per core; per core: one thread / one process. label: label_poses (four labels); collides: the "
          f"booleans-only fast path. Load average {load()} at the end (above ~1: not a quiet machine).")


def load() -> str:
    """The 1-, 5- and 15-minute load averages, as `uptime` prints them."""
    try:
        return ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


if __name__ == "__main__":
    main()
