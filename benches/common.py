"""What the field benches share (one module, imported by each; no bench imports another):
the output folder, the machine's load, held-out layouts, evaluation sets and scores."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

import profrobot
from profrobot.exact.crosscheck import mujoco_labels
from profrobot.exact.problems import colliding_poses, free_poses

OUT = Path(__file__).resolve().parent / "out"


def load() -> str:
    """The machine's load averages (1, 5, 15 min), to print beside every timing."""
    return ", ".join(f"{x:.2f}" for x in os.getloadavg())


def held_out_layouts(family, n: int, seed: int = 10_000) -> np.ndarray:
    """``n`` layouts from seeds no training run uses, skipping any whose blocks overlap the base."""
    out, k = [], 0
    while len(out) < n:
        for d in profrobot.sample_poses(family, 4 * n, seed=seed + k)[:, family.scene_index]:
            try:
                family.at(d)
            except profrobot.InputError:
                continue
            out.append(d)
            if len(out) == n:
                break
        k += 1
    return np.array(out)


def eval_set(static, seed: int, n: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    q = np.concatenate([colliding_poses(static, n, seed=seed), free_poses(static, n, seed=seed + 1)])
    return q, mujoco_labels(static, q, progress=False).collides


@torch.no_grad()
def scores(g: np.ndarray, y: np.ndarray) -> dict:
    pred = g > 0
    tpr, tnr = float(np.mean(pred[y])), float(np.mean(~pred[~y]))
    return dict(balanced=(tpr + tnr) / 2, false_free=1 - tpr, free_called_colliding=1 - tnr)


def values(sdf, q: np.ndarray, layout=None) -> np.ndarray:
    with torch.no_grad():
        x = torch.as_tensor(q, dtype=torch.float32)
        return (sdf(x, layout=layout) if layout is not None else sdf(x)).numpy()
