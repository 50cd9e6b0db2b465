"""Exact signed distances of the obstacle shapes a layout is fitted with, in the geom's frame.

Each function takes points ``q`` (N, 3) in the geom's local frame (metres) and returns the signed
distance (N,) to the solid's surface: negative inside. Closed forms (Inigo Quilez's, the standard
ones), exact everywhere:

- sphere (radius r):        |q| − r
- capsule (r, half length h along z):  |q − (0, 0, clamp(q_z, −h, h))| − r
- box (half extents b):     d = |q| − b;  |max(d, 0)| + min(max_i d_i, 0)
- cylinder (r, h along z):  d = (|q_xy| − r, |q_z| − h);  |max(d, 0)| + min(max(d_1, d_2), 0)
- convex mesh (its hull's planes n_k · q ≤ o_k): inside, max_k (n_k · q − o_k), exact; outside,
  the distance to the hull's nearest vertex, edge or face, computed as the distance to the
  nearest of the faces (each face clipped to its polygon via its vertices), exact.

MuJoCo's own geom sizes and frames are used (``geom_size``, ``geom_xpos``, ``geom_xmat``), so a
fitted obstacle is the obstacle the labeller checks. Gradients come from central differences of
these functions (step 1e-6 m; the functions are 1-Lipschitz, piecewise smooth).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from ...errors import InputError

__all__ = ["Solid", "solid_of", "SUPPORTED"]

_T = mujoco.mjtGeom
#: geom types a layout can be fitted with
SUPPORTED = {int(_T.mjGEOM_SPHERE): "sphere", int(_T.mjGEOM_CAPSULE): "capsule", int(_T.mjGEOM_BOX): "box",
             int(_T.mjGEOM_CYLINDER): "cylinder", int(_T.mjGEOM_MESH): "mesh"}

_H = 1e-6


def _sphere(q, size):
    return np.linalg.norm(q, axis=1) - size[0]


def _capsule(q, size):
    r, h = size[0], size[1]
    z = np.clip(q[:, 2], -h, h)
    return np.sqrt(q[:, 0] ** 2 + q[:, 1] ** 2 + (q[:, 2] - z) ** 2) - r


def _box(q, size):
    d = np.abs(q) - size
    return np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)


def _cylinder(q, size):
    r, h = size[0], size[1]
    d1 = np.sqrt(q[:, 0] ** 2 + q[:, 1] ** 2) - r
    d2 = np.abs(q[:, 2]) - h
    return np.sqrt(np.maximum(d1, 0) ** 2 + np.maximum(d2, 0) ** 2) + np.minimum(np.maximum(d1, d2), 0.0)


def _segment_distance(q, a, b):
    """Distance (N, E) from points q (N, 3) to segments a→b (E, 3)."""
    ab = b - a
    t = np.einsum("nei,ei->ne", q[:, None, :] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-30)
    t = np.clip(t, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(q[:, None, :] - closest, axis=2)


@dataclass(frozen=True)
class Solid:
    """One geom of an obstacle: its kind, MuJoCo ``size`` (3,), and for a mesh its hull (``planes``
    (F, 4): ``n · q ≤ o`` as rows ``(n, o)``, ``edges`` (E, 2, 3), ``vertices`` (V, 3), local)."""

    geom: int
    name: str
    kind: str
    size: np.ndarray
    planes: np.ndarray | None = None
    edges: np.ndarray | None = None
    vertices: np.ndarray | None = None

    def sdf(self, q: np.ndarray) -> np.ndarray:
        """Signed distance (N,) of local points ``q`` (N, 3), metres."""
        if self.kind == "sphere":
            return _sphere(q, self.size)
        if self.kind == "capsule":
            return _capsule(q, self.size)
        if self.kind == "box":
            return _box(q, self.size)
        if self.kind == "cylinder":
            return _cylinder(q, self.size)
        assert self.planes is not None and self.edges is not None   # a mesh: its hull
        inside = q @ self.planes[:, :3].T - self.planes[:, 3]      # (N, F)
        s = inside.max(axis=1)
        out = s > 0
        if out.any():
            # outside a convex polytope the nearest point lies on an edge, a vertex or a face interior
            qo = q[out]
            d = _segment_distance(qo, self.edges[:, 0], self.edges[:, 1]).min(axis=1)
            # a face interior: the plane distance where the projection falls inside every other plane
            proj_ok = np.ones((len(qo), len(self.planes)), dtype=bool)
            io = inside[out]
            for f in range(len(self.planes)):
                p = qo - io[:, f:f + 1] * self.planes[f, :3]
                proj_ok[:, f] = ((p @ self.planes[:, :3].T - self.planes[:, 3]) <= 1e-12).all(axis=1)
            face = np.where(proj_ok & (io > 0), io, np.inf).min(axis=1)
            s = s.copy()
            s[out] = np.minimum(d, face)
        return s

    def sdf_grad(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (N,) and its gradient (N, 3) in the local frame."""
        d = self.sdf(q)
        g = np.empty_like(q)
        for i in range(3):
            e = np.zeros(3)
            e[i] = _H
            g[:, i] = (self.sdf(q + e) - self.sdf(q - e)) / (2 * _H)
        return d, g

    def extreme_points(self) -> np.ndarray:
        """Local points (P, 3) whose convex hull covers the solid (round ones: 26 directions):
        how far the solid can move is read off them."""
        dirs = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)],
                        dtype=float)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        if self.kind == "box":
            return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * self.size
        if self.kind == "sphere":
            return dirs * self.size[0] / np.cos(np.pi / 8)   # the 26-direction polytope's covering radius, inflated
        if self.kind == "capsule":
            r, h = self.size[0], self.size[1]
            ends = np.array([[0, 0, -h], [0, 0, h]])
            return (ends[:, None, :] + dirs[None] * r / np.cos(np.pi / 8)).reshape(-1, 3)
        if self.kind == "cylinder":   # two rims of 16 points, inflated to cover the circle
            r, h = self.size[0], self.size[1]
            a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
            ring = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1) * r / np.cos(np.pi / 16)
            return np.concatenate([ring + [0, 0, -h], ring + [0, 0, h]])
        assert self.vertices is not None   # a mesh: its hull
        return self.vertices

    def radius(self) -> float:
        """Metres: the largest distance from the local origin to the solid."""
        return float(np.linalg.norm(self.extreme_points(), axis=1).max())

    def surface_points(self, n: int = 400) -> np.ndarray:
        """``n`` points (n, 3) on the surface, local: along Fibonacci-sphere directions from the
        origin (inside every solid here, all convex), each crossing found by bisection to 1e-9 m."""
        i = np.arange(n) + 0.5
        phi = np.arccos(1 - 2 * i / n)
        theta = np.pi * (1 + 5 ** 0.5) * i
        u = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)
        lo, hi = np.zeros(n), np.full(n, self.radius() * 1.01 + 1e-6)
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            inside = self.sdf(u * mid[:, None]) < 0
            lo, hi = np.where(inside, mid, lo), np.where(inside, hi, mid)
        return u * (0.5 * (lo + hi))[:, None]


