"""``python benches/field.py heldout [--scenes xarm7_table,vx300s_clutter] [--options JSON]``: the
default field on static scenes no default was tuned on (issue 38, acceptance 1).

For each scene: ``train_sdf(robot)`` with the library's defaults (or ``--options``, e.g.
``'{"preset": "pairs"}'``), nothing else (the dataset,
its features and the training all timed, as a user would wait for them), then scored on 10 000
colliding + 10 000 free poses of a seed training never used, labelled by MuJoCo
(``mujoco_labels``): balanced accuracy (TPR + TNR) / 2, and colliding poses called free (1 − TPR).
Writes benches/out/field_heldout.md and .json (``--out-name``: another name); the fields go to benches/out/fields/.
"""

from __future__ import annotations

import json
import time

import numpy as np

import profrobot
from profrobot.exact.crosscheck import mujoco_labels
from profrobot.field.metrics import field_values
from profrobot.files import atomic_path

from common import OUT, load, scores

TEST_SEED = 987654


def score(sdf, robot, n: int = 20_000) -> dict:
    test = profrobot.make_dataset(robot, n, seed=TEST_SEED, progress=False)
    mj = mujoco_labels(robot, test.poses, progress=False).collides
    r = scores(field_values(sdf, test.poses), mj)
    return dict(balanced_accuracy=100 * r["balanced"], colliding_called_free=100 * r["false_free"],
                free_called_colliding=100 * r["free_called_colliding"], n=int(n),
                mujoco_agrees=float(np.mean(mj == test.collides)))


def heldout_bench(args) -> int:
    rows = []
    for name in (args.scenes or "xarm7_table,vx300s_clutter").split(","):
        robot = profrobot.scenes.load(name)
        before = load()
        t = time.perf_counter()
        options = json.loads(args.options) if args.options else {}
        sdf = profrobot.train_sdf(robot, seed=args.seed, **options)
        total = time.perf_counter() - t
        after = load()
        sdf.save(OUT / "fields" / f"{name}_{'default' if not options else 'options'}")
        row = dict(scene=name, options=options, minutes=total / 60, train_minutes=sdf.metrics["train_seconds"] / 60,
                   iterations=sdf.metrics["iterations"], threads=sdf.metrics["threads"], load_before=before,
                   load_after=after, **score(sdf, robot))
        print(json.dumps(row), flush=True)
        rows.append(row)
    lines = ["# The default field on held-out static scenes (issue 38, acceptance 1)", "",
             "`train_sdf(robot)` with the defaults; scored on 10 000 colliding + 10 000 free poses of an unseen seed, "
             "labelled by MuJoCo. Time: dataset + features + training, as a user waits.", "",
             "| scene | options | balanced acc % (≥ 99.0) | colliding called free % (≤ 0.5) | free called colliding % | "
             "minutes (≤ 10) | iterations | MuJoCo agrees with the exact labels | load average before → after |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {json.dumps(r['options']) if r['options'] else 'defaults'} | {r['balanced_accuracy']:.2f} | {r['colliding_called_free']:.2f} | "
                     f"{r['free_called_colliding']:.2f} | {r['minutes']:.1f} | {r['iterations']} | "
                     f"{100 * r['mujoco_agrees']:.2f} % | {r['load_before']} → {r['load_after']} |")
    OUT.mkdir(exist_ok=True)
    name = args.out_name or "field_heldout"
    with atomic_path(OUT / f"{name}.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    with atomic_path(OUT / f"{name}.json") as tmp:
        tmp.write_text(json.dumps(rows, indent=1))
    print("\n".join(lines))
    return 0
