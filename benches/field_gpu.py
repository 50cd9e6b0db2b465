"""``python benches/field_gpu.py [--scenes a,b]`` on a machine with a CUDA GPU: the library's
defaults (``train_sdf(robot, device="cuda")``: the pair field, 1 M poses, 8000 iterations at
batch 2048) on xarm7_table, vx300s_clutter and shadow_hand, each scored on 10 000 colliding +
10 000 free poses of an unseen seed (exact labels, which agree with MuJoCo's on these scenes;
``benches/field.py heldout`` checks that). The time is the whole call, as a user waits: dataset,
labels, features, Jacobian pool, training and evaluation.

Writes benches/out/field_gpu.json. benches/field_gpu_results.md records the runs.
"""

from __future__ import annotations

import argparse
import json
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="xarm7_table,vx300s_clutter,shadow_hand")
    args = ap.parse_args(argv)
    if not torch.cuda.is_available():
        raise SystemExit("benches/field_gpu.py needs a CUDA device (torch.cuda.is_available() is False)")
    rows = []
    for scene in args.scenes.split(","):
        robot = profrobot.scenes.load(scene)
        test = profrobot.make_dataset(robot, 20_000, seed=TEST_SEED, progress=False)
        torch.cuda.synchronize()
        t = time.perf_counter()
        sdf = profrobot.train_sdf(robot, device="cuda", progress=False)
        torch.cuda.synchronize()
        total = time.perf_counter() - t
        h = sdf.history
        rows.append(dict(scene=scene, device="cuda", total_s=round(total, 1), train_s=round(sdf.metrics["train_seconds"], 1),
                         iterations=sdf.metrics["iterations"], pairs=len(sdf.config.get("pairs") or []),
                         ms_per_iteration=round(1000 * (h[-1]["seconds"] - h[9]["seconds"]) / (len(h) - 10), 2),
                         **scored(sdf, test)))
        print(json.dumps(rows[-1]), flush=True)
    OUT.mkdir(exist_ok=True)
    with atomic_path(OUT / "field_gpu.json") as tmp:
        tmp.write_text(json.dumps(dict(device=torch.cuda.get_device_name(0), torch=torch.__version__, rows=rows), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
