"""Global planning beside OMPL: hard problems per scene, ours (every edge certified
continuously, the default; every edge sampled at the resolution and verified 10x finer, the
earlier default; exact + field smoothing) and OMPL's RRT-Connect using our labeller as its
state-validity checker, in one run; VAMP's published figure as the anchor.

    python benches/planning.py [--problems 100] [--scenes a,b] [--max-time 10] [--field] [--no-ompl]
                               [--no-sampled] [--recheck 0.0005]
                               [--executor ray [--address ray://host:10001] [--workers N]]

A hard problem: start and goal free, the straight SO(2) interpolation colliding at the dense
check (``profrobot.exact.problems.hard_pairs``). Every path reported free is re-checked: each segment
re-interpolated so that no joint moves more than ``--recheck`` (0.0005 rad) between poses, with
the exact labeller, and every such pose with MuJoCo (``mj_forward`` contacts). Markdown in
``benches/out/planning.md``.

VAMP (Thomason, Kingston, Kavraki, ICRA 2024) is not run: its PyPI source build downloads CMake
helpers at build time and does not build offline. Its published figure (median 35 µs per
problem on its Panda benchmark, one core) is printed as the anchor; it checks sphere
approximations of the links at sampled states (32 per radian), we check exact shapes with a
proof for every pose of every edge.

OMPL (``pip install ".[bench]"``): a compound space (SO2 for continuous hinges, bounded R for
the rest), ``setStateValidityCheckingResolution`` so that consecutive checked states are at most
``resolution`` apart in OMPL's metric (a sum over joints, so no joint moves more than
``resolution``: the same guarantee as ours), the default range, and the path simplifier off
(ours: shortcutting on; both lengths are reported).

``--executor ray`` farms the problems out, one per task, to a Ray cluster's workers (each holds
the scene's robot, loaded once; ``profrobot.executors.RayExecutor``): the same problems, seeds
and re-checks, each planner on one CPU per problem (locally ours uses all cores); field
smoothing stays in this process (one batched torch call).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

import profrobot
from profrobot.exact.planning import plan_path, so2_length
from profrobot.exact.problems import hard_pairs
from profrobot.robot.angles import wrap
from profrobot.exact.labels import so2_steps

OUT = Path(__file__).resolve().parent / "out"


#: the re-check's step (rad / m): no joint moves more than this between re-checked poses
RECHECK = 0.0005


def dense_check(robot, path: np.ndarray, resolution: float) -> tuple[bool, bool, float]:
    """(exact labeller free, MuJoCo free, max joint step) over every segment re-interpolated so
    that no joint moves more than ``RECHECK`` between poses (``resolution`` is not used: the
    same re-check for every method)."""
    poses = []
    for a, b in zip(path[:-1], path[1:]):
        d = so2_steps(robot, np.stack([a, b]))[0]
        n = int(np.ceil(np.abs(d).max() / RECHECK)) + 1
        poses.append(profrobot.interpolate(robot, a, b, max(n, 2)))
    dense = np.concatenate(poses)
    step = np.abs(np.diff(dense, axis=0))
    step[:, robot.continuous] = np.abs(wrap(step[:, robot.continuous]))
    ours = not profrobot.label_poses(robot, dense).collides.any()
    m, data = robot.mj_model, mujoco.MjData(robot.mj_model)
    theirs = True
    for q in dense:
        data.qpos[robot.qpos_adr] = q
        mujoco.mj_forward(m, data)
        if data.ncon:
            theirs = False
            break
    return ours, theirs, float(step.max())


def ompl_plan(robot, start, goal, resolution: float, max_time: float, seed: int):
    """OMPL 2 RRT-Connect with our exact labeller as the state-validity checker."""
    from ompl import base as ob, geometric as og, util as ou

    ou.RNG.setSeed(seed + 1)
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    k = robot.njoint
    lim = robot.joint_limits
    space = ob.CompoundStateSpace()
    for j in range(k):
        if robot.continuous[j]:
            space.addSubspace(ob.SO2StateSpace(), 1.0)
        else:
            r = ob.RealVectorStateSpace(1)
            bounds = ob.RealVectorBounds(1)
            bounds.setLow(float(lim[j, 0]))
            bounds.setHigh(float(lim[j, 1]))
            r.setBounds(bounds)
            space.addSubspace(r, 1.0)
    cont = robot.continuous
    core = robot.core
    buf = np.empty((1, k))
    checks = [0]

    def read(state, out):
        for j in range(k):
            out[j] = state[j].value if cont[j] else state[j][0]

    def valid(state):
        checks[0] += 1
        read(state, buf[0])
        return not core.label(buf, threads=1)["collides"][0]

    ss = og.SimpleSetup(space)
    ss.setStateValidityChecker(valid)
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(resolution / space.getMaximumExtent())
    states = []
    for q in (start, goal):
        st = space.allocState()
        for j in range(k):
            if cont[j]:
                st[j].value = wrap(float(q[j]))
            else:
                st[j][0] = float(q[j])
        states.append(st)
    ss.setStartAndGoalStates(states[0], states[1])
    ss.setPlanner(og.RRTConnect(si))
    t = time.perf_counter()
    solved = ss.solve(max_time)
    seconds = time.perf_counter() - t
    exact = bool(solved) and ss.haveExactSolutionPath()
    path = None
    if exact:
        p = ss.getSolutionPath()
        path = np.empty((p.getStateCount(), k))
        for i in range(p.getStateCount()):
            read(p.getState(i), path[i])
    return dict(found=exact, seconds=seconds, path=path, checks=checks[0])


QUICK = dict(n_poses=200_000, iterations=400, batch_size=4096, eikonal_batch=256, threads=2)


def field_for(scene: str, recipe: str):
    """The cached bench field (benches/fields.py, ~15 min to train) or, with ``recipe="quick"``,
    a smaller one (QUICK, ~2 min), cached beside it."""
    if recipe == "quick":
        robot = profrobot.scenes.load(scene)
        path = OUT / "fields_quick" / scene
        if path.is_dir():
            return profrobot.PoseSDF.load(path, robot)
        sdf = profrobot.train_sdf(robot, progress=False, **QUICK)
        sdf.save(path)
        print(scene, "quick field", {k: round(v, 4) for k, v in sdf.metrics.items() if isinstance(v, float)}, flush=True)
        return sdf
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fields import field  # noqa: E402  (the cached bench fields)

    return field(scene, progress=False)


def summarise(rows: list[dict], robot, straight: list[float]) -> dict:
    found = [r for r in rows if r["found"]]
    secs = np.array([r["seconds"] for r in rows])
    ratio = [r["length"] / s for r, s in zip(rows, straight) if r["found"] and s > 0]
    return dict(success=len(found) / len(rows), median_s=float(np.median(secs)), p90_s=float(np.percentile(secs, 90)),
                length_ratio=float(np.median(ratio)) if ratio else float("nan"),
                max_step=max((r["max_step"] for r in found), default=float("nan")),
                dense_free=sum(r["dense_ours"] and r["dense_mujoco"] for r in found),
                false_free=sum(not (r["dense_ours"] and r["dense_mujoco"]) for r in found),
                checks=float(np.median([r["checks"] for r in rows])))


def ours_row(robot, i: int, start, goal, resolution: float, max_time: float, threads: int | None = None,
             check: str = "continuous") -> dict:
    """One problem with our exact planner (seed ``i``), its path re-checked densely."""
    r = plan_path(robot, start, goal, resolution=resolution, max_time=max_time, seed=i, threads=threads, check=check)
    row = dict(found=r.found, seconds=r.seconds, checks=r.checks, length=float("nan"), max_step=float("nan"),
               dense_ours=False, dense_mujoco=False)
    if r.found:
        row["length"] = so2_length(robot, r.path)
        row["dense_ours"], row["dense_mujoco"], row["max_step"] = dense_check(robot, r.path, resolution)
    return row


def ours_sampled_row(robot, i: int, start, goal, resolution: float, max_time: float) -> dict:
    """``ours_row`` with edges sampled at ``resolution`` and the answer verified 10x finer."""
    return ours_row(robot, i, start, goal, resolution, max_time, check="sampled")


def ompl_row(robot, i: int, start, goal, resolution: float, max_time: float) -> dict:
    """One problem with OMPL's RRT-Connect (seed ``i``), its path re-checked densely."""
    r = ompl_plan(robot, start, goal, resolution, max_time, seed=i)
    row = dict(found=r["found"], seconds=r["seconds"], checks=r["checks"], length=float("nan"),
               max_step=float("nan"), dense_ours=False, dense_mujoco=False)
    if r["found"]:
        row["length"] = so2_length(robot, r["path"])
        row["dense_ours"], row["dense_mujoco"], row["max_step"] = dense_check(robot, r["path"], resolution)
    return row


