"""Coarse, differentiable clearance of every candidate body pair: the kinematics-aware features.

Collision depends on where the links are, not on the angles as such. So for each pair of bodies
(or body and static geom) that the exact labeller tests, we compute a cheap proxy of its clearance
(metres) from the torch FK:

- each moving body is covered by ``m`` spheres (k-means of its collision geoms' points; centre
  ``c``, radius ``r`` covering its cluster);
- a static geom (welded to the world) keeps an exact signed distance function ``sdf(p)``
  (plane, sphere, capsule, cylinder, box; a mesh by its bounding box in its own frame);
- so does an obstacle of a family of scenes (:mod:`profrobot.robot.family`: a body moved by scene
  joints δ only), its SDF evaluated in the frame the FK gives it at δ: a moving obstacle is a
  moving body, and the clearance features see exactly where it is;
- body–body:    ``min_ij ‖c_i − c_j‖ − r_i − r_j``;
- body–static:  ``min_i sdf(c_i) − r_i``.

Grouping by body keeps the cost at (pairs of bodies × m²) rather than (pairs of geoms × m²): a few
hundred terms per pose. The proxy under-estimates the true clearance; the network on top learns
the rest. Everything is a function of θ, so the Eikonal gradient ∂g/∂θ flows through it.
"""

from __future__ import annotations

import numpy as np
import torch

from ..kinematics.fk import Kinematics, quat_to_matrix
from ..errors import InputError
from ..robot.pointcloud import CLOUD_GEOM_ID
from .chunking import cpu_chunks

# MuJoCo geom types
PLANE, SPHERE, CAPSULE, CYLINDER, BOX, MESH = 0, 2, 3, 5, 6, 7


def _surface_points(kind: int, size: np.ndarray, hull: np.ndarray | None) -> np.ndarray:
    """A point set (P, 3) whose convex hull is the geom (geom frame), for sphere fitting."""
    if kind == MESH:
        assert hull is not None, "a mesh geom has a mesh"
        return hull
    if kind == BOX:
        return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * size
    if kind in (SPHERE, CAPSULE):  # the ball (or the two end balls) sampled on 26 directions
        d = np.array([[x, y, z] for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)])
        ball = d / np.linalg.norm(d, axis=1, keepdims=True) * size[0]
        return ball if kind == SPHERE else np.concatenate([ball + [0, 0, size[1]], ball - [0, 0, size[1]]])
    if kind == CYLINDER:
        a = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        ring = np.stack([size[0] * np.cos(a), size[0] * np.sin(a), np.zeros_like(a)], 1)
        return np.concatenate([ring + [0, 0, size[1]], ring - [0, 0, size[1]]])
    raise InputError(f"no point set for geom type {kind}")


