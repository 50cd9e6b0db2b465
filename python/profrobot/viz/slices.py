"""Pictures: an SDF slice over two joints with the exact labels drawn over it."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch

from ..files import atomic_path
from ..errors import InputError
from ..robot.family import Layout
from ..robot.gate import robot_at
from ..robot.margin import CLEARANCE
from ..robot.robot import Robot

if TYPE_CHECKING:   # matplotlib (no profrobot module) loads when a figure is drawn
    from matplotlib.figure import Figure


class SlicedField(Protocol):
    """What :func:`sdf_slice` evaluates: a collision field, g (B,) at poses θ (B, K) (a
    :class:`~profrobot.PoseSDF`, or a family field at a layout; this layer sits below the field's)."""

    def __call__(self, theta: torch.Tensor) -> torch.Tensor: ...


def save_figure(fig: Figure, path: str | os.PathLike, **kwargs) -> Path:
    """Save a matplotlib figure atomically (temporary file in the same folder, then rename)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return path


def sdf_slice(sdf: SlicedField, robot: Robot, joints: tuple[int, int] = (1, 3), base_pose: np.ndarray | None = None,
              resolution: int = 120, path: str | os.PathLike | None = None, *, layout: Layout | None = None,
              margin: float = CLEARANCE) -> Figure:
    """g over joints ``joints`` (indices; the others fixed at ``base_pose``, default the middle of
    their ranges), as a heat map with g = 0 drawn, and the exact labeller's colliding region
    outlined over it (the paper's supplementary figure). Returns the matplotlib Figure; saves a PNG
    when ``path`` is given.

    ``layout``: a family's layout δ (:mod:`profrobot.robot.gate`): the slice is then over its θ
    (``joints`` index θ, ``base_pose`` (K − D,)) and the field is asked at ``robot.compose(θ, δ)``;
    a family without one is sliced over its full poses. ``margin``: metres the exact outline keeps
    from every obstacle (a field trained at a margin is compared with the labels at that margin).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ..exact.labels import label_poses

    exact_robot = robot_at(robot, layout=layout, margin=margin, family=True)
    i, j = (int(k) for k in joints)
    K = exact_robot.njoint
    if not (0 <= i < K and 0 <= j < K and i != j):
        raise InputError(f"joints must be two distinct indices in [0, {K}); got {joints}")
    lim = exact_robot.joint_limits
    base = lim.mean(1) if base_pose is None else np.asarray(base_pose, dtype=np.float64).reshape(K)
    a = np.linspace(lim[i, 0], lim[i, 1], resolution)
    b = np.linspace(lim[j, 0], lim[j, 1], resolution)
    A, Bg = np.meshgrid(a, b)
    poses = np.repeat(base[None], A.size, axis=0)
    poses[:, i], poses[:, j] = A.ravel(), Bg.ravel()
    with torch.no_grad():
        full = poses if layout is None else robot.compose(poses, layout)
        g = sdf(torch.as_tensor(full, dtype=torch.float32)).numpy().reshape(A.shape)
    exact = label_poses(exact_robot, poses).collides.reshape(A.shape)
    fig, ax = plt.subplots(figsize=(6, 5))
    vmax = float(np.abs(g).max()) or 1.0
    im = ax.pcolormesh(A, Bg, g, cmap="RdBu_r", vmin=-vmax, vmax=vmax, shading="auto")
    ax.contour(A, Bg, g, levels=[0.0], colors="k", linewidths=1.5)
    ax.contour(A, Bg, exact.astype(float), levels=[0.5], colors="yellow", linewidths=1.5, linestyles="--")
    fig.colorbar(im, ax=ax, label="g(θ)  (> 0: colliding)")
    names = exact_robot.joint_names
    unit = lambda k: "m" if exact_robot.joint_types[k] == "slide" else "rad"
    ax.set_xlabel(f"{names[i]} ({unit(i)})")
    ax.set_ylabel(f"{names[j]} ({unit(j)})")
    agree = float(np.mean((g > 0) == exact))
    ax.set_title(f"{robot.name}: g = 0 (black) vs exact boundary (yellow)\nagreement on this slice {agree:.1%}",
                 fontsize=10)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, dpi=120)
    return fig
