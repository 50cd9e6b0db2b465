"""Timed paths beside Ruckig and TOPP-RA, on the same certified waypoints.

    python benches/timing.py [--paths 100] [--scenes a,b] [--velocity 1.5] [--acceleration 3] [--jerk 30]

Per bundled arm, ``--paths`` hard problems (``hard_pairs``) planned by ``plan_path`` (every path
certified), then timed under the same per-joint limits (rad/s, rad/s²; no jerk limit) by:

- **ours** (``time_path``): each corner cut by the widest proven chord (``cut``, the default
  0.5 of each segment), segments at constant velocity, parabolic blends at the corners, each
  blend proven free (or a stop there); checked here at 1 kHz: no sample above a limit, every
  sample free by MuJoCo's own collision (``mj_collision``); and with the path's own corners
  (``cut=0``: parabolic blends alone, beside the least such blends could give);
- **Ruckig** (PyPI ``ruckig``, the community version, offline): state to state only, so it stops
  at every waypoint, each segment phase-synchronised (a straight line in joint space: the
  certified path itself) and time-optimal under the same limits (jerk unlimited);
- **TOPP-RA** (PyPI ``toppra``): time-optimal along a cubic spline through the waypoints — another
  path than the certified one; the share of its 1 kHz samples the exact labeller does not
  certify is reported.

Then again with a jerk limit as well (``--jerk`` rad/s³): ours (``time_path(..., jerk=)``, a
stop at every waypoint, each segment a double-S move) beside Ruckig under the same three limits,
with velocity, acceleration and jerk (differences of acceleration) checked at 1 kHz.

Also the cost of ``time_path`` on paths of 20 waypoints (certified plans chained goal to goal,
cut at 20 waypoints), twice per path: the first call, right after the ``plan_path`` that
completed the path, and the median of five more calls on it (its ``repeated`` figure: the same
work with the caches warm, as in a loop timing many paths). The first call pays for refilling
the caches the planning left cold, the more the longer a core idled: on this machine a 1.1 ms
call took 2–3 ms after 1–8 s of sleep and 8.5 ms after 15 s (the same code, the same answer),
and on ur5e_wall_box, whose hard goals' plans run out their 10 s on one of the two cores, the
first call took 0.9–9 ms where its repeats took 0.64–0.69 ms. Timings are medians; run it alone
on the machine.
Markdown in ``benches/timing_results.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

# TOPP-RA's linear algebra runs on OpenBLAS's threads, which spin for ~0.1 s after each call: on
# two cores that is one of the two `time_path` runs on, and it timed our 20-waypoint paths ~1.4×
# slower than in a process without TOPP-RA (vx300s_clutter: 2.04 against 1.48 ms, one after the
# other). The peers are not timed here; one BLAS thread leaves the cores to what is.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import profrobot
from profrobot.exact.labels import so2_steps
from profrobot.exact.problems import hard_pairs
from results import write_results

ARMS = ["panda_blocks", "panda_shelf", "ur5e_wall_box", "xarm7_table", "vx300s_clutter"]
RESULTS = Path(__file__).resolve().parent / "timing_results.md"


def unwrapped(robot, path):
    steps = so2_steps(robot, path)
    return path[:1] + np.concatenate([np.zeros((1, robot.njoint)), np.cumsum(steps, axis=0)])


def ruckig_stops(path, v, a, j=None) -> float:
    """Ruckig from rest to rest along each segment, phase-synchronised (jerk ``j`` or none):
    the duration."""
    from ruckig import InputParameter, Ruckig, Synchronization, Trajectory
    k = path.shape[1]
    otg, inp, total = Ruckig(k), InputParameter(k), 0.0
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = v.tolist(), a.tolist(), (
        [float("inf")] * k if j is None else j.tolist())
    inp.synchronization = Synchronization.Phase
    for x, y in zip(path[:-1], path[1:]):
        if np.abs(y - x).max() == 0:
            continue
        inp.current_position, inp.target_position = x.tolist(), y.tolist()
        tr = Trajectory(k)
        otg.calculate(inp, tr)
        total += tr.duration
    return total


def blend_floor(w, v, a) -> float:
    """The shortest duration blends at the corners could give on waypoints ``w``: every segment
    at its velocity limit and every corner free, only the start and the stop paying for their
    acceleration (half the time to reach, or leave, the cruise velocity). A parabolic blend takes
    exactly the time its cruise would, so a timing that blends every corner at full speed meets
    it; Ruckig stopping at every waypoint pays that start and stop at every corner."""
    d = np.diff(w, axis=0)
    t = (np.abs(d) / v).max(axis=1)
    first, last = d[0] / t[0], d[-1] / t[-1]
    return float(t.sum() + 0.5 * (np.abs(first) / a).max() + 0.5 * (np.abs(last) / a).max())


def toppra_time(robot, path, v, a) -> tuple[float, float]:
    """TOPP-RA along a cubic spline through the waypoints: (duration, share of its 1 kHz samples
    not certified free)."""
    import toppra as ta
    import toppra.algorithm as algo
    import toppra.constraint as constraint
    ta.setup_logging("WARNING")
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    spline = ta.SplineInterpolator(s / s[-1], path)
    cons = [constraint.JointVelocityConstraint(np.stack([-v, v], axis=1)),
            constraint.JointAccelerationConstraint(np.stack([-a, a], axis=1))]
    traj = algo.TOPPRA(cons, spline, parametrizer="ParametrizeConstAccel").compute_trajectory(0, 0)
    if traj is None:
        return np.nan, np.nan
    t = np.arange(0.0, traj.duration, 1e-3)
    q = traj(t)
    return float(traj.duration), float(1.0 - profrobot.certify_poses(robot, q).mean())


def run(name: str, n: int, vmax: float, amax: float, jmax: float) -> dict:
    robot = profrobot.scenes.load(name)
    v, a, j = np.full(robot.njoint, vmax), np.full(robot.njoint, amax), np.full(robot.njoint, jmax)
    jerk, rk_jerk, jerk_over, floor = [], [], [], []
    starts, goals = hard_pairs(robot, n, seed=0)
    ours, stops, rk, tp, tp_off, ms, corners, violations, mj_hits, samples, blends_stopped = ([] for _ in range(11))
    own, cuts = [], []
    twenty, twenty_warm = [], []
    for s, g in zip(starts, goals):
        plan = profrobot.plan_path(robot, s, g)
        if not plan.certified:
            continue
        t0 = time.perf_counter()
        timed = profrobot.time_path(robot, plan.path, velocity=v, acceleration=a)
        ms.append(time.perf_counter() - t0)
        assert timed.certified
        stop = profrobot.time_path(robot, plan.path, velocity=v, acceleration=a, blend=False)
        corners_kept = profrobot.time_path(robot, plan.path, velocity=v, acceleration=a, cut=0.0)
        own.append(corners_kept.duration)
        cuts.append(len(timed.waypoints) > len(corners_kept.waypoints))
        t, q, qd, qdd = timed.at_rate(1000)
        violations.append(int(((np.abs(qd) > v * (1 + 1e-9)) | (np.abs(qdd) > a * (1 + 1e-9))).any(axis=1).sum()))
        mj_hits.append(int(profrobot.mujoco_labels(robot, q, progress=False).collides.sum()))
        samples.append(len(t))
        ours.append(timed.duration)
        stops.append(stop.duration)
        corners.append(len(corners_kept.waypoints) - 2)
        blends_stopped.append(int(timed.stops[1:-1].sum()))
        w = unwrapped(robot, plan.path)
        rk.append(ruckig_stops(w, v, a))
        floor.append(blend_floor(corners_kept.waypoints, v, a))
        smooth = profrobot.time_path(robot, plan.path, velocity=v, acceleration=a, jerk=j)
        assert smooth.certified
        qd, qdd = smooth.at_rate(1000)[2:]
        jerk_over.append(int(((np.abs(qd) > v * (1 + 1e-9)) | (np.abs(qdd) > a * (1 + 1e-9))).any(axis=1).sum()
                             + (np.abs(np.diff(qdd, axis=0)) * 1000 > j * (1 + 1e-9)).any(axis=1).sum()))
        jerk.append(smooth.duration)
        rk_jerk.append(ruckig_stops(w, v, a, j))
        d, off = toppra_time(robot, w, v, a)
        tp.append(d)
        tp_off.append(off)
    # 20-waypoint paths: certified plans chained goal to goal until 20 waypoints
    chain = [goals[0][None]]
    for g in goals[1:]:
        plan = profrobot.plan_path(robot, chain[-1][-1], g)
        if not plan.certified:
            continue
        chain.append(plan.path[1:])
        path = np.concatenate(chain)
        if len(path) >= 20:
            t0 = time.perf_counter()
            timed = profrobot.time_path(robot, path[:20], velocity=v, acceleration=a)
            twenty.append(time.perf_counter() - t0)
            assert timed.certified
            again = []
            for _ in range(5):
                t0 = time.perf_counter()
                profrobot.time_path(robot, path[:20], velocity=v, acceleration=a)
                again.append(time.perf_counter() - t0)
            twenty_warm.append(np.median(again))
            chain = [path[19:20]]
    ours, rk = np.array(ours), np.array(rk)
    return dict(scene=name, paths=len(ours), corners=float(np.median(corners)), stopped=int(np.sum(blends_stopped)),
                ours=float(np.median(ours)), stops=float(np.median(stops)), ruckig=float(np.median(rk)),
                ratio=float(np.median(ours / rk)), own_ratio=float(np.median(np.array(own) / rk)),
                cut=float(np.mean(cuts)), toppra=float(np.nanmedian(tp)),
                toppra_off=float(np.nanmean(np.array(tp_off) > 0)), violations=int(np.sum(violations)),
                mujoco=int(np.sum(mj_hits)), samples=int(np.sum(samples)), ms=float(np.median(ms) * 1e3),
                ms20=float(np.median(twenty) * 1e3) if twenty else np.nan, n20=len(twenty),
                ms20_warm=float(np.median(twenty_warm) * 1e3) if twenty else np.nan,
                floor_ratio=float(np.median(np.array(floor) / rk)),
                jerk=float(np.median(jerk)), ruckig_jerk=float(np.median(rk_jerk)),
                jerk_ratio=float(np.median(np.array(jerk) / np.array(rk_jerk))), jerk_over=int(np.sum(jerk_over)))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=100)
    ap.add_argument("--scenes", default=",".join(ARMS))
    ap.add_argument("--velocity", type=float, default=1.5)
    ap.add_argument("--acceleration", type=float, default=3.0)
    ap.add_argument("--jerk", type=float, default=30.0)
    args = ap.parse_args(argv)
    rows = []
    for name in args.scenes.split(","):
        r = run(name, args.paths, args.velocity, args.acceleration, args.jerk)
        rows.append(r)
        print(r, flush=True)
    load = os.getloadavg()[0]
    head = (f"Per arm, {args.paths} hard problems planned by `plan_path` (certified), timed under the same limits "
            f"({args.velocity} rad/s, {args.acceleration} rad/s², no jerk limit). Load average {load:.2f}.\n\n"
            "| scene | paths | corners (median) | paths with a corner cut | blends turned into stops | "
            "ours: duration (median, s) | "
            "ours stopping at every waypoint | Ruckig, stopping at every waypoint | ours / Ruckig (median) | "
            "ours, corners kept (`cut=0`) / Ruckig | parabolic blends' floor / Ruckig (median) | "
            "TOPP-RA on a spline | TOPP-RA trajectories leaving the certified set | ours: samples over a limit | "
            "ours: MuJoCo contacts in 1 kHz samples | `time_path` ms (median) | 20 waypoints: ms, first call (median, n) | "
            "20 waypoints: ms, repeated (median) |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    lines = [f"| {r['scene']} | {r['paths']} | {r['corners']:.0f} | {r['cut']:.0%} | {r['stopped']} | {r['ours']:.3f} | "
             f"{r['stops']:.3f} | {r['ruckig']:.3f} | {r['ratio']:.3f} | {r['own_ratio']:.3f} | {r['floor_ratio']:.3f} | {r['toppra']:.3f} | {r['toppra_off']:.0%} | {r['violations']} | "
             f"{r['mujoco']} of {r['samples']} | {r['ms']:.2f} | {r['ms20']:.2f} ({r['n20']}) | {r['ms20_warm']:.2f} |"
             for r in rows]
    jerk = (f"\n\nWith a jerk limit of {args.jerk} rad/s³ as well (`time_path(..., jerk=)`: a stop at every waypoint, "
            "each segment a double-S move; Ruckig phase-synchronised from rest to rest along each segment, "
            "the same limits):\n\n| scene | ours: duration (median, s) | Ruckig (median, s) | ours / Ruckig (median) | "
            "ours: 1 kHz samples over a limit (velocity, acceleration, jerk) |\n|---|---|---|---|---|\n"
            + "\n".join(f"| {r['scene']} | {r['jerk']:.3f} | {r['ruckig_jerk']:.3f} | {r['jerk_ratio']:.4f} | "
                        f"{r['jerk_over']} |" for r in rows))
    text = ("# Timed paths beside Ruckig and TOPP-RA\n\n`python benches/timing.py`\n\n" + head + "\n".join(lines)
            + jerk + "\n")
    write_results(RESULTS, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
