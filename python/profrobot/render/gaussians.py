"""The Gaussian robot: 3D Gaussians attached to the robot's bodies, moved by differentiable FK.

Each Gaussian i lives in the frame of body ``b_i`` with mean ``m_i`` (metres), rotation ``Q_i``
(unit quaternion, w x y z), scales ``s_i = exp(log_s_i)`` (metres), opacity ``sigmoid(o_i)`` and
colour spherical harmonics ``f_i`` (degree 0-2) expressed in the body frame.

Motion (``theta`` (B, K) radians / metres → world), with ``FK`` from :mod:`profrobot.kinematics`:

- rigid (default): ``mu = R_b m + x_b``,  ``Sigma = A S^2 A^T`` with ``A = R_b Q``;
- ``skinning="lbs"`` (Dr. Robot): an MLP of the canonical position gives softmax weights
  ``w_ij`` over the bodies; ``T_j = FK(theta)_j FK(theta_c)^{-1}``; ``mu = sum_j w_ij T_j mu_c``
  and the linear part ``sum_j w_ij R_j R_cj^T`` carries the covariance. The MLP's output is
  biased towards each Gaussian's own body, so it starts as the rigid model.

Initialisation samples points on the robot's visual meshes (MuJoCo's compiled ``mesh_vert`` /
``mesh_face``, by triangle area), flat discs in the surface's tangent plane, colours from the
geom's material (or geom) rgba shaded like MuJoCo's headlight: ``c(d) = rgb (a - k n.d)`` for a
viewing direction ``d`` (a, k: the model's headlight ambient and diffuse), which degree-1
spherical harmonics represent exactly.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import os
from pathlib import Path
import warnings
from collections.abc import Callable, Iterator
from typing import Any, Literal, ParamSpec, TypeVar, get_args

import mujoco
import numpy as np
import numpy.typing as npt
import torch

from ..kinematics.fk import Kinematics, quat_to_matrix
from ..files import atomic_path, check_format, check_robot, format_tag
from ..errors import CorruptFileError, MissingFileError
from .rasterizer import Backend, Cutoff, RenderOut, native_backend, rasterize, rasterize_unchecked, render_native
from ..errors import InputError
from ..robot.robot import Robot
from .cameras import Cameras

__all__ = ["GaussianRobot", "frozen", "pose_only", "sample_visual_surface"]

_M = TypeVar("_M", bound=torch.nn.Module)
_P = ParamSpec("_P")
_R = TypeVar("_R")


@contextlib.contextmanager
def frozen(module: _M) -> Iterator[_M]:
    """``module``'s parameters out of autograd for the block, their ``requires_grad`` restored
    after (also on an exception). A pose loop differentiates w.r.t. the joints only: frozen, the
    model's gradients are neither built in torch (the opacity's sigmoid, the scales' exp) nor
    accumulated into its ``.grad`` on every step, which also left the caller's model with the
    summed gradients of a whole fit.

    It sets the flags on the module itself: not for a model another thread trains or fits at the
    same time (use a copy per thread; processes, as the executors use, are unaffected)."""
    flags = [(p, p.requires_grad) for p in module.parameters()]
    try:
        for p, _ in flags:
            p.requires_grad_(False)
        yield module
    finally:
        for p, f in flags:
            p.requires_grad_(f)


def pose_only(fn: Callable[_P, _R]) -> Callable[_P, _R]:
    """Runs ``fn(model, ...)`` (the model first, or as ``model=``) with the model :func:`frozen`."""
    @functools.wraps(fn)
    def wrapper(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        model = args[0] if args else kwargs.get("model")
        if not isinstance(model, torch.nn.Module):
            return fn(*args, **kwargs)                  # fn's own error for a missing or bad model
        with frozen(model):
            return fn(*args, **kwargs)
    return wrapper

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_FORMAT_VERSION = 1
_FORMAT = format_tag("gaussian_robot", _FORMAT_VERSION)
Skinning = Literal["rigid", "lbs"]


def eval_sh(sh: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Colour from SH coefficients ``sh`` (..., n, 3), n in {1, 4, 9}, for unit directions
    ``d`` (..., 3): the 3DGS convention ``c = sum_k Y_k(d) f_k + 1/2``, clamped at 0."""
    n = sh.shape[-2]
    c = SH_C0 * sh[..., 0, :]
    if n > 1:
        x, y, z = d[..., 0:1], d[..., 1:2], d[..., 2:3]
        c = c - SH_C1 * y * sh[..., 1, :] + SH_C1 * z * sh[..., 2, :] - SH_C1 * x * sh[..., 3, :]
        if n > 4:
            xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
            c = (c + SH_C2[0] * xy * sh[..., 4, :] + SH_C2[1] * yz * sh[..., 5, :]
                 + SH_C2[2] * (2 * zz - xx - yy) * sh[..., 6, :] + SH_C2[3] * xz * sh[..., 7, :]
                 + SH_C2[4] * (xx - yy) * sh[..., 8, :])
    return torch.clamp(c + 0.5, min=0.0)