def cover_spheres(points: np.ndarray, count: int, iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """``count`` spheres (centres (m, 3), radii (m,)) covering ``points`` (P, 3): deterministic
    k-means (seeded along the principal axis), each radius the farthest point of its cluster."""
    mean = points.mean(0)
    _, _, vt = np.linalg.svd(points - mean, full_matrices=False)
    t = (points - mean) @ vt[0]
    centres = mean + np.outer(np.quantile(t, (np.arange(count) + 0.5) / count), vt[0])
    for _ in range(iterations):
        nearest = np.argmin(np.linalg.norm(points[:, None] - centres[None], axis=2), axis=1)
        centres = np.stack([points[nearest == i].mean(0) if np.any(nearest == i) else centres[i] for i in range(count)])
    nearest = np.argmin(np.linalg.norm(points[:, None] - centres[None], axis=2), axis=1)
    radii = np.array([np.linalg.norm(points[nearest == i] - centres[i], axis=1).max() if np.any(nearest == i) else 0.0
                      for i in range(count)])
    return centres, radii


class PairClearance(torch.nn.Module):
    """Proxy clearance (metres) of each candidate body pair: θ (B, K) → (B, npair).

    Built from a :class:`profrobot.Robot`; shares its :class:`~profrobot.kinematics.Kinematics`.
    ``names`` lists the pairs ("link3|link5", "hand|block_1", …).
    """

    # buffers (register_buffer); st_body, st_lrot, st_lpos only when scene_moved
    body_ids: torch.Tensor
    sph_centre: torch.Tensor
    sph_radius: torch.Tensor
    st_rot: torch.Tensor
    st_pos: torch.Tensor
    st_size: torch.Tensor
    st_off: torch.Tensor
    st_body: torch.Tensor
    st_lrot: torch.Tensor
    st_lpos: torch.Tensor
    bb_a: torch.Tensor
    bb_b: torch.Tensor
    bs_a: torch.Tensor
    bs_g: torch.Tensor

    def __init__(self, robot, kinematics: Kinematics, spheres_per_body: int = 4, keep=None):
        super().__init__()
        arr = robot.core_arrays()
        self.kin = kinematics
        dtype = kinematics.qpos0.dtype
        weld = np.asarray(arr["body_weld"])
        gid = np.asarray(arr["geom_id"])
        gbody = np.asarray(arr["geom_body"])
        # a body moves with the robot when a robot joint (not a scene joint) is on it or an ancestor
        parent = np.asarray(arr["body_parent"])
        scene = set(int(j) for j in getattr(robot, "scene_index", ()))
        robot_moved = np.zeros(len(parent), dtype=bool)
        for j, b in enumerate(np.asarray(arr["jnt_body"])):
            if j not in scene:
                robot_moved[int(b)] = True
        for b in range(1, len(parent)):  # MuJoCo lists parents first
            robot_moved[b] |= robot_moved[int(parent[b])]
        moving = robot_moved[gbody]
        index_of = {int(g): i for i, g in enumerate(gid)}

        def hull(i):
            k = arr["geom_mesh"][i]
            return None if k < 0 else arr["mesh_vert"][arr["mesh_vert_adr"][k]:][: arr["mesh_vert_num"][k]]

        # spheres covering each moving body's collision geoms, in the body frame
        bodies = sorted({int(gbody[i]) for i in np.flatnonzero(moving)})
        slot = {b: s for s, b in enumerate(bodies)}
        m = spheres_per_body
        centres, radii = np.zeros((len(bodies), m, 3)), np.zeros((len(bodies), m))
        for b in bodies:
            pts = []
            for i in np.flatnonzero(moving & (gbody == b)):
                R = quat_to_matrix(torch.as_tensor(arr["geom_quat"][i])).numpy()
                pts.append(_surface_points(int(arr["geom_type"][i]), np.asarray(arr["geom_size"][i]), hull(i)) @ R.T
                           + arr["geom_pos"][i])
            centres[slot[b]], radii[slot[b]] = cover_spheres(np.concatenate(pts), m)
        f = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=dtype)
        self.register_buffer("body_ids", torch.as_tensor(bodies, dtype=torch.int64), persistent=False)
        self.register_buffer("sph_centre", f(centres), persistent=False)      # (nb, m, 3)
        self.register_buffer("sph_radius", f(radii), persistent=False)        # (nb, m)

        # static geoms: world pose (bodies welded to the world do not move) and SDF parameters
        xpos, xquat = robot.core.forward_kinematics(np.zeros((1, robot.njoint)))
        st_idx = np.flatnonzero(~moving)
        st_rot, st_pos, st_size, st_off, st_kind, st_lrot = [], [], [], [], [], []
        for i in st_idx:
            Rb = quat_to_matrix(torch.as_tensor(xquat[0][gbody[i]])).numpy()
            Rg = quat_to_matrix(torch.as_tensor(arr["geom_quat"][i])).numpy()
            st_rot.append(Rb @ Rg)
            st_lrot.append(Rg)
            st_pos.append(xpos[0][gbody[i]] + Rb @ arr["geom_pos"][i])
            kind, size, off = int(arr["geom_type"][i]), np.array(arr["geom_size"][i], dtype=np.float64), np.zeros(3)
            if kind == MESH:  # its box in the mesh frame
                v = hull(i)
                off, size, kind = (v.max(0) + v.min(0)) / 2, (v.max(0) - v.min(0)) / 2, BOX
            elif kind not in (PLANE, SPHERE, CAPSULE, CYLINDER, BOX):
                raise InputError(f"{robot.name}: no clearance proxy for static geom type {kind}")
            st_kind.append(kind)
            st_size.append(size)
            st_off.append(off)
        self.register_buffer("st_rot", f(np.array(st_rot).reshape(-1, 3, 3)), persistent=False)
        self.register_buffer("st_pos", f(np.array(st_pos).reshape(-1, 3)), persistent=False)
        self.register_buffer("st_size", f(np.array(st_size).reshape(-1, 3)), persistent=False)
        self.register_buffer("st_off", f(np.array(st_off).reshape(-1, 3)), persistent=False)
        self.st_kind = np.asarray(st_kind, dtype=np.int64)
        # obstacles of a family move with δ: their world frames come from the FK at each pose
        self.scene_moved = bool(len(st_idx)) and bool(np.any(weld[gbody[st_idx]] != 0))
        if self.scene_moved:
            self.register_buffer("st_body", torch.as_tensor(gbody[st_idx], dtype=torch.int64), persistent=False)
            self.register_buffer("st_lrot", f(np.array(st_lrot).reshape(-1, 3, 3)), persistent=False)
            self.register_buffer("st_lpos", f(np.asarray(arr["geom_pos"])[st_idx].reshape(-1, 3)), persistent=False)
        static_slot = {int(i): s for s, i in enumerate(st_idx)}

        # candidate geom pairs → distinct (body, body) and (body, static geom) pairs
        bb_seen: set[tuple[int, int]] = set()
        bs_seen: set[tuple[int, int]] = set()
        keys: list = []                              # each labeller pair's key, None without a proxy
        for g1, g2 in np.asarray(robot.pair_geoms):
            keys.append(None)
            if CLOUD_GEOM_ID in (int(g1), int(g2)):  # a point cloud has no proxy: the labeller certifies it
                continue
            a, b = index_of[int(g1)], index_of[int(g2)]
            if not moving[a]:
                a, b = b, a
            if not moving[a]:
                continue
            if moving[b]:
                keys[-1] = ("bb", tuple(sorted((slot[int(gbody[a])], slot[int(gbody[b])]))))
                bb_seen.add(keys[-1][1])
            else:
                keys[-1] = ("bs", (slot[int(gbody[a])], static_slot[int(b)]))
                bs_seen.add(keys[-1][1])
        bb, bs = sorted(bb_seen), sorted(bs_seen)
        #: every candidate pair's count before ``keep`` (``keep`` indexes that list: bb, then bs)
        self.all_npair = len(bb) + len(bs)
        #: the kept pairs' indices in the full list (``keep``, sorted), or None: all
        self.kept: list[int] | None = None
        if keep is not None:
            keep = self.kept = _check_keep(keep, self.all_npair)
            bb, bs = [bb[i] for i in keep if i < len(bb)], [bs[i - len(bb)] for i in keep if i >= len(bb)]
        column = {("bb", k): i for i, k in enumerate(bb)} | {("bs", k): len(bb) + i for i, k in enumerate(bs)}
        #: (len(robot.pair_geoms),) int64: each labeller pair's clearance column, −1 where it has no
        #: proxy (point clouds; pairs no robot joint moves; pairs left out by ``keep``)
        self.pair_column = np.array([column.get(k, -1) if k is not None else -1 for k in keys], dtype=np.int64)
        idx = lambda pairs, k: torch.as_tensor(np.array([p[k] for p in pairs], dtype=np.int64))
        self.register_buffer("bb_a", idx(bb, 0), persistent=False)
        self.register_buffer("bb_b", idx(bb, 1), persistent=False)
        self.register_buffer("bs_a", idx(bs, 0), persistent=False)
        self.register_buffer("bs_g", idx(bs, 1), persistent=False)
        bs_kinds = self.st_kind[[g for _, g in bs]] if bs else np.zeros(0, np.int64)
        self._bs_kinds = [int(k) for k in np.unique(bs_kinds)]
        for k in self._bs_kinds:
            self.register_buffer(f"_bs_kind_{k}", torch.as_tensor(np.flatnonzero(bs_kinds == k)), persistent=False)
        bname = robot.body_names
        gname = [t["name"] for t in robot.geom_table()]
        self.names = ([f"{bname[bodies[a]]}|{bname[bodies[b]]}" for a, b in bb]
                      + [f"{bname[bodies[a]]}|{gname[st_idx[g]]}" for a, g in bs])
        self.npair = len(self.names)

    def pair_hits(self, colliding_pairs: np.ndarray) -> np.ndarray:
        """Indices (into the full pair list, before ``keep``) of the pairs in contact in at least
        one row of ``label_poses(..., pairs=True).colliding_pairs`` (rows (pose, labeller pair)),
        sorted: a ``keep`` for the pairs that a dataset shows colliding. Needs a PairClearance
        built without ``keep``."""
        if self.npair != self.all_npair:
            raise InputError("pair_hits needs the full pair list (a PairClearance built without keep)")
        col = self.pair_column[np.asarray(colliding_pairs)[:, 1]] if len(colliding_pairs) else np.zeros(0, np.int64)
        return np.unique(col[col >= 0])

    def _kind_columns(self, g: torch.Tensor) -> list[tuple[int, torch.Tensor]]:
        """(kind, columns of g with that kind); cached for the pair list so that tracing
        (torch.export) sees constant indices."""
        if g is self.bs_g:
            return [(k, getattr(self, f"_bs_kind_{k}")) for k in self._bs_kinds]
        kinds = self.st_kind[g.cpu().numpy()]
        return [(int(k), torch.as_tensor(np.flatnonzero(kinds == k), device=g.device)) for k in np.unique(kinds)]

    def sphere_centres(self, bp) -> torch.Tensor:
        """World centres (B, nb, m, 3) of the covering spheres, from the FK's body poses ``bp``."""
        R, x = bp.rot[:, self.body_ids], bp.pos[:, self.body_ids]                 # (B, nb, 3, 3), (B, nb, 3)
        return torch.einsum("bnij,nmj->bnmi", R, self.sph_centre) + x[:, :, None]

    def static_frames(self, bp) -> tuple[torch.Tensor, torch.Tensor] | None:
        """World frames of the static geoms at each pose, rotations (B, nst, 3, 3) and positions
        (B, nst, 3), when some move with scene joints; None when all are fixed (``st_rot``,
        ``st_pos`` then hold them)."""
        if not self.scene_moved:
            return None
        Rb, xb = bp.rot[:, self.st_body], bp.pos[:, self.st_body]
        return torch.einsum("bnij,njk->bnik", Rb, self.st_lrot), xb + torch.einsum("bnij,nj->bni", Rb, self.st_lpos)

    def static_sdf(self, p: torch.Tensor, g: torch.Tensor, frames=None) -> torch.Tensor:
        """Signed distance (B, n, m) of world points p (B, n, m, 3) to static geoms g (n,), metres
        (``frames``: :meth:`static_frames`, needed when obstacles move with scene joints)."""
        if frames is None:
            if self.scene_moved:
                raise InputError("static_sdf needs the frames of the moving obstacles (static_frames)")
            local = torch.einsum("nji,bnmj->bnmi", self.st_rot[g], p - self.st_pos[g][:, None])
        else:
            R, x = frames[0][:, g], frames[1][:, g]                                # (B, n, 3, 3), (B, n, 3)
            local = torch.einsum("bnji,bnmj->bnmi", R, p - x[:, :, None])
        local = local - self.st_off[g][:, None]
        size = self.st_size[g][:, None]                                            # (n, 1, 3)
        out = torch.empty(local.shape[:-1], dtype=p.dtype, device=p.device)
        # one formula per kind, on its own columns, so no NaN gradient leaks from another kind
        for k, cols in self._kind_columns(g):
            q, s = local[:, cols], size[cols]
            if k == PLANE:
                d = q[..., 2]
            elif k == SPHERE:
                d = q.norm(dim=-1) - s[..., 0]
            elif k == CAPSULE:
                z = torch.minimum(torch.maximum(q[..., 2], -s[..., 1]), s[..., 1])
                d = torch.stack([q[..., 0], q[..., 1], q[..., 2] - z], -1).norm(dim=-1) - s[..., 0]
            else:
                e = (torch.stack([q[..., :2].norm(dim=-1) - s[..., 0], q[..., 2].abs() - s[..., 1]], -1)
                     if k == CYLINDER else q.abs() - s)
                outside = e.max(-1).values
                # the 1e-12 floor keeps the norm's gradient finite at the surface
                d = torch.where(outside > 0, e.clamp(min=1e-12).norm(dim=-1), outside)
            out[:, cols] = d
        return out

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        bp = self.kin(theta)
        return self.from_centres(self.sphere_centres(bp), self.static_frames(bp))

    def from_centres(self, c: torch.Tensor, frames=None) -> torch.Tensor:
        """Clearances (B, npair) from sphere centres (B, nb, m, 3) (``frames``: the static geoms'
        world frames, :meth:`static_frames`, when obstacles move).

        A pair's clearance is the smallest of its m² (or m) sphere terms, and the gradient of a
        minimum is its smallest term's. So the nearest spheres are found on detached tensors
        (no autograd graph over the m² terms, :func:`_argmin_sphere_pair`), and only that term
        is computed again with gradients: the same value, and the same ∂/∂θ as ``min``'s (a tie
        goes to the first index, as ``min`` does), in first, second and forward-mode AD."""
        feats = []
        m = c.shape[2]
        if len(self.bb_a):
            ca, cb = c.index_select(1, self.bb_a), c.index_select(1, self.bb_b)     # (B, P, m, 3)
            ra, rb = self.sph_radius.index_select(0, self.bb_a), self.sph_radius.index_select(0, self.bb_b)  # (P, m)
            k = _argmin_sphere_pair(ca.detach(), cb.detach(), ra, rb)                # (B, P): i·m + j
            i, j = k // m, k % m
            pa = ca.gather(2, i[..., None, None].expand(-1, -1, 1, 3))[:, :, 0]      # (B, P, 3)
            pb = cb.gather(2, j[..., None, None].expand(-1, -1, 1, 3))[:, :, 0]
            # the floor keeps sqrt's gradient finite for coincident centres
            d = ((pa - pb) ** 2).sum(-1).clamp(min=1e-10).sqrt()
            feats.append(d - _pick(ra, i) - _pick(rb, j))
        if len(self.bs_a):
            cs = c.index_select(1, self.bs_a)                                         # (B, n, m, 3)
            r = self.sph_radius.index_select(0, self.bs_a)                            # (n, m)
            with torch.no_grad():
                k = (self.static_sdf(cs.detach(), self.bs_g, _detach(frames)) - r).argmin(-1)   # (B, n)
            p = cs.gather(2, k[..., None, None].expand(-1, -1, 1, 3))                # (B, n, 1, 3)
            feats.append(self.static_sdf(p, self.bs_g, frames)[..., 0] - _pick(r, k))
        return torch.cat(feats, 1)


