"""A picture of a layout estimate: what each depth pixel was taken for, and the fitted obstacles.

Left, one camera's view: each valid pixel coloured by its kind (the robot's, removed: red; the
modelled static scene: grey, shaded by depth; explained by a fitted obstacle: that obstacle's
colour; an obstacle candidate no obstacle explains: black; behind the model, unexplained: dark
blue; missing: white), and the fitted obstacles' surfaces projected over it as dots. Right, the
scene from above (world x right, y up): the same points (every few) and the fitted obstacles'
outlines, the robot's removed points in red.
"""

from __future__ import annotations

import os
from pathlib import Path

from typing import TYPE_CHECKING, Any

import numpy as np

from ...files import atomic_path
from ...robot.robot import Robot

from .kinds import OBSTACLE, ROBOT, STATIC, UNEXPLAINED
from .fit import Placer, movable_obstacles
from .depth import DEFAULT_GEOMGROUP

if TYPE_CHECKING:   # matplotlib (no profrobot module) loads when a figure is drawn
    from matplotlib.figure import Figure


__all__ = ["layout_picture"]

_COLOURS = np.array([[0.12, 0.47, 0.71], [1.0, 0.5, 0.05], [0.17, 0.63, 0.17], [0.58, 0.4, 0.74],
                     [0.55, 0.34, 0.29], [0.89, 0.47, 0.76], [0.74, 0.74, 0.13], [0.09, 0.75, 0.81]])


def _fitted_surfaces(est: Any, family: Robot) -> list[tuple[str, np.ndarray]]:
    """(name, world surface points (P, 3)) of every estimated obstacle."""
    m = family.mj_model
    qpos = m.qpos0.copy()
    qpos[family.qpos_adr[family.robot_index]] = est.pose
    placer = Placer(m, qpos)
    out = []
    for ob in movable_obstacles(family, np.asarray(DEFAULT_GEOMGROUP, np.uint8)):
        if ob.name not in est.support:
            continue
        frames, _, _ = placer.frames(ob, est.layout[ob.joints])
        pts = [s.surface_points(500) @ R.T + x for s, (x, R) in zip(ob.solids, frames)]
        out.append((ob.name, np.concatenate(pts)))
    return out


def layout_picture(est: Any, family: Robot, path: str | os.PathLike | None = None, *, camera: int = 0) -> Figure:
    """The figure (module docs); saved as a PNG when ``path`` is given. Returns the Figure."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    cams = est.cameras
    H, W = cams.height, cams.width
    names = list(est.obstacles)
    img = np.ones((H, W, 3))
    sel = est.camera == camera
    u, v = est.pixel[sel, 0].astype(int), est.pixel[sel, 1].astype(int)
    kind, owner = est.kind[sel], est.owner[sel]
    depth = np.linalg.norm(est.points[sel] - cams.centres()[camera], axis=1)
    shade = 0.45 + 0.5 * (depth - depth.min()) / max(float(np.ptp(depth)), 1e-9) if len(depth) else depth
    img[v, u] = np.where((kind == STATIC)[:, None], shade[:, None] * np.ones(3), img[v, u])
    img[v[kind == ROBOT], u[kind == ROBOT]] = (0.85, 0.15, 0.15)
    img[v[kind == UNEXPLAINED], u[kind == UNEXPLAINED]] = (0.1, 0.1, 0.35)
    cand = kind == OBSTACLE
    img[v[cand], u[cand]] = (0.0, 0.0, 0.0)
    for j in range(len(names)):
        on = cand & (owner == j)
        img[v[on], u[on]] = _COLOURS[j % len(_COLOURS)]

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 5.2))
    ax0.imshow(img, interpolation="nearest")
    surfaces = _fitted_surfaces(est, family)
    for name, pts in surfaces:
        j = names.index(name)
        uv = cams.project(pts)[camera]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        ax0.scatter(uv[inside, 0], uv[inside, 1], s=1.0, color=_COLOURS[j % len(_COLOURS)] * 0.6, label=name)
    ax0.set_title(f"camera {camera}: red robot (removed), grey static, colours fitted obstacles")
    ax0.set_axis_off()

    step = max(1, len(est.points) // 20000)
    P, K, O = est.points[::step], est.kind[::step], est.owner[::step]
    for k, colour, label in ((STATIC, (0.75, 0.75, 0.75), "static"), (UNEXPLAINED, (0.1, 0.1, 0.35), "unexplained"),
                             (ROBOT, (0.85, 0.15, 0.15), "robot (removed)")):
        on = K == k
        ax1.scatter(P[on, 0], P[on, 1], s=0.3, color=colour, label=label)
    for j in range(len(names)):
        on = (K == OBSTACLE) & (O == j)
        ax1.scatter(P[on, 0], P[on, 1], s=0.5, color=_COLOURS[j % len(_COLOURS)])
    on = (K == OBSTACLE) & (O < 0)
    ax1.scatter(P[on, 0], P[on, 1], s=0.5, color="k", label="candidates nothing explains")
    for name, pts in surfaces:
        j = names.index(name)
        ax1.scatter(pts[:, 0], pts[:, 1], s=0.4, color=_COLOURS[j % len(_COLOURS)] * 0.6)
        c = pts.mean(axis=0)
        ax1.annotate(name, c[:2], fontsize=8)
    # the region that matters: the robot and the obstacles (the floor reaches the horizon)
    keep = [P[(K == ROBOT) | ((K == OBSTACLE) & (O >= 0))]] + [pts for _, pts in surfaces]
    region = np.concatenate([k for k in keep if len(k)]) if any(len(k) for k in keep) else P
    if len(region):
        lo, hi = region[:, :2].min(axis=0) - 0.15, region[:, :2].max(axis=0) + 0.15
        ax1.set_xlim(lo[0], hi[0])
        ax1.set_ylim(lo[1], hi[1])
    ax1.set_aspect("equal")
    ax1.set_xlabel("x (m)")
    ax1.set_ylabel("y (m)")
    missing = [n for n in names if n not in est.support]
    ax1.set_title(f"from above; margin {est.margin * 1000:.1f} mm" + (f"; not estimated: {', '.join(missing)}" if missing else ""))
    ax1.legend(loc="upper right", fontsize=7, markerscale=8)
    fig.tight_layout()
    if path is not None:
        with atomic_path(Path(path)) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    return fig
