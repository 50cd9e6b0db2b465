"""Adam, written out (12 lines of math) instead of ``torch.optim.Adam``.

Why: constructing a ``torch.optim`` optimiser imports ``torch._dynamo``, which imports triton;
in a process where ``mujoco`` already loaded OSMesa (``MUJOCO_GL=osmesa``, llvmpipe), triton's
own LLVM crashes the interpreter (segfault) on import. Rendering data and fitting in one process
is this package's normal use, so it keeps clear of that import.
"""

from __future__ import annotations

import torch


class Adam:
    """``m <- b1 m + (1 - b1) g``; ``v <- b2 v + (1 - b2) g^2``;
    ``p <- p - lr (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)``.

    ``groups``: list of dicts with ``params`` (list of tensors) and ``lr``; ``lr`` may be changed
    between steps (schedules)."""

    def __init__(self, groups, betas=(0.9, 0.999), eps: float = 1e-15):
        self.groups = [dict(g, params=list(g["params"]), base_lr=g["lr"]) for g in groups]
        self.b1, self.b2, self.eps = betas[0], betas[1], eps
        self.t = 0
        self.state = {}

    def zero_grad(self) -> None:
        for g in self.groups:
            for p in g["params"]:
                p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        self.t += 1
        c1, c2 = 1 - self.b1 ** self.t, 1 - self.b2 ** self.t
        for g in self.groups:
            for p in g["params"]:
                if p.grad is None:
                    continue
                m, v = self.state.setdefault(id(p), (torch.zeros_like(p), torch.zeros_like(p)))
                m.mul_(self.b1).add_(p.grad, alpha=1 - self.b1)
                v.mul_(self.b2).addcmul_(p.grad, p.grad, value=1 - self.b2)
                p.sub_(g["lr"] * (m / c1) / ((v / c2).sqrt() + self.eps))

    def scale_lr(self, factor: float) -> None:
        """Set every group's rate to ``factor`` times its initial rate."""
        for g in self.groups:
            g["lr"] = g["base_lr"] * factor
