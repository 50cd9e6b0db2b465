"""``python benches/field.py cost [--scenes xarm7_table] [--field DIR]``: the field's evaluation cost
per pose (issue 38, acceptance 4).

µs per pose for g, and for g with ∂g/∂θ (one backward), at batch 10 000 on torch's threads,
median of 15 calls: the single-MLP field (``preset="cpu"``: kinematic encoder, 4 × 256; its cost
does not depend on its weights) beside the default field, ``--field DIR`` (a trained checkpoint,
e.g. ``benches/out/fields/xarm7_table_default`` from ``field.py heldout``: a trained pair field
keeps only its colliding pairs) or, without it, a pair field over every candidate pair. Prints the
ratios and the load average.
"""

from __future__ import annotations

import os
import time

import numpy as np
import torch

import profrobot
from profrobot.field import PoseSDF


def per_pose(sdf, q: torch.Tensor, grad: bool, repeats: int = 15) -> float:
    def call():
        if grad:
            t = q.clone().requires_grad_(True)
            torch.autograd.grad(sdf(t).sum(), t)
        else:
            with torch.no_grad():
                sdf(q)
    call()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return 1e6 * float(np.median(times)) / len(q)


def cost_bench(args) -> int:
    for name in (args.scenes or "xarm7_table").split(","):
        robot = profrobot.scenes.load(name)
        q = torch.as_tensor(profrobot.sample_poses(robot, 10_000, seed=1), dtype=torch.float32)
        fields = {"cpu preset (kinematic, 4 x 256)": PoseSDF(robot, encoder="kinematic", hidden=(256,) * 4)}
        if args.field:
            fields[f"default ({args.field})"] = PoseSDF.load(args.field, robot)
        else:
            fields["pairs 32 x 32, every pair"] = PoseSDF(robot, encoder="pairs", hidden=(32, 32))
        rows = {k: (per_pose(f.eval(), q, False), per_pose(f, q, True)) for k, f in fields.items()}
        base = next(iter(rows.values()))
        print(f"{name}, batch 10 000, torch threads {torch.get_num_threads()}, load average "
              f"{', '.join(f'{x:.2f}' for x in os.getloadavg())}")
        for k, (g, gg) in rows.items():
            pairs = getattr(fields[k].encoder, "npair", None)
            print(f"  {k}{f' ({pairs} pairs)' if pairs else ''}: g {g:.1f} µs ({g / base[0]:.2f}x), "
                  f"g + dg/dθ {gg:.1f} µs ({gg / base[1]:.2f}x)")
    return 0