_G = mujoco.mjtGeom
_PRIMITIVES = tuple(int(k) for k in (_G.mjGEOM_SPHERE, _G.mjGEOM_CAPSULE, _G.mjGEOM_ELLIPSOID, _G.mjGEOM_CYLINDER,
                                     _G.mjGEOM_BOX))


def _visible_geoms(m: mujoco.MjModel) -> list[int]:
    """Robot geoms MuJoCo draws by default (groups 0-2, alpha > 0, not on the world body) that
    have a surface to sample: meshes and the primitives (URDF links are often boxes, cylinders and
    spheres); planes, height fields and SDFs are skipped with a warning."""
    out: list[int] = []
    skipped: list[int] = []
    for g in range(m.ngeom):
        rgba = m.mat_rgba[m.geom_matid[g]] if m.geom_matid[g] >= 0 else m.geom_rgba[g]
        if m.geom_bodyid[g] == 0 or m.geom_group[g] > 2 or rgba[3] <= 0:
            continue
        (out if int(m.geom_type[g]) == int(_G.mjGEOM_MESH) or int(m.geom_type[g]) in _PRIMITIVES else skipped).append(g)
    if skipped:
        warnings.warn(f"GaussianRobot: {len(skipped)} visible geoms (planes, height fields) get no Gaussians "
                      "from the initialiser; the appearance fit must cover them", stacklevel=3)
    return out


