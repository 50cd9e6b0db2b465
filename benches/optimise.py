"""Collision-aware optimisation benchmarks (paper Tables 5 and 6, supplement trajectories).

    python benches/optimise.py [--sections resolve,trajectories,gif] [--poses 1000] [--pairs 100]
                               [--threads 1]

- Resolution on Panda-blocks: ``--poses`` colliding poses; l_thres sweep at lr 0.01 (Table 5),
  lr sweep at l_thres −0.1 (Table 6), as in the paper (no refinement), plus our default
  (refinement on). Columns: mean iterations, time per pose (batch wall time / poses), Δθ, MuJoCo
  contacts per pose before and after, certified-free share, wall time of the batch.
- Trajectories: ``--pairs`` start/goal pairs of free poses whose straight interpolation collides
  (dense check), on Panda-blocks and UR5e wall-and-box; penalty vs tangent: share fully free at
  the dense check, path length relative to the straight interpolation, wall time; and whether
  any path reported free collides under the exact labeller (must be 0).
- A 100-waypoint UR5e trajectory past the wall and box as a GIF.

Fields come from ``benches/fields.py`` (cached under benches/out/fields). Results go to
benches/out/optimise.json and .md. Timings on shared machines are inflated by contention.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

import profrobot
from profrobot.optim import PenaltyOptions, TangentOptions, plan_trajectories, resolve
from profrobot.exact.problems import colliding_poses, hard_pairs

from fields import OUT as FIELDS_OUT, field

OUT = FIELDS_OUT.parent
PAPER_T5 = {0.0: (19.017, 0.155, 0.162, 5.557, 0.399), -0.001: (19.392, 0.156, 0.165, 5.633, 0.375),
            -0.005: (18.874, 0.153, 0.159, 5.508, 0.312), -0.01: (20.124, 0.154, 0.173, 5.617, 0.187),
            -0.02: (20.090, 0.162, 0.173, 5.471, 0.080), -0.03: (20.236, 0.160, 0.172, 5.343, 0.019),
            -0.04: (21.256, 0.171, 0.181, 5.626, 0.016), -0.05: (22.627, 0.174, 0.190, 5.757, 0.006),
            -0.1: (24.450, 0.192, 0.203, 5.197, 0.001)}
PAPER_T6 = {0.001: (241.363, 1.841, 0.203, 5.460, 0.003), 0.01: (24.450, 0.192, 0.203, 5.197, 0.001),
            0.02: (12.826, 0.104, 0.215, 5.495, 0.000), 0.05: (5.634, 0.049, 0.236, 5.622, 0.000),
            0.1: (3.026, 0.028, 0.256, 5.569, 0.000), 0.2: (1.785, 0.018, 0.315, 5.635, 0.001),
            0.5: (1.127, 0.013, 0.527, 5.326, 0.000), 1.0: (1.104, 0.013, 1.040, 5.553, 0.000)}


def contacts(robot, poses) -> float:
    return float(profrobot.mujoco_labels(robot, poses).ncon.mean())


def resolve_row(sdf, robot, poses, before, **kw) -> dict:
    res = resolve(sdf, poses, robot=robot, **kw)
    moved = res.poses - poses   # Panda-blocks has no continuous joints
    # delta: the L2 norm (ours); the paper's Δθ grows as lr × iterations, like a per-joint change,
    # so the per-joint RMS (‖Δθ‖/√K) and mean |Δθ_k| are given too
    return dict(iterations=float(res.iterations.mean()), time_per_pose=res.seconds / len(poses),
                delta=float(res.delta.mean()), delta_rms=float(res.delta.mean() / np.sqrt(poses.shape[1])),
                delta_mean_abs=float(np.abs(moved).mean()), before=before, after=contacts(robot, res.poses),
                mujoco_colliding_after=float((profrobot.mujoco_labels(robot, res.poses).ncon > 0).mean()),
                certified=float(res.certified.mean()), wall=res.seconds, rounds=res.rounds,
                max_iterations=int(res.iterations.max()))


def bench_resolve(n: int, default_only: bool = False) -> dict:
    robot = profrobot.scenes.load("panda_blocks")
    sdf = field("panda_blocks")
    poses = colliding_poses(robot, n, seed=100)
    before = contacts(robot, poses)
    resolve(sdf, poses[:10], robot=robot)            # warm-up (first-call allocations)
    out = {"t5": {}, "t6": {}, "default": None, "n": len(poses), "field": sdf.metrics}
    out["default"] = resolve_row(sdf, robot, poses, before)
    print("default (refine on)", out["default"], flush=True)
    if default_only:
        return out
    for l in PAPER_T5:
        out["t5"][l] = resolve_row(sdf, robot, poses, before, l_thres=l, lr=0.01, refine=False, method="adam",
                                   shrink=False)
        print("l_thres", l, out["t5"][l], flush=True)
    for lr in PAPER_T6:
        out["t6"][lr] = resolve_row(sdf, robot, poses, before, l_thres=-0.1, lr=lr, refine=False, method="adam",
                                    shrink=False)
        print("lr", lr, out["t6"][lr], flush=True)
    return out


def bench_trajectories(scene: str, n: int, methods) -> dict:
    robot = profrobot.scenes.load(scene)
    sdf = field(scene)
    starts, goals = hard_pairs(robot, n, seed=200)
    out = {"pairs": len(starts), "field": sdf.metrics}
    for name, kw in methods.items():
        t = time.perf_counter()
        res = plan_trajectories(sdf, starts, goals, steps=100, robot=robot, **kw)
        wall = time.perf_counter() - t
        free = np.array([r.certified for r in res])
        # independent re-check: any path reported free must be free under the exact labeller
        false_free = sum(bool(profrobot.label_poses(robot, r.check.dense).collides.any()) for r in res if r.certified)
        out[name] = dict(free=float(free.mean()), relative_length=float(np.mean([r.relative_length for r in res])),
                         relative_length_free=float(np.mean([r.relative_length for r in res if r.certified])) if free.any() else None,
                         wall=wall, wall_per_problem=wall / len(res), reported_free_but_colliding=false_free,
                         mean_iterations=float(np.mean([r.iterations for r in res])))
        print(scene, name, out[name], flush=True)
    return out


def bench_gif() -> dict:
    from profrobot.optim.pictures import plot_trajectory, render_trajectory

    robot = profrobot.scenes.load("ur5e_wall_box")
    sdf = field("ur5e_wall_box")
    starts, goals = hard_pairs(robot, 30, seed=300)
    # of the problems solved, the one whose straight path hits the wall or box (not only the
    # floor or itself) the most: the clearest demonstration
    results = plan_trajectories(sdf, starts, goals, steps=100, robot=robot,
                              penalty=PenaltyOptions(lr=0.05, iterations=200, check_every=5))
    hits = [profrobot.label_poses(robot, profrobot.interpolate(robot, a, b, 100)).scene_collides.sum()
            for a, b in zip(starts, goals)]
    solved = [i for i, r in enumerate(results) if r.certified] or list(range(len(results)))
    worst = max(solved, key=lambda i: hits[i])
    res = results[worst]
    straight = profrobot.interpolate(robot, starts[worst], goals[worst], 100)
    gif = render_trajectory(robot, res.path, OUT / "ur5e_wall_box_trajectory.gif", size=(320, 240))
    render_trajectory(robot, straight, OUT / "ur5e_wall_box_straight.gif", size=(320, 240))
    with torch.no_grad():
        g_straight = sdf(torch.as_tensor(straight, dtype=torch.float32)).numpy()
    plot_trajectory(res, OUT / "ur5e_wall_box_trajectory.png", joint_names=robot.joint_names, straight=g_straight)
    print("gif", gif, res.summary(), flush=True)
    return dict(gif=str(Path(gif).resolve().relative_to(Path(__file__).resolve().parents[1])), free=res.certified, summary=res.summary(),
                straight_colliding_waypoints=int(profrobot.label_poses(robot, straight).collides.sum()))


def markdown(results: dict) -> str:
    lines = []
    r = results.get("resolve")
    if r:
        lines += [f"## Collision resolution, Panda-blocks, {r['n']} colliding poses", "",
                  f"Field: accuracy {r['field'].get('accuracy', float('nan')):.4f}. Ours / paper. "
                  "Time per pose = batch wall time / poses (ours batched).", ""]
        head = "| {} | iter. | time/pose (s) | Δθ | before | after | certified free | batch wall (s) |"
        for _key, table, paper, label in (("t5", r["t5"], PAPER_T5, "l_thres"), ("t6", r["t6"], PAPER_T6, "lr")):
            lines += [head.format(label), "|---|---|---|---|---|---|---|---|"]
            for k, row in table.items():
                p = paper[float(k)]
                lines.append(f"| {k} | {row['iterations']:.2f} / {p[0]} | {row['time_per_pose']:.4f} / {p[1]} | "
                             f"{row['delta']:.3f} / {p[2]} | {row['before']:.3f} / {p[3]} | {row['after']:.3f} / {p[4]} | "
                             f"{row['certified']:.1%} | {row['wall']:.2f} |")
            lines.append("")
        d = results.get("resolve_default") or r["default"]
        lines += [f"Default (l_thres −0.1, lr 0.01, refinement on): iterations {d['iterations']:.2f}, "
                  f"Δθ {d['delta']:.3f} (L2; per-joint RMS {d.get('delta_rms', float('nan')):.3f}, mean |Δθ_k| "
                  f"{d.get('delta_mean_abs', float('nan')):.3f}), MuJoCo contacts {d['before']:.3f} → {d['after']:.4f}, certified "
                  f"{d['certified']:.1%}, batch {d['wall']:.2f} s ({d['rounds']} refinement rounds).", ""]
    for scene in ("panda_blocks", "ur5e_wall_box"):
        t = results.get(f"traj_{scene}")
        if not t:
            continue
        lines += [f"## Trajectories, {scene}, {t['pairs']} hard pairs, 100 waypoints, dense check 10×", "",
                  "| method | fully free | length / straight (all) | (free only) | wall per problem (s) | reported free but colliding |",
                  "|---|---|---|---|---|---|"]
        for m, row in t.items():
            if isinstance(row, dict) and "free" in row:
                lf = row["relative_length_free"]
                lines.append(f"| {m} | {row['free']:.0%} | {row['relative_length']:.2f} | "
                             f"{'-' if lf is None else f'{lf:.2f}'} | {row['wall_per_problem']:.2f} | {row['reported_free_but_colliding']} |")
        lines.append("")
    if results.get("gif"):
        lines += [f"UR5e GIF: {results['gif']['gif']} ({results['gif']['summary']})", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sections", default="resolve,trajectories,gif")
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--pairs", type=int, default=100)
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (1: on an oversubscribed machine 2 threads ran ~10x slower)")
    ap.add_argument("--methods", default="penalty,tangent")
    ap.add_argument("--scenes", default="panda_blocks,ur5e_wall_box", help="trajectory scenes")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    path = OUT / "optimise.json"
    results = {}
    sections = args.sections.split(",")
    # lr 0.05 / δ 0.03: fewer steps on two shared cores (100 problems × 100 waypoints per step)
    methods = {"penalty": dict(method="penalty", penalty=PenaltyOptions(lr=0.05, iterations=200, check_every=5)),
               "tangent": dict(method="tangent", tangent=TangentOptions(delta=0.03, iterations=1500)),
               "tangent_l2": dict(method="tangent", tangent=TangentOptions(delta=0.03, iterations=1500, goal_norm="l2"))}
    methods = {k: methods[k] for k in args.methods.split(",")}
    if "resolve" in sections:
        results["resolve"] = bench_resolve(args.poses)
    if "resolve_default" in sections:  # only our default row (refinement on), kept beside the tables
        results["resolve_default"] = bench_resolve(args.poses, default_only=True)["default"]
    if "trajectories" in sections:
        for scene in args.scenes.split(","):
            results[f"traj_{scene}"] = bench_trajectories(scene, args.pairs, methods)
    if "gif" in sections:
        results["gif"] = bench_gif()
    results["threads"] = args.threads
    OUT.mkdir(parents=True, exist_ok=True)
    if path.exists():  # sections run separately add up
        old = json.loads(path.read_text())
        for key, value in results.items():   # one method re-run keeps the others' rows
            if key.startswith("traj_") and isinstance(old.get(key), dict):
                results[key] = {**old[key], **value}
        results = {**old, **results}
    path.write_text(json.dumps(results, indent=1, default=float))
    (OUT / "optimise.md").write_text(markdown(json.loads(path.read_text())))
    print(markdown(json.loads(path.read_text())))


if __name__ == "__main__":
    main()
