"""The CUDA paths: a field trained on a GPU, resolving with it, rendering CUDA tensors.

The device checks are skipped where torch sees no CUDA device (CI has none); on a GPU machine
``pytest tests/test_cuda.py`` runs them. The errors for a device that cannot run are checked
everywhere.
"""

import importlib.util

import numpy as np
import pytest
import torch

import profrobot
from profrobot.errors import BackendUnavailableError, InputError
from profrobot.field import train_sdf
from profrobot.field.metrics import field_values

cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA device")
TINY = dict(hidden=(64, 64), n_poses=20_000, iterations=150, batch_size=1024, eikonal_batch=64, progress=False, seed=1)


def test_a_device_torch_does_not_know_is_named(panda):
    with pytest.raises(InputError, match="device must name a torch device.*'gpu0'"):
        train_sdf(panda, device="gpu0", **TINY)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_cuda_without_a_cuda_device_says_so_before_any_work(panda):
    with pytest.raises(BackendUnavailableError, match="sees no CUDA device"):
        train_sdf(panda, device="cuda", **TINY)


@cuda
@pytest.mark.parametrize("encoder", ["kinematic", "pairs"])
def test_a_tiny_training_run_on_cuda_beats_90_percent_and_matches_its_cpu_copy(panda, encoder):
    """The CPU test's recipe on the GPU: the same held-out bar, the field on the GPU, and its CPU
    copy giving the same g (float32 kernels differ in summation order only)."""
    sdf = train_sdf(panda, device="cuda", **{**TINY, "encoder": encoder, **({"hidden": (16,)} if encoder == "pairs" else {})})
    assert sdf.joint_limits.device.type == "cuda" and sdf.metrics["device"].startswith("cuda")
    assert sdf.metrics["accuracy"] > 0.90, sdf.metrics
    q = profrobot.sample_poses(panda, 2000, seed=5)
    g_gpu = field_values(sdf, q)
    g_cpu = field_values(sdf.cpu(), q)
    np.testing.assert_allclose(g_gpu, g_cpu, atol=1e-4, rtol=1e-4)


@cuda
def test_resolve_with_a_cuda_field_returns_certified_poses(panda):
    sdf = train_sdf(panda, device="cuda", **TINY)
    from profrobot.exact.problems import colliding_poses

    q = colliding_poses(panda, 40, seed=2)
    res = profrobot.resolve(sdf, q, robot=panda)
    assert res.certified.mean() > 0.9
    assert not profrobot.collides(panda, res.poses[res.certified]).any()


def _random_gaussians(n: int, seed: int):
    """n random Gaussians about 1 m in front of an identity camera: means (n, 3) m, covariances
    (n, 3, 3) m², opacities (n,) below 0.9, colours (n, 3)."""
    gen = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=gen) * 0.4 - 0.2
    means[:, 2] += 1.0
    a = torch.randn(n, 3, 3, generator=gen) * 0.02
    covs = a @ a.transpose(1, 2) + 1e-5 * torch.eye(3)
    return means, covs, torch.rand(n, generator=gen) * 0.9, torch.rand(n, 3, generator=gen)


@cuda
def test_rasterize_cuda_tensors_agree_with_the_cpu_kernel():
    """backend="torch" on the GPU and the Rust kernel ("auto" without gsplat copies CUDA tensors
    to the CPU and back): the same image and the same gradients, to float32 rounding."""
    from profrobot.render.rasterizer import rasterize

    means, covs, opac, cols = _random_gaussians(200, seed=0)
    view = torch.eye(4)[None]
    K = torch.tensor([[[60.0, 0, 32], [0, 60.0, 32], [0, 0, 1]]])
    out = {}
    for name, dev, backend in (("cpu", "cpu", "rust"), ("torch", "cuda", "torch"), ("auto", "cuda", "auto")):
        m = means.detach().clone().to(dev).requires_grad_(True)   # a leaf on each device
        r = rasterize(m, covs.to(dev), opac.to(dev), cols.to(dev), view.to(dev), K.to(dev), 64, 64, backend=backend)
        assert r.rgb.device.type == dev
        (r.rgb.sum() + r.depth.sum()).backward()
        out[name] = (r.rgb.detach().cpu(), m.grad.cpu())
    # with gsplat installed "auto" takes its kernel (a hard cutoff): compared here only without it
    for name in ("torch",) if importlib.util.find_spec("gsplat") else ("torch", "auto"):
        torch.testing.assert_close(out[name][0], out["cpu"][0], atol=1e-5, rtol=1e-4)
        torch.testing.assert_close(out[name][1], out["cpu"][1], atol=1e-4, rtol=1e-3)