def _primitive_mesh(kind: int, size: np.ndarray, n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and faces (F, 3) of a primitive in its geom frame (MuJoCo's ``size``:
    sphere r; capsule r, half-length; ellipsoid radii; cylinder r, half-length; box half-sizes):
    a latitude-longitude surface of ``n`` x ``n`` quads (the box exactly, 12 triangles)."""
    if kind == int(_G.mjGEOM_BOX):
        v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * size[:3]
        f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
        return v, f
    # a surface of revolution about z: rings of (radius, z) profiles, each with n points around
    t = np.linspace(0, np.pi, n + 1)
    if kind == int(_G.mjGEOM_CYLINDER):
        r, h = size[0], size[1]
        prof = np.array([[0, -h], [r, -h], [r, h], [0, h]], float)
        scale = np.ones(3)
    elif kind == int(_G.mjGEOM_CAPSULE):
        r, h = size[0], size[1]
        lat = t[: n // 2 + 1]   # lower hemisphere, then the upper one
        prof = np.concatenate([np.stack([r * np.sin(lat), -h - r * np.cos(lat)], 1),
                               np.stack([r * np.sin(lat[::-1]), h + r * np.cos(lat[::-1])], 1)])
        scale = np.ones(3)
    else:   # sphere, ellipsoid: the unit sphere, scaled
        prof = np.stack([np.sin(t), -np.cos(t)], 1)
        scale = size[:3] if kind == int(_G.mjGEOM_ELLIPSOID) else np.full(3, size[0])
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = np.stack([prof[:, None, 0] * np.cos(phi), prof[:, None, 0] * np.sin(phi),
                  np.broadcast_to(prof[:, None, 1], (len(prof), n))], -1).reshape(-1, 3) * scale
    i, j = np.meshgrid(np.arange(len(prof) - 1), np.arange(n), indexing="ij")
    a, b = i * n + j, i * n + (j + 1) % n
    f = np.concatenate([np.stack([a, b, b + n], -1), np.stack([a, b + n, a + n], -1)]).reshape(-1, 3)
    return v, f


def sample_visual_surface(m: mujoco.MjModel, n: int,
                          seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """``n`` points on the robot's visible geoms (meshes, and primitives tessellated by
    :func:`_primitive_mesh`), by area. Returns body (n,) int, points (n, 3) and normals (n, 3)
    in the body frame, rgb (n, 3) in [0, 1], and the area per point (m^2)."""
    rng = np.random.default_rng(seed)
    tris, bodies, cols = [], [], []
    for g in _visible_geoms(m):
        if int(m.geom_type[g]) == int(_G.mjGEOM_MESH):
            mid = m.geom_dataid[g]
            v = m.mesh_vert[m.mesh_vertadr[mid]: m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(np.float64)
            f = m.mesh_face[m.mesh_faceadr[mid]: m.mesh_faceadr[mid] + m.mesh_facenum[mid]]
        else:
            v, f = _primitive_mesh(int(m.geom_type[g]), np.asarray(m.geom_size[g], np.float64))
        # compiled mesh vertices are in the geom frame; geom_pos/quat place it in the body
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, m.geom_quat[g])
        vb = v @ R.reshape(3, 3).T + m.geom_pos[g]
        tris.append(vb[f])
        bodies.append(np.full(len(f), m.geom_bodyid[g]))
        rgba = m.mat_rgba[m.geom_matid[g]] if m.geom_matid[g] >= 0 else m.geom_rgba[g]
        cols.append(np.tile(rgba[:3], (len(f), 1)))
    if not tris:
        raise InputError("the robot has no visible geoms to put Gaussians on")
    T, B, Cl = np.concatenate(tris), np.concatenate(bodies), np.concatenate(cols)
    cr = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    area = 0.5 * np.linalg.norm(cr, axis=1)
    idx = rng.choice(len(T), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    bary = np.stack([1 - s, s * (1 - r2), s * r2], 1)           # uniform on each triangle
    pts = np.einsum("nk,nkj->nj", bary, T[idx])
    nrm = cr[idx] / np.maximum(2 * area[idx, None], 1e-18)
    return B[idx], pts, nrm, Cl[idx], area.sum() / n


def _quat_from_z(n: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z) rotating the z axis onto unit vectors ``n`` (N, 3)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    w = 1.0 + n[:, 2]
    q = np.concatenate([w[:, None], axis], 1)
    flip = w < 1e-6                                              # n = -z: half turn about x
    q[flip] = [0.0, 1.0, 0.0, 0.0]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


class GaussianRobot(torch.nn.Module):
    """Gaussians attached to a :class:`profrobot.Robot`'s bodies (see the module docstring).

    Build with :meth:`from_robot`; :meth:`render` draws poses from cameras; :meth:`save` /
    :meth:`load` keep a fitted model (safetensors + JSON, robot fingerprint checked).
    """

    body: torch.Tensor           # buffers (register_buffer)
    joint_limits: torch.Tensor
    continuous: torch.Tensor
    canonical: torch.Tensor

    def __init__(self, robot: Robot, body: np.ndarray, means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray,
                 opacity_logits: np.ndarray, sh: np.ndarray, *, skinning: Skinning = "rigid",
                 canonical: npt.ArrayLike | None = None, hidden: int = 64):
        super().__init__()
        if skinning not in get_args(Skinning):
            raise InputError(f"skinning must be 'rigid' or 'lbs'; got {skinning!r}")
        self.fingerprint = robot.fingerprint
        self.robot_name = robot.name
        self.njoint = robot.njoint
        # the robot's joint equalities: answers fitted through this model are put on them
        # (joints.Limits.of; a plain object, pickles with the module)
        self.couplings = getattr(robot, "couplings", None)
        # the limits in float64, as the labeller has them (the float32 buffer below rounds a limit
        # of 3.14158 up by 1e-7: a pose clipped to it would lie outside the robot's own limits)
        self.limits_f64 = np.array(robot.joint_limits, dtype=np.float64)
        self.kin = Kinematics.from_robot(robot)
        f = lambda a: torch.nn.Parameter(torch.as_tensor(np.asarray(a), dtype=torch.float32).clone())
        self.register_buffer("body", torch.as_tensor(np.asarray(body), dtype=torch.long).clone())
        self.means, self.quats, self.log_scales = f(means), f(quats), f(log_scales)
        self.opacity_logits, self.sh = f(opacity_logits), f(sh)
        self.skinning = skinning
        self.hidden = hidden
        can = np.asarray(robot.mj_model.qpos0[robot.qpos_adr] if canonical is None else canonical, dtype=np.float64)
        self.register_buffer("joint_limits", torch.as_tensor(np.asarray(robot.joint_limits), dtype=torch.float32).clone())
        # continuous hinges wrap (pose fitting); not saved: it is the robot's, checked on load
        self.register_buffer("continuous", torch.as_tensor(np.asarray(robot.continuous, dtype=bool)).clone(),
                             persistent=False)
        self.register_buffer("canonical", torch.as_tensor(can, dtype=torch.float32).reshape(1, -1))
        self.skin_mlp: torch.nn.Sequential | None = None
        if skinning == "lbs":
            # Dr. Robot: an MLP (GELU) from the canonical position to logits over the frames
            nb = self.kin.nbody
            last = torch.nn.Linear(hidden, nb)
            self.skin_mlp = torch.nn.Sequential(torch.nn.Linear(3, hidden), torch.nn.GELU(), torch.nn.Linear(hidden, hidden),
                                                torch.nn.GELU(), last)
            torch.nn.init.zeros_(last.weight)
            torch.nn.init.zeros_(last.bias)

    # ---- construction ------------------------------------------------------------------------
    @classmethod
    def from_robot(cls, robot: Robot, n: int = 8000, *, sh_degree: int = 1, skinning: Skinning = "rigid",
                   opacity: float = 0.9, thickness: float = 0.2, seed: int = 0) -> "GaussianRobot":
        """``n`` Gaussians on the robot's visual meshes. Each is a disc of standard deviation half
        the spacing of the samples (``sqrt(area / n)``) in the tangent plane, ``thickness`` times
        that along the normal. ``sh_degree`` 0, 1 or 2."""
        if sh_degree not in (0, 1, 2):
            raise InputError(f"sh_degree must be 0, 1 or 2; got {sh_degree}")
        if n < 1:
            raise InputError(f"n must be positive; got {n}")
        body, pts, nrm, rgb, area = sample_visual_surface(robot.mj_model, n, seed)
        spacing = math.sqrt(area)
        log_s = np.log(np.array([0.5 * spacing, 0.5 * spacing, thickness * 0.5 * spacing]))
        nsh = (sh_degree + 1) ** 2
        sh = np.zeros((n, nsh, 3))
        # MuJoCo's headlight (a directional light along the view): c(d) = rgb (ambient - diffuse n.d)
        hl = robot.mj_model.vis.headlight
        amb, dif = float(np.mean(hl.ambient)), float(np.mean(hl.diffuse)) if hl.active else 0.0
        sh[:, 0] = (amb * rgb - 0.5) / SH_C0
        if sh_degree >= 1:
            sh[:, 1] = dif * rgb * nrm[:, 1:2] / SH_C1
            sh[:, 2] = -dif * rgb * nrm[:, 2:3] / SH_C1
            sh[:, 3] = dif * rgb * nrm[:, 0:1] / SH_C1
        else:
            sh[:, 0] = ((amb + 0.7 * dif) * rgb - 0.5) / SH_C0
        op = np.full(n, math.log(opacity / (1 - opacity)))
        return cls(robot, body, pts, _quat_from_z(nrm), np.tile(log_s, (n, 1)), op, sh, skinning=skinning)

    @property
    def n(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return int(round(math.sqrt(self.sh.shape[1]))) - 1

    # ---- motion --------------------------------------------------------------------------------
    def _check_theta(self, theta) -> torch.Tensor:
        theta = torch.as_tensor(theta, dtype=self.means.dtype, device=self.means.device)
        if theta.ndim == 1:
            theta = theta[None]
        if theta.ndim != 2 or theta.shape[1] != self.njoint:
            raise InputError(f"theta must have shape (B, {self.njoint}) or ({self.njoint},); got {tuple(theta.shape)}")
        if not torch.isfinite(theta).all():
            raise InputError("theta contains NaN or inf")
        return theta

    def skin_weights(self) -> torch.Tensor:
        """(N, nbody) LBS weights (one-hot on the attached body for the rigid model)."""
        onehot = torch.nn.functional.one_hot(self.body, self.kin.nbody).to(self.means.dtype)
        if self.skin_mlp is None:
            return onehot
        fk0 = self.kin(self.canonical)
        mu_c = fk0.transform(self.body, self.means)[0]
        return torch.softmax(self.skin_mlp(mu_c) + 8.0 * onehot, dim=-1)

    def world(self, theta: npt.ArrayLike) -> tuple[torch.Tensor, torch.Tensor]:
        """World means (B, N, 3) metres and the linear maps A (B, N, 3, 3) from each Gaussian's
        own frame to the world (covariance ``A S^2 A^T``)."""
        return self._world(self._check_theta(theta))

    def _world(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`world` without the checks: ``theta`` a (B, K) tensor on the model's device."""
        mu, A, _ = self._world_frames(theta)
        return mu, A

    def _world_frames(self, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """World means (B, N, 3), maps A (B, N, 3, 3), and the linear part of each Gaussian's
        body motion (B, N, 3, 3): the body rotation (rigid), the blended map (LBS)."""
        fk = self.kin.fast(theta)                                     # the same FK as the native path
        Q = quat_to_matrix(self.quats)                                # (N, 3, 3)
        if self.skin_mlp is None:
            # index_select, not fancy indexing: its backward is an index_add, several times
            # cheaper on a CPU than the accumulating index_put of advanced indexing
            Rb = fk.rot.index_select(1, self.body)                    # (B, N, 3, 3)
            mu = (Rb * self.means[:, None, :]).sum(-1) + fk.pos.index_select(1, self.body)
            return mu, Rb @ Q, Rb
        fk0 = self.kin(self.canonical)
        R0, x0 = fk0.rot[0], fk0.pos[0]                               # (nb, 3, 3), (nb, 3)
        mu_c = torch.einsum("nij,nj->ni", R0[self.body], self.means) + x0[self.body]
        w = self.skin_weights()                                       # (N, nb)
        Rrel = fk.rot @ R0.transpose(-1, -2)                          # (B, nb, 3, 3): T_j = FK FK_c^-1
        trel = fk.pos - torch.einsum("bjik,jk->bji", Rrel, x0)
        Rbl = torch.einsum("nj,bjik->bnik", w, Rrel)
        tbl = torch.einsum("nj,bjk->bnk", w, trel)
        mu = torch.einsum("bnij,nj->bni", Rbl, mu_c) + tbl
        Ab = Rbl @ R0[self.body]
        return mu, Ab @ Q, Ab

    def covariances(self, A: torch.Tensor) -> torch.Tensor:
        """(B, N, 3, 3) world covariances ``A diag(s^2) A^T`` (m^2)."""
        s2 = torch.exp(2 * self.log_scales)
        return (A * s2[:, None, :]) @ A.transpose(-1, -2)

    # ---- rendering -----------------------------------------------------------------------------
    def render(self, theta: npt.ArrayLike, viewmats: npt.ArrayLike, Ks: npt.ArrayLike, width: int, height: int, *,
               background: npt.ArrayLike | None = None, cutoff: Cutoff = "soft", backend: Backend = "auto",
               threads: int | None = None) -> RenderOut:
        """Draw B poses ``theta`` (B, K) from C cameras (``viewmats`` (C, 4, 4), ``Ks`` (C, 3, 3)
        OpenCV, see :mod:`profrobot.render.cameras`). Outputs are (B*C, H, W, ...) pose-major.
        ``backend``, ``cutoff``, ``threads``: see :func:`profrobot.render.rasterize`."""
        viewmats = torch.as_tensor(viewmats, dtype=self.means.dtype, device=self.means.device)
        Ks = torch.as_tensor(Ks, dtype=self.means.dtype, device=self.means.device)
        return self.render_unchecked(self._check_theta(theta), viewmats, Ks, width, height, background=background,
                            cutoff=cutoff, backend=backend, threads=threads, check=True)

    def render_unchecked(self, theta: torch.Tensor, viewmats: torch.Tensor, Ks: torch.Tensor, width: int, height: int,
                         *, background: npt.ArrayLike | None = None, cutoff: Cutoff = "soft", backend: Backend = "auto",
                         threads: int | None = None, check: bool = False) -> RenderOut:
        """:meth:`render` for inner loops whose inputs were validated once, at entry (``theta``
        (B, K), ``viewmats`` (C, 4, 4), ``Ks`` (C, 3, 3) tensors on the model's device, e.g. from
        :class:`profrobot.render.ImageTargets`): no per-call finiteness checks and no host syncs,
        unless ``check``."""
        B, C = theta.shape[0], viewmats.shape[0]
        op = torch.sigmoid(self.opacity_logits)
        if native_backend(backend, self.means.device):
            # one native call for the B x C views: skinning (rigid), projection and SH colour
            # (in each Gaussian's body frame) fused with rasterization, forward and backward;
            # the kernel checks its inputs (NaN/inf, shapes) whatever ``check`` says
            views = [(b, c) for b in range(B) for c in range(C)]
            common: dict[str, Any] = dict(opacities=op, sh=self.sh, viewmats=viewmats, Ks=Ks, background=background,
                                          cutoff=cutoff, threads=threads)
            if self.skin_mlp is None:
                fk = self.kin.fast(theta)                  # FK with its backward in closed form
                return render_native(views, width, height, body_rot=fk.rot, body_pos=fk.pos, body=self.body,
                                     local_means=self.means, local_quats=self.quats,
                                     scales=torch.exp(self.log_scales), **common)
            mu, A, Ab = self._world_frames(theta)
            return render_native(views, width, height, means=mu, covs=self.covariances(A),
                                 frames=Ab if self.sh.shape[1] > 1 else None, **common)
        mu, A, Ab = self._world_frames(theta)                                          # Ab: body motion (B, N, 3, 3)
        cov = self.covariances(A)
        # view direction from each camera centre to each Gaussian, in the Gaussian's body frame
        # (normalised once, after the rotation into the body frame)
        cam_c = -torch.einsum("cji,cj->ci", viewmats[:, :3, :3], viewmats[:, :3, 3])   # (C, 3)
        d = mu[:, None] - cam_c[None, :, None]                                          # (B, C, N, 3)
        # d_loc = Ab^T d, component by component (cheaper on a CPU than a batched einsum)
        dx, dy, dz = d.unbind(-1)                                                       # (B, C, N)
        Ab = Ab[:, None]
        d_loc = torch.stack([Ab[..., 0, i] * dx + Ab[..., 1, i] * dy + Ab[..., 2, i] * dz for i in range(3)], -1)
        d_loc = d_loc / d_loc.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        col = eval_sh(self.sh[None, None], d_loc)                                      # (B, C, N, 3)
        # one pose: every camera shares the means and covariances (broadcast, not copied)
        rep = (lambda t: t[0]) if B == 1 else (lambda t: t[:, None].expand(B, C, *t.shape[1:]).reshape(B * C, *t.shape[1:]))
        draw = rasterize if check else rasterize_unchecked
        return draw(rep(mu), rep(cov), op, col.reshape(B * C, -1, 3), viewmats.repeat(B, 1, 1),
                    Ks.repeat(B, 1, 1), width, height, background=background, cutoff=cutoff, backend=backend,
                    threads=threads)

    def render_views(self, theta: npt.ArrayLike, cameras: Cameras, **kw) -> RenderOut:
        """:meth:`render` with a :class:`profrobot.render.Cameras`."""
        return self.render(theta, cameras.world_to_cam, cameras.K, cameras.width, cameras.height, **kw)

    # ---- topology edits (used by the appearance fit) ----------------------------------------------
    def keep(self, mask: torch.Tensor) -> None:
        """Keep only Gaussians where ``mask`` (N,) is true (parameters replaced in place)."""
        for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
            setattr(self, name, torch.nn.Parameter(getattr(self, name).detach()[mask].clone()))
        self.body = self.body[mask]

    def append(self, body: torch.Tensor, means: torch.Tensor, quats: torch.Tensor, log_scales: torch.Tensor,
               opacity_logits: torch.Tensor, sh: torch.Tensor) -> None:
        """Add Gaussians (tensors shaped like the parameters)."""
        for name, v in (("means", means), ("quats", quats), ("log_scales", log_scales),
                        ("opacity_logits", opacity_logits), ("sh", sh)):
            setattr(self, name, torch.nn.Parameter(torch.cat([getattr(self, name).detach(), v.detach()])))
        self.body = torch.cat([self.body, body])

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # state dicts of earlier releases name the joint-limits buffer "limits"
        old = prefix + "limits"
        if old in state_dict and prefix + "joint_limits" not in state_dict:
            state_dict[prefix + "joint_limits"] = state_dict.pop(old)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    # ---- persistence ---------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """safetensors file with a JSON header (format, robot fingerprint, configuration); written
        to a temporary file and renamed (atomic)."""
        from safetensors.torch import save_file

        path = os.fspath(path)
        tensors = {k: v.detach().cpu().contiguous() for k, v in self.state_dict().items()}
        meta = dict(format=_FORMAT, robot_fingerprint=self.fingerprint, robot_name=self.robot_name,
                    skinning=self.skinning, hidden=self.hidden, n=self.n, sh_degree=self.sh_degree)
        with atomic_path(path) as tmp:
            save_file(tensors, str(tmp), metadata={"profrobot": json.dumps(meta)})
        return Path(path)

    @classmethod
    def load(cls, path: str | os.PathLike, robot: Robot) -> "GaussianRobot":
        """A model saved by :meth:`save`, for ``robot`` (refused if it was fitted to another)."""
        from safetensors import safe_open

        path = os.fspath(path)
        if not os.path.isfile(path):
            raise MissingFileError(f"no Gaussian robot file at {path!r}")
        try:
            with safe_open(path, framework="pt") as f:
                meta = json.loads((f.metadata() or {})["profrobot"])
                tensors = {k: f.get_tensor(k) for k in f.keys()}
        except Exception as e:  # safetensors raises its own error types on corrupt headers
            raise CorruptFileError(f"{path}: not a readable Gaussian robot file ({type(e).__name__}: {e})") from e
        check_format(meta.get("format") if isinstance(meta, dict) else meta, "gaussian_robot", _FORMAT_VERSION,
                     str(path))
        check_robot(meta, robot, f"Gaussian robot {path}", geometry=True)
        t = lambda k: tensors[k].numpy()
        try:
            model = cls(robot, t("body"), t("means"), t("quats"), t("log_scales"), t("opacity_logits"), t("sh"),
                        skinning=meta["skinning"], canonical=t("canonical")[0], hidden=meta["hidden"])
            if "limits" in tensors and "joint_limits" not in tensors:   # files of earlier releases
                tensors["joint_limits"] = tensors.pop("limits")
            model.load_state_dict(tensors, strict=True)
        except (KeyError, RuntimeError) as e:
            raise CorruptFileError(f"{path}: inconsistent Gaussian robot file ({e})") from e
        return model