def rows(fn, robot, problems: list[tuple], executor, desc: str) -> list[dict]:
    """``fn(robot, *problem)`` (a chunk function: one problem per chunk) for each problem: here
    (``executor=None``), or one problem per task on the executor's workers (each holding the
    scene's robot), in problem order either way."""
    from profrobot.executors import RayExecutor, check_executor

    executor = check_executor(executor)
    if isinstance(executor, RayExecutor) and __name__ != "__main__":
        # imported (not run as a script): send this module's functions by value
        from ray import cloudpickle

        cloudpickle.register_pickle_by_value(sys.modules[__name__])
    return executor.map(fn, problems, robot=robot, desc=desc)


def run_scene(scene: str, n: int, resolution: float, max_time: float, with_field: bool, with_ompl: bool,
              recipe: str = "bench", executor=None, with_sampled: bool = True) -> dict:
    robot = profrobot.scenes.load(scene)
    starts, goals = hard_pairs(robot, n, seed=200)
    straight = [so2_length(robot, np.stack([a, b])) for a, b in zip(starts, goals)]
    problems = [(i, a, b, resolution, max_time) for i, (a, b) in enumerate(zip(starts, goals))]
    out: dict[str, list] = {"ours (continuous certificate)": rows(ours_row, robot, problems, executor, f"{scene} ours")}
    print(scene, "ours", summarise(out["ours (continuous certificate)"], robot, straight), flush=True)
    if with_sampled:
        out["ours (sampled, verified 10x)"] = rows(ours_sampled_row, robot, problems, executor, f"{scene} sampled")
        print(scene, "sampled", summarise(out["ours (sampled, verified 10x)"], robot, straight), flush=True)
    smoothing = None
    if with_field:
        sdf = field_for(scene, recipe)
        t = time.perf_counter()
        res = profrobot.plan_trajectories(sdf, starts, goals, steps=100, init="planner",
                                        planner=dict(resolution=resolution, max_time=max_time))
        wall = (time.perf_counter() - t) / n
        field_rows = []
        for r in res:
            ok_o, ok_m, step = dense_check(robot, r.path, resolution) if r.certified else (False, False, float("nan"))
            field_rows.append(dict(found=r.certified, seconds=wall, checks=r.planner.checks if r.planner else 0,
                                   length=r.length, max_step=step, dense_ours=ok_o, dense_mujoco=ok_m))
        out["ours (exact + field smoothing)"] = field_rows
        before = np.array([r.length_before for r in res])
        after = np.array([r.length for r in res])
        tv = lambda p: float(np.abs(np.diff(p, axis=0)).sum())
        smoothing = dict(length_before=float(np.nanmedian(before)), length_after=float(np.nanmedian(after)),
                         shortened=int(sum(r.smoothed for r in res)),
                         tv_after=float(np.median([tv(r.path) for r in res])))
        print(scene, "field", summarise(field_rows, robot, straight), smoothing, flush=True)
    if with_ompl:
        out["OMPL RRT-Connect"] = rows(ompl_row, robot, problems, executor, f"{scene} ompl")
        print(scene, "ompl", summarise(out["OMPL RRT-Connect"], robot, straight), flush=True)
    return dict(scene=scene, n=n, methods={k: summarise(v, robot, straight) for k, v in out.items()},
                smoothing=smoothing)


