"""``python benches/field.py scenes``: one field for a family of scenes (issue: g(θ, δ)).

On panda_blocks_moving (Panda, three blocks each ±15 cm in x and y and ±45° of yaw, δ ∈ R⁹):

- (a) the family field g(θ, δ), trained once (the default recipe, ``--minutes`` of training);
- (b) a field trained on one layout alone (the upper bound), for the first ``--upper`` held-out
  layouts, ``--upper-minutes`` each;
- (c) the field of one fixed layout (δ = 0, i.e. panda_blocks: today's behaviour, the lower
  bound), ``--upper-minutes``;

scored on ``--layouts`` held-out layouts (seeds never used in training), each on 2000 colliding +
2000 free poses of that layout, labelled by MuJoCo (``mujoco_labels`` on the static scene
``family.at(δ)``): balanced accuracy (TPR + TNR) / 2 and false-free (colliding poses called free,
1 − TPR). Then at every held-out layout: ``resolve`` on 50 colliding poses and
``plan_trajectory`` on ``--pairs`` hard problems, certified at that layout, every answer
re-checked by MuJoCo; and the field's cost per pose at batch 10⁴ against today's field (same
run). Writes benches/out/field_scenes.md and .json. Fields are cached under
benches/out/fields/ (``--retrain`` to train again).
"""

from __future__ import annotations

import json
import time

import numpy as np
import torch

import profrobot
from profrobot.exact.crosscheck import mujoco_labels
from profrobot.files import atomic_path
from profrobot.exact.problems import colliding_poses, hard_pairs

from common import OUT, eval_set, held_out_layouts, load, scores, values

FAMILY = "panda_blocks_moving"


def trained(name: str, robot, poses: int, minutes: float, seed: int, retrain: bool) -> tuple:
    """A field of the default recipe with ``minutes`` of training, cached; (field, dataset s, train s, load)."""
    path = OUT / "fields" / f"{name}_{minutes:g}min_{poses}"
    if path.is_dir() and not retrain:
        sdf = profrobot.PoseSDF.load(path, robot)
        return sdf, float(sdf.metrics.get("dataset_seconds", float("nan"))), float(sdf.metrics["train_seconds"]), "cached"
    before = "load average " + load()
    t = time.perf_counter()
    data = profrobot.make_dataset(robot, poses, seed=seed, progress=False)
    data_s = time.perf_counter() - t
    sdf = profrobot.train_sdf(data, robot=robot, seed=seed, time_budget=60 * minutes, iterations=10**9, progress=True)
    sdf.metrics["dataset_seconds"] = data_s
    sdf.save(path)
    print(f"{name}: dataset {data_s:.0f} s, training {sdf.metrics['train_seconds']:.0f} s "
          f"({sdf.metrics['iterations']} iterations); before: {before}; after: load average {load()}", flush=True)
    return sdf, data_s, float(sdf.metrics["train_seconds"]), f"{before} → load average {load()}"


def cost_per_pose(sdf, poses: np.ndarray, repeats: int = 15) -> float:
    x = torch.as_tensor(poses, dtype=torch.float32)
    with torch.no_grad():
        sdf(x)
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            sdf(x)
            times.append(time.perf_counter() - t)
    return float(np.median(times)) / len(poses)


