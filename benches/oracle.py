"""Δθ of collision resolution against the oracle (issue 13, part 2): how much farther than the
nearest free pose the exact labeller can find does ``resolve`` move each colliding pose?

    python benches/oracle.py [--poses 1000] [--field benches/out/fields/panda_blocks]
                             [--rows default,0.0,-0.01,-0.1] [--directions 1024 --refine 4096]

Panda-blocks, the colliding poses of benches/optimise.py (``colliding_poses(robot, n, seed=100)``).
For each row (``default``: l_thres −0.1, lr 0.01, refinement on; a number: that l_thres at lr
0.01, refinement off, as the paper's Table 5), Δθ(resolve) / Δθ(oracle) per pose over the
poses resolve certifies free: median and 90th percentile, beside the mean Δθ (ours and the
paper's Table 5 column). The oracle's distance is an upper bound on the true nearest free
distance, so the ratios are lower bounds.

The field comes from benches/fields.py (``--field``: a saved field directory instead).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

import profrobot
from profrobot.optim import resolve
from profrobot.problems import colliding_poses

PAPER_T5_DELTA = {0.0: 0.162, -0.001: 0.165, -0.005: 0.159, -0.01: 0.173, -0.02: 0.173, -0.03: 0.172,
                  -0.04: 0.181, -0.05: 0.190, -0.1: 0.203}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--field", type=Path, default=None, help="a saved field (default: benches/fields.py's)")
    ap.add_argument("--rows", default="default," + ",".join(str(l) for l in PAPER_T5_DELTA))
    ap.add_argument("--directions", type=int, default=1024, help="oracle rays per pose")
    ap.add_argument("--refine", type=int, default=4096, help="oracle refinement probes per pose")
    ap.add_argument("--torch-threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.torch_threads)

    robot = profrobot.scenes.load("panda_blocks")
    if args.field is None:
        from fields import field

        sdf = field("panda_blocks")
    else:
        sdf = profrobot.PoseSDF.load(args.field, robot)
    poses = colliding_poses(robot, args.poses, seed=100)
    t = time.perf_counter()
    oracle = profrobot.nearest_free(robot, poses, directions=args.directions, refine=args.refine)
    t_oracle = time.perf_counter() - t
    assert not profrobot.label_poses(robot, oracle.poses).collides.any()
    print(f"panda_blocks, {len(poses)} colliding poses; field accuracy {sdf.metrics.get('accuracy', float('nan')):.4f}; "
          f"load average {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"oracle: Δθ median {np.median(oracle.distance):.3f}, mean {oracle.distance.mean():.3f}, "
          f"p90 {np.quantile(oracle.distance, 0.9):.3f} rad (L2); {oracle.checks.mean():,.0f} labelled poses "
          f"per pose, {t_oracle:.1f} s ({args.directions} rays, {args.refine} refinements)")
    resolve(sdf, poses[:10], robot=robot)  # warm-up
    print()
    print("| row | Δθ resolve (mean, L2) | paper Δθ (Table 5) | Δθ oracle (mean) | ratio median | ratio p90 | certified |")
    print("|---|---|---|---|---|---|---|")
    for row in args.rows.split(","):
        if row == "default":
            res = resolve(sdf, poses, robot=robot, l_thres=-0.1, lr=0.01)
            paper = "–"
        else:
            l_thres = float(row)
            res = resolve(sdf, poses, robot=robot, l_thres=l_thres, lr=0.01, refine=False)
            paper = f"{PAPER_T5_DELTA.get(l_thres, float('nan')):.3f}"
        ok = res.certified
        ratio = res.delta[ok] / oracle.distance[ok]
        print(f"| {row} | {res.delta.mean():.3f} | {paper} | {oracle.distance.mean():.3f} | {np.median(ratio):.2f} "
              f"| {np.quantile(ratio, 0.9):.2f} | {ok.mean():.1%} |", flush=True)
    print("\nratio: Δθ(resolve) / Δθ(oracle) per pose, over the poses resolve certifies free. The paper's Δθ "
          "column is its own scene and measure (see benches/optimise_results.md).")


if __name__ == "__main__":
    main()
