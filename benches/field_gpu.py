"""``python benches/field_gpu.py`` on a machine with a CUDA GPU: ``train_sdf(device="cuda")``.

Two parts, each field scored on 10 000 colliding + 10 000 free poses of an unseen seed (exact
labels, which agree with MuJoCo's on these scenes; ``benches/field.py heldout`` checks that):

1. xarm7_table, one 2 M-pose dataset: the default recipe on the GPU, the pair field
   (``encoder="pairs"``, 64 × 64 per pair, batch 8192) on the GPU, and the default recipe on the
   machine's CPU cores for a per-iteration comparison;
2. the pair field on xarm7_table, vx300s_clutter and shadow_hand with 45 s of training each.

Writes benches/out/field_gpu.json. The run recorded in benches/field_gpu_results.md used this
code on one H200 (issue 38's session).
"""

from __future__ import annotations

import json
import os
import time

import torch

import profrobot
from profrobot.field.metrics import field_values
from profrobot.files import atomic_path

from family_bench import scores
from field import OUT
from field_heldout import TEST_SEED


def scored(sdf, test) -> dict:
    r = scores(field_values(sdf, test.poses), test.collides)
    return dict(balanced_accuracy=round(100 * r["balanced"], 3), colliding_called_free=round(100 * r["false_free"], 3))


def main() -> int:
    if not torch.cuda.is_available():
        raise SystemExit("benches/field_gpu.py needs a CUDA device (torch.cuda.is_available() is False)")
    rows = []
    robot = profrobot.scenes.load("xarm7_table")
    test = profrobot.make_dataset(robot, 20_000, seed=TEST_SEED, progress=False)
    data = profrobot.make_dataset(robot, 2_000_000, seed=0, progress=False)
    for device, opts in (("cuda", dict(time_budget=40)),
                         ("cuda", dict(time_budget=60, encoder="pairs", hidden=(64, 64), batch_size=8192)),
                         ("cpu", dict(time_budget=20, threads=os.cpu_count()))):
        t = time.perf_counter()
        sdf = profrobot.train_sdf(data, robot=robot, device=device, progress=False, **opts)
        total = time.perf_counter() - t
        h = sdf.history
        rows.append(dict(part=1, scene=robot.name, device=device, opts={k: str(v) for k, v in opts.items()},
                         total_s=round(total, 1), train_s=round(sdf.metrics["train_seconds"], 1),
                         iterations=sdf.metrics["iterations"],
                         ms_per_iteration=round(1000 * (h[-1]["seconds"] - h[9]["seconds"]) / (len(h) - 10), 2),
                         **scored(sdf, test)))
        print(json.dumps(rows[-1]), flush=True)
    for scene, extra in (("xarm7_table", dict(iterations=8000)), ("vx300s_clutter", {}), ("shadow_hand", dict(iterations=4000))):
        robot = profrobot.scenes.load(scene)
        test = profrobot.make_dataset(robot, 20_000, seed=TEST_SEED, progress=False)
        t = time.perf_counter()
        sdf = profrobot.train_sdf(robot, device="cuda", progress=False, encoder="pairs", hidden=(64, 64),
                                  batch_size=8192, time_budget=45, **extra)
        rows.append(dict(part=2, scene=scene, device="cuda", total_s=round(time.perf_counter() - t, 1),
                         iterations=sdf.metrics["iterations"], **scored(sdf, test)))
        print(json.dumps(rows[-1]), flush=True)
    OUT.mkdir(exist_ok=True)
    with atomic_path(OUT / "field_gpu.json") as tmp:
        tmp.write_text(json.dumps(dict(device=torch.cuda.get_device_name(0), torch=torch.__version__, rows=rows), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