@cuda
@pytest.mark.skipif(importlib.util.find_spec("gsplat") is None, reason="gsplat is not installed")
def test_gsplat_draws_the_hard_cutoff_reference_pixel_for_pixel():
    """backend="gsplat" (and "auto", which takes it on CUDA) against the PyTorch reference with
    3DGS's hard cutoff, on two cameras of a 64 x 48 image. Regression: gsplat evaluates pixel j at
    j + 0.5 in its K and ours at j; without the half-pixel shift of the principal point every
    image moved by half a pixel."""
    from profrobot.render.rasterizer import rasterize

    means, covs, opac, cols = _random_gaussians(300, seed=3)
    turn = torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])          # the second camera rolled 90°
    view = torch.eye(4).repeat(2, 1, 1)
    view[1, :3, :3] = turn
    view[1, :3, 3] = torch.tensor([0.03, -0.02, 0.05])
    K = torch.tensor([[60.0, 0, 31.3], [0, 58.0, 23.8], [0, 0, 1]]).repeat(2, 1, 1)
    bg = torch.tensor([0.2, 0.4, 0.6])
    out = {}
    for name, backend, cutoff in (("torch", "torch", "hard"), ("gsplat", "gsplat", "hard"), ("auto", "auto", "soft"),
                                  ("per camera", "gsplat", "hard")):
        m = means.cuda().requires_grad_(True)
        c = covs.cuda().requires_grad_(True)
        # shared Gaussians go to gsplat in one call; per-camera ones (C, N, ...) one camera a call
        mm, cc = (m.expand(2, -1, -1), c.expand(2, -1, -1, -1)) if name == "per camera" else (m, c)
        r = rasterize(mm, cc, opac.cuda(), cols.cuda(), view.cuda(), K.cuda(), 64, 48, background=bg.cuda(),
                      cutoff=cutoff, backend=backend)
        assert r.rgb.shape == (2, 48, 64, 3) and r.depth.shape == (2, 48, 64)
        (r.rgb.sum() + 0.1 * r.depth.sum()).backward()
        out[name] = [t.detach().cpu() for t in (r.rgb, r.depth, r.alpha, m.grad, c.grad)]
    ref = out["torch"]
    assert float(ref[2].mean()) > 0.2                                   # the images are not empty
    for backend in ("gsplat", "auto", "per camera"):                    # "auto" on CUDA is gsplat
        rgb, depth, alpha, gm, gc = out[backend]
        for got, want in ((rgb, ref[0]), (alpha, ref[2])):
            err = (got - want).abs()
            # float32 exp on the GPU can flip a pair at alpha = 1/255 exactly: a few pixels may
            # differ by one such pair (< 0.004), the rest agree to rounding
            assert float(err.quantile(0.999)) < 1e-4 and float(err.max()) < 5e-3, (backend, float(err.max()))
        covered = ref[2] > 0.5
        torch.testing.assert_close(depth[covered], ref[1][covered], atol=1e-3, rtol=1e-3)
        # gsplat returns ∂/∂Σ with each off-diagonal pair summed into the upper entry, ours split
        # over both: the same derivative along every symmetric direction (the only ones a
        # covariance R S² Rᵀ moves in), so the symmetric parts are compared
        for got, want in ((gm, ref[3]), (_sym(gc), _sym(ref[4]))):
            assert float((got - want).norm() / want.norm()) < 2e-2, (backend, float((got - want).norm() / want.norm()))


def _sym(g: torch.Tensor) -> torch.Tensor:
    return 0.5 * (g + g.transpose(-1, -2))


@cuda
def test_pose_loss_on_cuda_equals_the_native_cpu_pass():
    """pose_loss on CUDA tensors runs in torch; on CPU tensors in one native pass
    (``rust/bindings/images.rs``): the same losses and gradients."""
    from profrobot.render.rasterizer import RenderOut
    from profrobot.render.targets import pose_loss

    g = torch.Generator().manual_seed(0)
    imgs = (torch.rand(3, 16, 20, 3, generator=g), torch.rand(3, 16, 20, generator=g), torch.rand(3, 16, 20, generator=g))
    tg = (torch.rand(3, 16, 20, 3, generator=g), torch.rand(3, 16, 20, generator=g), torch.rand(3, 16, 20, generator=g) > 0.5)
    res = {}
    for dev in ("cpu", "cuda"):
        rgb, alpha, depth = (t.to(dev).requires_grad_(True) for t in imgs)
        loss = pose_loss(RenderOut(rgb, depth, alpha), *(t.to(dev) for t in tg), w_depth=5.0)
        res[dev] = (loss, *torch.autograd.grad(loss.sum(), (rgb, alpha, depth)))
    assert res["cuda"][0].device.type == "cuda"
    for a, b in zip(res["cpu"], res["cuda"]):
        torch.testing.assert_close(a, b.cpu(), atol=1e-5, rtol=1e-5)


@cuda
def test_native_render_of_cuda_tensors_finishes_a_cuda_background(panda):
    """backend="rust" on a model moved to CUDA: the kernel runs on copies on the CPU, the
    background (a CUDA tensor) is finished there; images and pose gradients come back to the GPU
    equal to the CPU model's."""
    from profrobot.render import GaussianRobot, ring_cameras

    model = GaussianRobot.from_robot(panda, 1500, seed=0)
    cams = ring_cameras(2, size=32, distance=1.5, lookat=(0.0, 0.0, 0.45))
    res = {}
    for dev in ("cpu", "cuda"):
        m = model.to(dev)
        th = torch.tensor([[0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5, 0.02, 0.02]], device=dev, requires_grad=True)
        out = m.render_views(th, cams, background=torch.tensor([0.2, 0.4, 0.6], device=dev), backend="rust")
        assert out.rgb.device.type == dev
        (out.rgb.sum() + out.depth.sum()).backward()
        res[dev] = (out.rgb.detach().cpu(), out.depth.detach().cpu(), th.grad.cpu())
    for a, b in zip(res["cpu"][:2], res["cuda"][:2]):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-4)
    # the kernel's inputs differ by float32 rounding (sigmoid and exp taken on the GPU), which the
    # gradient's sum over 2 x 32^2 pixels carries to ~3e-4 relative (measured on an H200)
    g_cpu, g_cuda = res["cpu"][2], res["cuda"][2]
    torch.testing.assert_close(g_cpu, g_cuda, atol=1e-3 * float(g_cpu.abs().max()), rtol=1e-3)
