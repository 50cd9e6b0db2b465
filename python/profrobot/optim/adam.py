"""Adam with one step counter per row: B independent problems (poses, or whole paths) optimised
in one batch, each as if it had its own ``torch.optim.Adam``.

Why not ``torch.optim.Adam``: it keeps one step counter per parameter tensor, so all rows of a
(B, K) tensor share one bias correction, and a row can neither be frozen (``resolve`` stops a
pose the moment it meets its threshold: it must not move again, and its momentum would move it)
nor restarted on its own (refinement rounds reset the moments of the poses still colliding).
Splitting into B one-row tensors would give B optimisers and B kernel launches per step. Adam is
element-wise and each row's loss depends on that row alone, so one (B, K) state with a (B,)
counter, updated only on the rows being stepped, is exactly B separate Adams.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

__all__ = ["BatchedAdam"]


class BatchedAdam:
    """Adam state (m, v: ``shape``; t: ``shape[0]``) on the device and dtype of ``like``.

    ``step(x, rows, grad)`` updates ``x[rows]`` in place from ``grad`` (len(rows), ...) and
    advances only those rows' counters; ``reset(rows)`` restarts those rows."""

    def __init__(self, shape: Sequence[int], lr: float, like: torch.Tensor, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8):
        self.lr, (self.b1, self.b2), self.eps = lr, betas, eps
        self.m = like.new_zeros(shape)
        self.v = like.new_zeros(shape)
        self.t = like.new_zeros(shape[0])

    def reset(self, rows: torch.Tensor) -> None:
        self.m[rows] = 0
        self.v[rows] = 0
        self.t[rows] = 0

    @torch.no_grad()
    def step(self, x: torch.Tensor, rows: torch.Tensor, grad: torch.Tensor) -> None:
        """x[rows] −= Adam update from ``grad`` (len(rows), ...)."""
        self.t[rows] += 1
        t = self.t[rows].reshape(-1, *([1] * (grad.ndim - 1)))
        m = self.m[rows] * self.b1 + (1 - self.b1) * grad
        v = self.v[rows] * self.b2 + (1 - self.b2) * grad * grad
        self.m[rows], self.v[rows] = m, v
        mhat = m / (1 - self.b1 ** t)
        vhat = v / (1 - self.b2 ** t)
        x[rows] -= self.lr * mhat / (vhat.sqrt() + self.eps)
