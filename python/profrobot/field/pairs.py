"""The pair-structured field: one small network per candidate body pair, g their union.

A collision is the union of its pairs' contacts, and whether two rigid bodies touch depends on
their relative pose alone. So instead of one MLP over the whole robot (the kinematic encoder's),
``encoder="pairs"`` gives every candidate pair p (a moving body against another, or against a
static geom) its own MLP over what decides that pair:

- x_p (13,): the relative pose — b's origin in a's frame ``R_aᵀ (x_b − x_a)`` (3) and
  ``R_aᵀ R_b`` (9); for a static geom, the body's pose in the geom's frame — and the pair's proxy
  clearance (:mod:`profrobot.field.proxies`, 1), standardised;
- z_p = MLP_p(x_p), all pairs at once as batched matrix products ``(P, B, in) @ (P, in, out)``;
- g = :func:`pair_union` (z): max_p z_p where every pair is free, Σ_p max(z_p, 0) where some
  pair is in contact. Its sign is always max_p z_p's (the union of the pairs' contacts: a pose
  collides iff some pair does), so the field classifies exactly as the max would; it is
  continuous (where one pair is in contact both read z_p). Inside a collision its gradient is
  the sum of the colliding pairs' gradients, so a step guided by g frees them together. Under
  the max, the gradient is the deciding pair's alone: a pose where two pairs' logits tie and
  their gradients oppose (freeing one drives the other deeper) is a fixed point the paper's
  Adam protocol cannot leave. Measured on panda_blocks (benches/field_results.md): one field
  trained under the max, its weights read both ways, left 18 of 1000 colliding poses stuck for
  the protocol's 1000 steps under the max and 5 under the sum (4.1 % against 1.9 % still
  colliding after it; 54 steps a pose against 31); trained as the union, 6 stuck, 1.1 %, 33.

Training supervises every pair with its own exact label (``label_poses(..., pairs=True)``, geom
pairs grouped to body pairs by :meth:`PairEncoder.pair_labels`) beside the pose's label: a
pose gives P labels instead of one.

Pairs that no robot joint moves (a family's obstacle against the robot's fixed base) have no
pair here: they depend on the layout δ alone, and the labeller certifies them as ever.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from ..kinematics.fk import Kinematics
from .chunking import cpu_chunks
from .encoders import StandardisedEncoder
from .proxies import PairClearance

PER_PAIR = 13  # relative position (3), relative rotation (9), proxy clearance (1)
HEAD_CHUNK = 256  # poses per chunk of the pair MLPs on a CPU


def pair_union(z: torch.Tensor) -> torch.Tensor:
    """g (B,) from pair logits z (B, P): Σ_p max(z_p, 0) + min(max_p z_p, 0) — the largest
    logit where no pair is in contact, the sum of the positive ones where some is (module docs)."""
    return torch.relu(z).sum(1) + z.max(dim=1).values.clamp(max=0)


class PairEncoder(StandardisedEncoder):
    """θ (B, K) → per-pair relative poses and clearances, (B, P·13), standardised; no learnable
    parameters (training computes them once per pose)."""

    def __init__(self, robot, *, spheres_per_body: int = 4, clearance_clip: float = 0.3, stats_poses: int = 4096,
                 pairs=None):
        super().__init__()
        self.kin = Kinematics.from_robot(robot)
        self.clearance = PairClearance(robot, self.kin, spheres_per_body, keep=pairs)
        self.clip = float(clearance_clip)
        self.npair = self.clearance.npair
        self.out_features = PER_PAIR * self.npair
        self._geom_to_pair = self.clearance.pair_column      # labeller pair → pair column (−1: none)
        self._fit_standardisation(robot, stats_poses)

    def pair_labels(self, colliding_pairs: np.ndarray, n: int) -> np.ndarray:
        """(n, P) uint8: 1 where the pose's body pair is in contact, from ``label_poses(...,
        pairs=True).colliding_pairs`` rows (pose, geom pair)."""
        y = np.zeros((n, self.npair), dtype=np.uint8)
        if len(colliding_pairs):
            col = self._geom_to_pair[colliding_pairs[:, 1]]
            keep = col >= 0
            y[colliding_pairs[keep, 0], col[keep]] = 1
        return y

    def raw(self, theta: torch.Tensor) -> torch.Tensor:
        c = self.clearance
        bp = self.kin(theta)
        R, x = bp.rot.index_select(1, c.body_ids), bp.pos.index_select(1, c.body_ids)  # (B, nb, 3, 3), (B, nb, 3)
        frames = c.static_frames(bp)
        parts = []
        if len(c.bb_a):
            Ra = R.index_select(1, c.bb_a)
            parts.append(_relative(Ra, x.index_select(1, c.bb_a), R.index_select(1, c.bb_b), x.index_select(1, c.bb_b)))
        if len(c.bs_a):
            Ra, xa = R.index_select(1, c.bs_a), x.index_select(1, c.bs_a)
            if frames is None:   # fixed obstacles: one frame per pair, broadcast over the batch
                Rg, xg = c.st_rot.index_select(0, c.bs_g), c.st_pos.index_select(0, c.bs_g)
            else:
                Rg, xg = frames[0].index_select(1, c.bs_g), frames[1].index_select(1, c.bs_g)
            parts.append(_relative(Rg, xg, Ra, xa))
        clear = c.from_centres(c.sphere_centres(bp), frames).clamp(max=self.clip)   # (B, P)
        return torch.cat([torch.cat(parts, 1), clear[..., None]], 2).flatten(1)     # (B, P·13)


def _relative(Ra: torch.Tensor, xa: torch.Tensor, Rb: torch.Tensor, xb: torch.Tensor) -> torch.Tensor:
    """b's pose in a's frame, (B, P, 12): origin ``Raᵀ (xb − xa)`` (3) and ``Raᵀ Rb`` (9, row
    major), from rotations (B, P, 3, 3) and positions (B, P, 3); a's may lack the batch axis
    (a fixed obstacle's frame). einsum: torch runs each as one batched matrix product."""
    a = "" if Ra.ndim == 3 else "b"
    p = torch.einsum(f"{a}pji,bpj->bpi", Ra, xb - xa)
    return torch.cat([p, torch.einsum(f"{a}pji,bpjk->bpik", Ra, Rb).flatten(2)], 2)


class PairHead(nn.Module):
    """One MLP per pair over its 13 features: (B, P·13) → pair logits z (B, P); ``hidden``: the
    widths of each pair's MLP. LeakyReLU between layers, as the field's MLP."""

    def __init__(self, npair: int, hidden: tuple[int, ...] = (64, 64)):
        super().__init__()
        self.npair = npair
        widths = [PER_PAIR, *hidden, 1]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for n_in, n_out in zip(widths[:-1], widths[1:]):
            bound = 1 / math.sqrt(n_in)        # nn.Linear's initialisation, per pair
            self.weights.append(nn.Parameter(torch.empty(npair, n_in, n_out).uniform_(-bound, bound)))
            self.biases.append(nn.Parameter(torch.empty(npair, 1, n_out).uniform_(-bound, bound)))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        B = features.shape[0]
        chunks = cpu_chunks(features, HEAD_CHUNK)
        if len(chunks) > 1:   # the (P, B, width) activations of a chunk stay in cache: 2.5x faster
            return torch.cat([self(f) for f in chunks])
        h = features.reshape(B, self.npair, PER_PAIR).transpose(0, 1)               # (P, B, 13)
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = torch.baddbmm(b, h, w)                                               # (P, B, out)
            if i < last:
                h = nn.functional.leaky_relu(h)
        return h[..., 0].transpose(0, 1)                                             # (B, P)
