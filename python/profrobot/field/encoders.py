"""Pose encoders: θ (B, K) in radians / metres → features (B, F) for the field's MLP.

- :class:`HierarchicalEncoder` — the paper's: joint k gets ``ν_k = W_k [θ_k, ν_parent(k)] + b_k``
  (roots: ``W_k θ_k + b_k``), ν ∈ R^8, along the robot's kinematic tree (branching trees too).
  Evaluated level by level: all joints at one depth in one batched einsum.
- :class:`FlatEncoder` — the ablation: one Linear over all joints, same output size.
- :class:`KinematicEncoder` — ours (``train_sdf(preset="cpu")``): what decides collision is where the links are,
  so the features are [sin θ, cos θ] (slides: θ), each moving body's world position and rotation
  from the torch FK, and the proxy clearance of every candidate body pair
  (:mod:`profrobot.field.proxies`), standardised. No learnable parameters, so training can
  compute them once per pose.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ..kinematics.fk import Kinematics
from .proxies import PairClearance


class HierarchicalEncoder(nn.Module):
    """Tree-structured linear map over the joints (paper §3): output (B, K·feature_size)."""

    learnable = True
    parent: torch.Tensor     # buffers (register_buffer)
    is_root: torch.Tensor

    def __init__(self, parents: list[int], feature_size: int = 8):
        super().__init__()
        K, F = len(parents), feature_size
        self.K, self.F = K, F
        depth = np.zeros(K, dtype=np.int64)
        for k, p in enumerate(parents):  # MuJoCo lists parent joints first
            depth[k] = 0 if p < 0 else depth[p] + 1
        self.levels = [torch.as_tensor(np.flatnonzero(depth == d)) for d in range(int(depth.max()) + 1)]
        self.register_buffer("parent", torch.as_tensor(np.maximum(parents, 0)), persistent=False)
        self.register_buffer("is_root", torch.as_tensor(np.asarray(parents) < 0), persistent=False)
        # W_k acts on [θ_k, ν_parent]; roots see ν_parent = 0, i.e. only their first column matters.
        bound = 1 / np.sqrt(1 + F)
        self.weight = nn.Parameter(torch.empty(K, 1 + F, F).uniform_(-bound, bound))
        self.bias = nn.Parameter(torch.empty(K, F).uniform_(-bound, bound))
        self.out_features = K * F

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        B = theta.shape[0]
        nu = theta.new_zeros(B, self.K, self.F)
        for joints in self.levels:
            parent_nu = nu[:, self.parent[joints]] * (~self.is_root[joints])[:, None].to(theta.dtype)
            x = torch.cat([theta[:, joints, None], parent_nu], dim=2)             # (B, n, 1+F)
            lvl = torch.einsum("bni,nio->bno", x, self.weight[joints]) + self.bias[joints]
            nu = nu.index_copy(1, joints, lvl)                                     # out of place: autograd
        return nu.reshape(B, -1)


class FlatEncoder(nn.Module):
    """The flattened ablation: ``Linear(K → K·feature_size)``."""

    learnable = True

    def __init__(self, K: int, feature_size: int = 8):
        super().__init__()
        self.linear = nn.Linear(K, K * feature_size)
        self.out_features = K * feature_size

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        return self.linear(theta)


class StandardisedEncoder(nn.Module):
    """A parameter-free encoder whose raw features (:meth:`raw`, (B, F)) are standardised with
    the statistics of ``stats_poses`` uniform poses (fixed seed: the same robot gives the same
    encoder; saved with checkpoints all the same)."""

    learnable = False
    out_features: int        # set by the subclass before _fit_standardisation
    mean: torch.Tensor       # buffers (register_buffer)
    std: torch.Tensor

    def _fit_standardisation(self, robot, stats_poses: int) -> None:
        F = self.out_features
        self.register_buffer("mean", torch.zeros(F))
        self.register_buffer("std", torch.ones(F))
        from ..exact.labels import sample_poses

        with torch.no_grad():
            raw = self.raw(torch.as_tensor(sample_poses(robot, stats_poses, seed=0), dtype=torch.float32))
            self.mean.copy_(raw.mean(0))
            self.std.copy_(raw.std(0).clamp(min=1e-3))

    def raw(self, theta: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        return (self.raw(theta) - self.mean) / self.std


class KinematicEncoder(StandardisedEncoder):
    """Link-pose and pair-clearance features from differentiable FK (ours): (B, F), standardised.

    ``clearance_clip`` (metres): clearances above it are clipped, so far-apart pairs stop moving
    the features (they cannot decide a collision).
    """

    learnable = False
    hinge: torch.Tensor      # buffers (register_buffer)
    bodies: torch.Tensor

    def __init__(self, robot, *, spheres_per_body: int = 4, clearance_clip: float = 0.3,
                 stats_poses: int = 4096):
        super().__init__()
        self.kin = Kinematics.from_robot(robot)
        self.clearance = PairClearance(robot, self.kin, spheres_per_body)
        self.clip = float(clearance_clip)
        hinge = np.array([t == "hinge" for t in robot.joint_types])
        self.register_buffer("hinge", torch.as_tensor(hinge), persistent=False)
        self.register_buffer("bodies", self.clearance.body_ids.clone(), persistent=False)
        self.out_features = 2 * int(hinge.sum()) + int((~hinge).sum()) + 12 * len(self.bodies) + self.clearance.npair
        self._fit_standardisation(robot, stats_poses)

    def raw(self, theta: torch.Tensor) -> torch.Tensor:
        h = self.hinge
        ang = [torch.sin(theta[:, h]), torch.cos(theta[:, h]), theta[:, ~h]]
        bp = self.kin(theta)
        rot = bp.rot[:, self.bodies].flatten(1)                                     # (B, nb·9)
        pos = bp.pos[:, self.bodies].flatten(1)                                     # (B, nb·3)
        # the same FK feeds the clearance proxies (one FK call per forward)
        clear = self.clearance.from_centres(self.clearance.sphere_centres(bp),
                                            self.clearance.static_frames(bp)).clamp(max=self.clip)
        return torch.cat(ang + [pos, rot, clear], dim=1)
