"""Evaluating in chunks of poses on a CPU, so that a batch's intermediates stay in cache.

A pair field's activations are (P, B, width) and its sphere distances (B, P, m, m): at B = 10 000
they are hundreds of MB, and every elementwise step streams them through memory. In chunks of a
few hundred poses the same operations run from cache, 2-2.5x faster on two cores. The result is
the same pose by pose (each pose's arithmetic does not depend on its neighbours).
"""

from __future__ import annotations

import torch


def cpu_chunks(x: torch.Tensor, size: int) -> tuple[torch.Tensor, ...]:
    """``x`` split along its first axis into chunks of at most ``size`` rows, on a CPU; ``(x,)``
    unchanged on other devices (a GPU wants the whole batch) and while ``torch.export`` or
    ``torch.compile`` trace (a loop over a symbolic batch size would pin it)."""
    # the tracing test first: comparing a symbolic batch size with ``size`` would guard on it
    if (torch.compiler.is_exporting() or torch.compiler.is_compiling() or x.device.type != "cpu"
            or x.shape[0] <= size):
        return (x,)
    return x.split(size)
