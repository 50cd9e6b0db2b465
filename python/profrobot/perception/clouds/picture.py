"""A picture of a point-cloud scene: the balls, the robot and a planned path.

Two views, from above (world x right, y up) and from the side (x right, z up): the cloud's
balls (every few, coloured by height), the robot's links (lines between body origins) at the
path's start (blue) and goal (green), and the path of the hand (the last body's origin) between
them, sampled along every segment.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from ...files import atomic_path
from ...exact.labels import interpolate
from ...robot.robot import Robot

if TYPE_CHECKING:   # matplotlib (no profrobot module) loads when a figure is drawn
    from matplotlib.figure import Figure

__all__ = ["cloud_picture"]


def _links(robot: Robot, xpos: np.ndarray) -> list[np.ndarray]:
    """(2, 3) segments from each robot body's parent origin to its own (a stick figure)."""
    parent = np.asarray(robot.core_arrays()["body_parent"])
    moving = np.zeros(len(parent), dtype=bool)
    for b in np.asarray(robot.core_arrays()["jnt_body"]):
        moving[int(b)] = True
    for b in range(1, len(parent)):
        moving[b] |= moving[int(parent[b])]
    return [np.stack([xpos[int(parent[b])], xpos[b]]) for b in range(1, len(parent)) if moving[b] and parent[b] > 0]


def cloud_picture(robot: Robot, path: str | os.PathLike | None = None, *, waypoints: npt.ArrayLike | None = None,
                  title: str | None = None) -> Figure:
    """The figure (module docs) of ``robot`` (with its :attr:`~profrobot.Robot.cloud`) and, when
    given, ``waypoints`` (T, K), a path (:class:`~profrobot.PathResult`'s ``path``); saved as a PNG
    when ``path`` is given (atomically). Returns the Figure."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    cloud = robot.cloud
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.4))
    P = cloud.points if cloud is not None else np.zeros((0, 3))
    step = max(1, len(P) // 30000)
    hand = None
    ends = []
    if waypoints is not None:
        w = np.atleast_2d(np.asarray(waypoints, dtype=np.float64))
        dense = np.concatenate([interpolate(robot, w[i:i + 1], w[i + 1:i + 2], 30)[0] for i in range(len(w) - 1)]) \
            if len(w) > 1 else w
        xpos, _ = robot.core.forward_kinematics(np.ascontiguousarray(dense))
        hand = xpos[:, -1]
        ends = [(xpos[0], "tab:blue", "start"), (xpos[-1], "tab:green", "goal")]
    for ax, (i, j), name in ((axes[0], (0, 1), "from above"), (axes[1], (0, 2), "from the side")):
        if len(P):
            ax.scatter(P[::step, i], P[::step, j], s=1.0, c=P[::step, 2], cmap="viridis", alpha=0.6, label="cloud")
        for xp, colour, label in ends:
            for k, seg in enumerate(_links(robot, xp)):
                ax.plot(seg[:, i], seg[:, j], color=colour, lw=2.5, label=label if k == 0 else None)
        if hand is not None:
            ax.plot(hand[:, i], hand[:, j], color="tab:red", lw=1.5, label="hand path")
        ax.set_aspect("equal")
        ax.set_xlabel("xyz"[i] + " (m)")
        ax.set_ylabel("xyz"[j] + " (m)")
        ax.set_title(name)
    axes[0].legend(loc="upper right", fontsize=7, markerscale=4)
    n = len(P)
    fig.suptitle(title or f"{robot.name}: {n} balls" + (f", radius {cloud.radius.min() * 1e3:.1f}–{cloud.radius.max() * 1e3:.1f} mm" if cloud is not None and n else ""))
    fig.tight_layout()
    if path is not None:
        with atomic_path(Path(path)) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    return fig