def _check_keep(keep, n: int) -> list[int]:
    """``keep`` as sorted distinct pair indices in [0, n), or a clear error."""
    try:
        idx = sorted({int(i) for i in keep})
    except (TypeError, ValueError) as e:
        raise InputError(f"pairs must be a list of pair indices; got {keep!r}") from e
    if not idx or idx[0] < 0 or idx[-1] >= n:
        raise InputError(f"pairs must list at least one pair index in [0, {n}); got {list(keep)!r}")
    return idx


def _pick(r: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
    """r[p, i[b, p]] (B, P) from radii r (P, m) and indices i (B, P)."""
    return r.expand(i.shape[0], -1, -1).gather(2, i[..., None])[..., 0]


def _detach(frames):
    return None if frames is None else tuple(f.detach() for f in frames)


def _argmin_sphere_pair(ca: torch.Tensor, cb: torch.Tensor, ra: torch.Tensor, rb: torch.Tensor,
                        chunk: int = 1024) -> torch.Tensor:
    """Index i·m + j (B, P) of the sphere pair with the smallest ``‖ca_i − cb_j‖ − ra_i − rb_j``,
    centres ca, cb (B, P, m, 3), radii (P, m); no gradient. In chunks of poses, so that the
    (chunk, P, m, m) distances stay in cache."""
    P, m = ca.shape[1], ca.shape[2]
    with torch.no_grad():
        rr = ra[:, :, None] + rb[:, None, :]                                        # (P, m, m)
        out = [(torch.cdist(a.reshape(-1, m, 3), b.reshape(-1, m, 3)).view(-1, P, m, m) - rr).flatten(2).argmin(-1)
               for a, b in zip(cpu_chunks(ca, chunk), cpu_chunks(cb, chunk))]
    return out[0] if len(out) == 1 else torch.cat(out)
