"""``python benches/field.py families [--scenes panda_blocks_moving,vx300s_clutter_moving]
[--options JSON] [--layouts 20]``: the default field of each family of scenes, on held-out layouts
(issue 38, acceptance 2).

For each family: ``train_sdf(family)`` with the library's defaults (or ``--options``), the dataset,
its features and the training timed whole, as a user waits for them; then ``--layouts`` layouts
from seeds training never used (:func:`family_bench.held_out_layouts`), each scored on 2000
colliding + 2000 free poses of that layout labelled by MuJoCo (:func:`family_bench.eval_set` on
the static scene ``family.at(δ)``): balanced accuracy (TPR + TNR) / 2 and colliding poses called
free (1 − TPR), mean and worst layout. Writes benches/out/field_families.md and .json; the fields
go to benches/out/fields/.
"""

from __future__ import annotations

import json
import time

import numpy as np

import profrobot
from profrobot.files import atomic_path

from common import OUT, eval_set, held_out_layouts, load, scores, values


def families_bench(args) -> int:
    rows = []
    options = json.loads(args.options) if args.options else {}
    for name in (args.scenes or "panda_blocks_moving,vx300s_clutter_moving").split(","):
        family = profrobot.scenes.load(name)
        before = load()
        t = time.perf_counter()
        sdf = profrobot.train_sdf(family, seed=args.seed, **options)
        total = time.perf_counter() - t
        after = load()
        sdf.save(OUT / "fields" / f"{name}_{'default' if not options else 'options'}")
        per = []
        for i, d in enumerate(held_out_layouts(family, args.layouts)):
            q, y = eval_set(family.at(d), seed=20_000 + 7 * i)
            per.append(scores(values(sdf, q, layout=d), y))
        bal = np.array([100 * r["balanced"] for r in per])
        ff = np.array([100 * r["false_free"] for r in per])
        row = dict(scene=name, options=options, scene_joints=len(family.scene_joints), minutes=total / 60,
                   iterations=sdf.metrics["iterations"], pairs=getattr(sdf.encoder, "npair", None),
                   balanced_mean=float(bal.mean()), balanced_worst=float(bal.min()), false_free_mean=float(ff.mean()),
                   false_free_worst=float(ff.max()), layouts=len(per), load_before=before, load_after=after,
                   per_layout=per)
        print(json.dumps({k: v for k, v in row.items() if k != "per_layout"}), flush=True)
        rows.append(row)
    lines = ["# The default field on families of scenes, held-out layouts (issue 38, acceptance 2)", "",
             "`train_sdf(family)` with the defaults; each held-out layout scored on 2000 colliding + 2000 free poses "
             "labelled by MuJoCo. Time: dataset + features + training, as a user waits.", "",
             "| family | scene joints | options | balanced acc % mean (≥ 98.0) | worst layout (≥ 97) | colliding called "
             "free % mean (≤ 1.0) | worst | minutes (≤ 15) | iterations | load average before → after |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['scene_joints']} | {json.dumps(r['options']) if r['options'] else 'defaults'} | "
                     f"{r['balanced_mean']:.2f} | {r['balanced_worst']:.2f} | {r['false_free_mean']:.2f} | "
                     f"{r['false_free_worst']:.2f} | {r['minutes']:.1f} | {r['iterations']} | "
                     f"{r['load_before']} → {r['load_after']} |")
    OUT.mkdir(exist_ok=True)
    with atomic_path(OUT / "field_families.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    with atomic_path(OUT / "field_families.json") as tmp:
        tmp.write_text(json.dumps(rows, indent=1))
    print("\n".join(lines))
    return 0