def scenes_bench(args) -> int:
    wall = time.perf_counter()
    family = profrobot.scenes.load(FAMILY)
    fixed_robot = family.at(np.zeros(len(family.scene_joints)))       # panda_blocks itself
    minutes = args.minutes or 13.0
    fam, fam_data_s, fam_train_s, fam_load = trained(FAMILY, family, args.poses, minutes, args.seed, args.retrain)
    print("family field:", fam.metrics, flush=True)
    fixed, *_ = trained("panda_blocks_at_zero", fixed_robot, args.poses, args.upper_minutes, args.seed, args.retrain)
    layouts = held_out_layouts(family, args.layouts)
    rows = []
    for i, d in enumerate(layouts):
        static = family.at(d)
        q, y = eval_set(static, seed=20_000 + i)
        row = dict(layout=i, delta=d.tolist(), colliding=int(y.sum()), n=len(y),
                   family=scores(values(fam, q, layout=d), y), fixed=scores(values(fixed, q), y))
        if i < args.upper:
            own, *_ = trained(f"{FAMILY}_layout{i}", static, args.poses, args.upper_minutes, args.seed, args.retrain)
            row["own"] = scores(values(own, q), y)
        rows.append(row)
        print(i, {k: v for k, v in row.items() if k != "delta"}, flush=True)

    # use at held-out layouts: resolve and plan_trajectory, certified there, re-checked by MuJoCo
    res_cert = res_n = res_lies = 0
    res_s = 0.0
    traj = dict(n=0, free=0, lies=0, seconds=0.0)
    for i, d in enumerate(layouts):
        static = family.at(d)
        cp = colliding_poses(static, 50, seed=30_000 + i)
        t = time.perf_counter()
        r = profrobot.resolve(fam, cp, layout=d)
        res_s += time.perf_counter() - t
        res_n += len(cp)
        res_cert += int(r.certified.sum())
        res_lies += int(mujoco_labels(static, r.poses[r.certified], progress=False).collides.sum()) if r.certified.any() else 0
        if args.pairs:
            starts, goals = hard_pairs(static, args.pairs, seed=40_000 + i)
            t = time.perf_counter()
            out = profrobot.plan_trajectories(fam, starts, goals, steps=100, layout=d)
            traj["seconds"] += time.perf_counter() - t
            for p in out:
                traj["n"] += 1
                traj["free"] += int(p.certified)
                if p.certified and mujoco_labels(static, p.check.dense, progress=False).collides.any():
                    traj["lies"] += 1
        print(f"layout {i}: resolve {res_cert}/{res_n} certified, lies {res_lies}; trajectories {traj}", flush=True)

    # evaluation cost at batch 10^4: the family field vs today's field, same run
    torch.set_num_threads(args.threads or torch.get_num_threads())
    qf = profrobot.sample_poses(family, 10_000, seed=5)
    cost_load = "load average " + load()
    c_fam = cost_per_pose(fam, qf)
    c_fixed = cost_per_pose(fixed, qf[:, family.robot_index])
    c_at = cost_per_pose(fam.at(layouts[0]), qf[:, family.robot_index])

    def mean(key, sub):
        vals = [r[key][sub] for r in rows if key in r]
        return 100 * float(np.mean(vals)), 100 * float(np.min(vals) if sub == "balanced" else np.max(vals))

    # a picture: g over joint 1 and the front block's x offset, the exact boundary over it
    from profrobot.viz import sdf_slice

    base = family.compose(family.at(layouts[0]).joint_limits.mean(1), layouts[0])
    sdf_slice(fam, family, joints=(0, family.joint_names.index("block_front_x")), base_pose=base,
              path=OUT / "field_scenes_slice.png")

    lines = [f"# One field for a family of scenes: {FAMILY} (δ ∈ R^{len(family.scene_joints)}: three blocks, "
             "±15 cm in x and y, ±45° yaw)", "",
             f"{len(layouts)} held-out layouts, each scored on 2000 colliding + 2000 free poses of that layout "
             "labelled by MuJoCo. Balanced accuracy = (TPR + TNR)/2; false-free = colliding poses called free.", "",
             "| field | trained on | training | balanced acc % mean (worst) | false-free % mean (worst) |",
             "|---|---|---|---|---|"]
    fb, ff = mean("family", "balanced"), mean("family", "false_free")
    lines.append(f"| (a) family g(θ, δ) | {args.poses:,} poses over θ and δ | {fam_train_s / 60:.1f} min "
                 f"(+ {fam_data_s:.0f} s labelling) | {fb[0]:.2f} ({fb[1]:.2f}) | {ff[0]:.2f} ({ff[1]:.2f}) |")
    if any("own" in r for r in rows):
        ob, of = mean("own", "balanced"), mean("own", "false_free")
        fo = [100 * r["family"]["balanced"] for r in rows if "own" in r]
        lines.append(f"| (b) per layout (upper bound), {sum('own' in r for r in rows)} layouts | that layout alone | "
                     f"{args.upper_minutes:g} min each | {ob[0]:.2f} ({ob[1]:.2f}); family on the same layouts "
                     f"{np.mean(fo):.2f} | {of[0]:.2f} ({of[1]:.2f}) |")
    xb, xf = mean("fixed", "balanced"), mean("fixed", "false_free")
    lines.append(f"| (c) one fixed layout (δ = 0; today) | panda_blocks | {args.upper_minutes:g} min | "
                 f"{xb[0]:.2f} ({xb[1]:.2f}) | {xf[0]:.2f} ({xf[1]:.2f}) |")
    lines += ["", f"Family field training: {fam_load}.", "",
              "## Use at held-out layouts (answers certified at that layout, re-checked by MuJoCo)", "",
              f"- `resolve`, 50 colliding poses per layout: {res_cert}/{res_n} certified "
              f"({100 * res_cert / max(res_n, 1):.1f} %), {res_lies} certified poses MuJoCo finds colliding; "
              f"{res_s:.1f} s in all",
              f"- `plan_trajectory` (defaults, 100 waypoints), {args.pairs} hard problems per layout: {traj['free']}/"
              f"{traj['n']} certified free ({100 * traj['free'] / max(traj['n'], 1):.1f} %), {traj['lies']} certified "
              f"paths MuJoCo finds colliding on the dense check; {traj['seconds']:.0f} s in all", "",
              "## Evaluation cost per pose, batch 10 000 (same run)", "",
              f"- family field g(θ, δ): {1e6 * c_fam:.2f} µs; at a layout (LayoutField): {1e6 * c_at:.2f} µs; "
              f"today's field (panda_blocks): {1e6 * c_fixed:.2f} µs; ratio {c_fam / c_fixed:.2f}× "
              f"(torch threads {torch.get_num_threads()}, {cost_load})",
              "", f"wall time {time.perf_counter() - wall:.0f} s"]
    text = "\n".join(lines) + "\n"
    OUT.mkdir(exist_ok=True)
    with atomic_path(OUT / "field_scenes.md") as tmp:
        tmp.write_text(text)
    with atomic_path(OUT / "field_scenes.json") as tmp:
        tmp.write_text(json.dumps(dict(rows=rows, resolve=dict(n=res_n, certified=res_cert, lies=res_lies),
                                       trajectories=traj, cost=dict(family=c_fam, fixed=c_fixed, layout=c_at)), indent=1))
    print(text)
    return 0
