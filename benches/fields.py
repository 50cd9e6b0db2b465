"""Fields for the optimisation benchmarks: trained once per scene with a reduced budget of the
library's default recipe ("kinematic" encoder), cached under ``benches/out/fields/<scene>``.

``python benches/fields.py [scene ...]`` trains the missing ones (default: panda_blocks,
ur5e_wall_box).
"""

from __future__ import annotations

import sys
from pathlib import Path

import profrobot

OUT = Path(__file__).resolve().parent / "out" / "fields"
# Reduced budget: the default recipe is 3000 iterations on 2 M poses; on two shared CPU cores we
# stop at 600 iterations or 15 minutes, whichever comes first (the schedule stretches to fit).
# One torch thread: on a shared, oversubscribed machine two threads ran ~10x slower than one.
RECIPE = dict(n_poses=400_000, iterations=600, eikonal_batch=256, time_budget=900.0, threads=1)


def field(scene: str, *, progress: bool = True) -> profrobot.PoseSDF:
    """The cached field for ``scene``, trained first if missing."""
    robot = profrobot.scenes.load(scene)
    path = OUT / scene
    if path.is_dir():
        return profrobot.PoseSDF.load(path, robot)
    sdf = profrobot.train_sdf(robot, progress=progress, **RECIPE)
    sdf.save(path)
    return sdf


if __name__ == "__main__":
    for name in sys.argv[1:] or ["panda_blocks", "ur5e_wall_box"]:
        sdf = field(name, progress=False)
        print(name, sdf.metrics, flush=True)