def solid_of(m: mujoco.MjModel, g: int) -> Solid:
    """The :class:`Solid` of geom ``g`` of ``m``; :class:`InputError` for a type a layout cannot
    be fitted with (planes, ellipsoids, height fields: a moving obstacle is none of those)."""
    name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
    t = int(m.geom_type[g])
    kind = SUPPORTED.get(t)
    if kind is None:
        tname = mujoco.mjtGeom(t).name.removeprefix("mjGEOM_").lower()
        raise InputError(f"obstacle geom {name!r} is a {tname}: layouts are fitted with spheres, capsules, boxes, "
                         "cylinders and meshes (their convex hulls)")
    size = np.array(m.geom_size[g], dtype=np.float64)
    if kind != "mesh":
        return Solid(g, name, kind, size)
    from scipy.spatial import ConvexHull

    mesh = int(m.geom_dataid[g])
    adr, num = int(m.mesh_vertadr[mesh]), int(m.mesh_vertnum[mesh])
    verts = np.asarray(m.mesh_vert[adr:adr + num], dtype=np.float64)   # in the geom's frame
    hull = ConvexHull(verts)
    planes = np.concatenate([hull.equations[:, :3], -hull.equations[:, 3:]], axis=1)
    edges = set()
    for simplex in hull.simplices:
        for a, b in ((0, 1), (1, 2), (2, 0)):
            i, j = sorted((int(simplex[a]), int(simplex[b])))
            edges.add((i, j))
    e = np.array([[verts[i], verts[j]] for i, j in sorted(edges)])
    return Solid(g, name, kind, size, planes=planes, edges=e, vertices=verts[hull.vertices])