def markdown(results: list[dict], args) -> str:
    load = os.getloadavg()
    lines = ["# Planning: ours beside OMPL RRT-Connect", "",
             f"Hard problems per scene: {args.problems}; sampled rows: resolution {args.resolution} rad (no joint "
             f"moves more than that between checks); continuous rows: every pose of every edge proven; re-check "
             f"every {RECHECK} rad with our labeller and MuJoCo; budget {args.max_time} s per problem; "
             + ("2 threads for ours, " if getattr(args, "executor", "local") == "local" else
                "on a Ray cluster (one problem per task, one CPU each), ")
             + "OMPL single-threaded (its checker is our labeller, one pose per call). Load average at the end: "
             f"{load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f}. Field recipe for smoothing: {args.recipe}.", "",
             "| scene | method | success | median s | p90 s | length / straight | max joint step | "
             "dense check free | reported free but colliding | median checks |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for name, m in r["methods"].items():
            lines.append(f"| {r['scene']} | {name} | {m['success']:.0%} | {m['median_s']:.4f} | {m['p90_s']:.4f} | "
                         f"{m['length_ratio']:.2f} | {m['max_step']:.4f} | {m['dense_free']} | {m['false_free']} | "
                         f"{m['checks']:.0f} |")
    lines += ["", "Anchor, not run here: VAMP (Thomason, Kingston, Kavraki, ICRA 2024), published median 35 µs per "
              "problem on its own Panda benchmark, one core: sphere approximations of the links, edges sampled at 32 "
              "states per radian, no proof between samples. 'median checks': poses placed (continuous) or labelled "
              "(sampled, OMPL)."]
    sm = [r for r in results if r["smoothing"]]
    if sm:
        lines += ["", "Field smoothing of the planner's paths (medians; 100 waypoints):", "",
                  "| scene | length before | length after | problems shortened | TV after |", "|---|---|---|---|---|"]
        for r in sm:
            s = r["smoothing"]
            lines.append(f"| {r['scene']} | {s['length_before']:.3f} | {s['length_after']:.3f} | {s['shortened']} | "
                         f"{s['tv_after']:.3f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    global RECHECK
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--problems", type=int, default=100)
    ap.add_argument("--scenes", default=",".join(profrobot.scenes.names()))
    ap.add_argument("--resolution", type=float, default=0.01)
    ap.add_argument("--max-time", dest="max_time", type=float, default=10.0)
    ap.add_argument("--field", action="store_true", help="also smooth with the cached bench field (benches/fields.py)")
    ap.add_argument("--field-scenes", dest="field_scenes", default="panda_blocks,ur5e_wall_box")
    ap.add_argument("--field-recipe", dest="recipe", choices=("bench", "quick"), default="bench",
                    help="bench: benches/fields.py's cached fields; quick: a 2-minute field per scene")
    ap.add_argument("--no-ompl", dest="ompl", action="store_false")
    ap.add_argument("--no-sampled", dest="sampled", action="store_false", help="skip the sampled-edges row")
    ap.add_argument("--recheck", type=float, default=RECHECK, help="re-check step (rad / m)")
    ap.add_argument("--executor", choices=("local", "ray"), default="local",
                    help="ray: one problem per task on a Ray cluster's workers (pip install '.[ray]')")
    ap.add_argument("--address", default=None, help="Ray address (default: start a local cluster)")
    ap.add_argument("--workers", type=int, default=None, help="Ray workers (default: the cluster's CPUs)")
    ap.add_argument("--out", default=str(OUT / "planning.md"), help="the Markdown table")
    args = ap.parse_args()
    RECHECK = args.recheck
    executor = None
    if args.executor == "ray":
        from profrobot.executors import RayExecutor

        executor = RayExecutor(args.address, workers=args.workers)
    results = []
    try:
        for scene in args.scenes.split(","):
            results.append(run_scene(scene, args.problems, args.resolution, args.max_time,
                                     args.field and scene in args.field_scenes.split(","), args.ompl, args.recipe,
                                     executor, args.sampled))
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            from profrobot.files import atomic_path

            with atomic_path(args.out) as tmp:
                Path(tmp).write_text(markdown(results, args))
    finally:
        if executor is not None:
            executor.shutdown()
    print(markdown(results, args))


if __name__ == "__main__":
    main()
