"""``python benches/render_gpu.py`` on a machine with a CUDA GPU: ``rasterize`` forward + backward
for 12 000 random Gaussians seen by 4 cameras of 128 x 128 (issue 39's frame size), with each
backend: gsplat and the PyTorch reference on the GPU, the Rust kernel on 2 and on every CPU core.
Median and fastest of 20 timed calls after 5 warm-ups. Results: benches/render_results.md."""

from __future__ import annotations

import os
import time

import torch

from profrobot.render.rasterize import rasterize

N, CAMERAS, SIZE = 12_000, 4, 128


def scene():
    """means (N, 3) m, covs (N, 3, 3) m², opacities (N,), colours (N, 3), viewmats (C, 4, 4), Ks (C, 3, 3)."""
    gen = torch.Generator().manual_seed(0)
    means = torch.rand(N, 3, generator=gen) * 0.5 - 0.25
    means[:, 2] += 1.0
    a = torch.randn(N, 3, 3, generator=gen) * 0.006
    covs = a @ a.transpose(1, 2) + 1e-6 * torch.eye(3)
    view = torch.eye(4).repeat(CAMERAS, 1, 1)
    view[:, 0, 3] = torch.linspace(-0.05, 0.05, CAMERAS)
    K = torch.tensor([[150.0, 0, 63.5], [0, 150.0, 63.5], [0, 0, 1]]).repeat(CAMERAS, 1, 1)
    return means, covs, torch.rand(N, generator=gen) * 0.9, torch.rand(N, 3, generator=gen), view, K


def time_backend(backend: str, device: str, threads: int | None, reps: int = 25) -> tuple[float, float, float]:
    """(median ms, fastest ms, mean alpha) of forward + backward."""
    means, *rest = scene()
    rest = [t.to(device) for t in rest]
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    times = []
    for _ in range(reps):
        m = means.to(device).requires_grad_(True)
        sync()
        t = time.perf_counter()
        r = rasterize(m, *rest, SIZE, SIZE, backend=backend, threads=threads)
        (r.rgb.sum() + r.depth.sum()).backward()
        sync()
        times.append(time.perf_counter() - t)
    times = sorted(times[5:])
    return 1000 * times[len(times) // 2], 1000 * times[0], float(r.alpha.detach().mean())


def main() -> int:
    if not torch.cuda.is_available():
        raise SystemExit("benches/render_gpu.py needs a CUDA device (torch.cuda.is_available() is False)")
    for backend, device, threads in (("gsplat", "cuda", None), ("torch", "cuda", None), ("rust", "cpu", 2),
                                     ("rust", "cpu", os.cpu_count())):
        med, best, alpha = time_backend(backend, device, threads)
        print(f"{backend:7s} {device:5s} threads={threads}: median {med:.2f} ms  min {best:.2f} ms  (alpha mean {alpha:.3f})",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
