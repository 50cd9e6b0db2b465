"""The Rust tile rasterizer (``backend="rust"``, ``rust/splat.rs``) against the torch reference:
same images and pose gradients on the Panda, ``torch.autograd.gradcheck`` for every Gaussian
parameter, bit-identical results across thread counts, and every bad input a Python exception."""

import numpy as np
import pytest
import torch

from profrobot import _core
from profrobot.errors import ProfrobotError
from profrobot.render import GaussianRobot, rasterize, ring_cameras


def _cam(W=16, H=12, f=20.0, dtype=torch.float64):
    vm = torch.eye(4, dtype=dtype)[None]
    K = torch.tensor([[[f, 0, W / 2 - 0.5], [0, f, H / 2 - 0.5], [0, 0, 1]]], dtype=dtype)
    return vm, K


def _small_scene(n=6, seed=0):
    """``n`` overlapping anisotropic Gaussians in front of one camera (float64)."""
    g = torch.Generator().manual_seed(seed)
    means = torch.cat([(torch.rand(n, 2, generator=g, dtype=torch.float64) - 0.5) * 0.4,
                       1.0 + 0.3 * torch.rand(n, 1, generator=g, dtype=torch.float64)], 1)
    L = torch.randn(n, 3, 3, generator=g, dtype=torch.float64) * 0.03 + torch.eye(3, dtype=torch.float64) * 0.06
    covs = L @ L.transpose(-1, -2)
    op = 0.3 + 0.5 * torch.rand(n, generator=g, dtype=torch.float64)
    col = torch.rand(n, 3, generator=g, dtype=torch.float64)
    return means, covs, op, col


@pytest.fixture(scope="module")
def panda_model(panda):
    return GaussianRobot.from_robot(panda, 12000, seed=0)


@pytest.fixture(scope="module")
def cams128():
    return ring_cameras(4, size=128, distance=1.5, lookat=(0.0, 0.0, 0.45))


THETA = [[0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5, 0.02, 0.02]]


@pytest.mark.parametrize("cutoff", ["soft", "hard"])
def test_rust_equals_torch_on_the_panda_float32(panda_model, cams128, cutoff):
    """Acceptance 1: RGB, depth and alpha within 1e-5 (float32), 12 000 Gaussians, 4 cameras at
    128^2; the same composited pairs and per-Gaussian largest weights."""
    th = torch.tensor(THETA, dtype=torch.float32)
    bg = torch.tensor([0.2, 0.3, 0.4])
    with torch.no_grad():
        a = panda_model.render_views(th, cams128, background=bg, cutoff=cutoff, backend="torch")
        b = panda_model.render_views(th, cams128, background=bg, cutoff=cutoff, backend="rust")
    assert b.npairs == a.npairs > 100_000
    for k in ("rgb", "depth", "alpha"):
        err = (getattr(a, k) - getattr(b, k)).abs().max().item()
        assert err <= 1e-5, (k, err)
    assert b.rgb.dtype == torch.float32 and b.rgb.shape == (4, 128, 128, 3)
    # contrib: Gaussians at exactly equal float32 depth may composite in either order (torch's
    # argsort is not stable; ours breaks ties by index), which moves weight between the two
    # without changing the image; exact agreement is checked in float64
    assert ((a.contrib - b.contrib).abs() > 1e-4).float().mean() < 1e-3


def test_rust_pose_gradients_equal_torch_float64(panda):
    """Acceptance 1: dRGB/dθ and dDepth/dθ of the Rust backend within 1e-4 relative of the torch
    backend (float64; against finite differences: tests/test_render_rasterize.py)."""
    model = GaussianRobot.from_robot(panda, 3000, seed=0).double()
    cams = ring_cameras(4, size=64, distance=1.5, lookat=(0.0, 0.0, 0.45))
    w = torch.rand(4, 64, 64, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    grads = {}
    for backend in ("torch", "rust"):
        th = torch.tensor(THETA, dtype=torch.float64, requires_grad=True)
        out = model.render_views(th, cams, background=torch.ones(3, dtype=torch.float64), backend=backend)
        g_rgb = torch.autograd.grad((out.rgb * w).sum(), th, retain_graph=True)[0][0]
        g_d = torch.autograd.grad((out.depth * w[..., 0]).sum(), th)[0][0]
        grads[backend] = (g_rgb, g_d, out)
    for i in range(2):
        a, b = grads["torch"][i], grads["rust"][i]
        assert ((a - b).abs().max() / a.abs().max()).item() < 1e-4, (a, b)
    a, b = grads["torch"][2], grads["rust"][2]
    for k in ("rgb", "depth", "alpha", "contrib"):
        assert (getattr(a, k) - getattr(b, k)).abs().max().item() < 1e-9, k


@pytest.mark.parametrize("cutoff", ["soft", "hard"])
def test_gradcheck_every_gaussian_parameter(cutoff):
    """torch.autograd.gradcheck through rasterize(backend="rust") w.r.t. means, covariances,
    opacities and colours (and so through the kernel's 2D means, conics, opacities, colours and
    depths), outputs RGB, alpha and expected depth."""
    means, covs, op, col = _small_scene()
    vm, K = _cam()

    def f(means, covs, op, col):
        out = rasterize(means, covs, op, col, vm, K, 16, 12, backend="rust", cutoff=cutoff,
                        background=torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64))
        return out.rgb, out.alpha, out.depth * out.alpha

    inputs = tuple(t.clone().requires_grad_(True) for t in (means, covs, op, col))
    # the hard cutoff is discontinuous where a pixel's alpha crosses 1/255: gradcheck's 1e-6
    # steps stay clear of it in this scene (the soft cutoff is continuous everywhere)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_native_kernel_gradients_against_gradcheck():
    """The kernel alone: gradcheck w.r.t. its five direct inputs (2D means, conics,
    opacities, colours, depths)."""
    from profrobot.render.rasterize import _Splat

    g = torch.Generator().manual_seed(3)
    C, N = 2, 5
    uv = torch.rand(C, N, 2, generator=g, dtype=torch.float64) * torch.tensor([14.0, 10.0], dtype=torch.float64) + 1
    sx = 1.5 + 2 * torch.rand(C, N, generator=g, dtype=torch.float64)
    conic = torch.stack([1 / sx**2, 0.1 / sx**2, 1 / (1.2 * sx) ** 2], -1)
    op = 0.3 + 0.5 * torch.rand(C, N, generator=g, dtype=torch.float64)
    col = torch.rand(C, N, 3, generator=g, dtype=torch.float64)
    z = 1 + torch.rand(C, N, generator=g, dtype=torch.float64)

    def f(uv, conic, op, col, z):
        rgb, acc, dsum, _, _ = _Splat.apply(uv, conic, op, col, z, 16, 12, "soft", None)
        return rgb, acc, dsum

    inputs = tuple(t.clone().requires_grad_(True) for t in (uv, conic, op, col, z))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


def test_same_bits_for_one_and_two_threads(panda_model, cams128):
    """Acceptance 5: forward outputs and every gradient identical for 1 and 2 threads."""
    from profrobot.render.rasterize import _Splat, project

    th = torch.tensor(THETA, dtype=torch.float32)
    with torch.no_grad():
        mu, A = panda_model._world(th)
        vm = torch.as_tensor(cams128.world_to_cam, dtype=torch.float32)
        Ks = torch.as_tensor(cams128.K, dtype=torch.float32)
        uv, conic, _, z = project(mu[0], panda_model.covariances(A)[0], vm, Ks, 128, 128)
    op = torch.sigmoid(panda_model.opacity_logits).detach().expand(4, -1)
    col = torch.rand(4, panda_model.n, 3, generator=torch.Generator().manual_seed(0))
    w = torch.rand(4, 128, 128, 3, generator=torch.Generator().manual_seed(1))
    res = []
    for threads in (1, 2):
        ins = [t.double().clone().requires_grad_(True) for t in (uv, conic, op, col, z)]
        rgb, acc, dsum, contrib, npairs = _Splat.apply(*ins, 128, 128, "soft", threads)
        ((rgb * w).sum() + acc.sum() - 0.5 * dsum.sum()).backward()
        res.append([rgb, acc, dsum, contrib] + [t.grad for t in ins])
    for a, b in zip(*res):
        assert torch.equal(a, b)


def test_bad_input_raises_python_errors():
    """Acceptance 5: NaN/inf, wrong shapes or dtypes, empty sets, zero-size images and singular
    conics give exceptions naming the problem, never a Rust panic."""
    means, covs, op, col = _small_scene(3)
    vm, K = _cam()
    r = lambda *a, **k: rasterize(*a, backend="rust", **k)
    with pytest.raises(ProfrobotError, match="NaN"):
        r(means, covs, torch.tensor([0.5, float("nan"), 0.5], dtype=torch.float64), col, vm, K, 16, 12)
    with pytest.raises(ProfrobotError, match="inf"):
        r(means, covs, op, col, vm, K * float("inf"), 16, 12)
    with pytest.raises(ProfrobotError, match="covs"):
        r(means, covs[:2], op, col, vm, K, 16, 12)
    with pytest.raises(ProfrobotError, match="empty"):
        r(means[:0], covs[:0], op[:0], col[:0], vm, K, 16, 12)
    with pytest.raises(ProfrobotError, match="image size"):
        r(means, covs, op, col, vm, K, 0, 12)
    with pytest.raises(TypeError, match="float32 or float64"):
        r(means.half(), covs, op, col, vm, K, 16, 12)
    with pytest.raises(TypeError, match="float32 or float64"):
        r(means, covs, op.long(), col, vm, K, 16, 12)
    # a covariance that is not positive semi-definite projects to a conic that is not positive
    # definite: the kernel names it
    bad = covs.clone()
    bad[1] = -bad[1]
    with pytest.raises(ProfrobotError, match=r"conics\[0, 1\].*not positive definite"):
        r(means, bad, op, col, vm, K, 16, 12)

    # the native entry points directly
    C, N = 1, 2
    uv = np.zeros((C, N, 2))
    conic = np.tile([1.0, 0.0, 1.0], (C, N, 1))
    op_, col_, z = np.full((C, N), 0.5), np.ones((C, N, 3)), np.ones((C, N))
    with pytest.raises(ProfrobotError, match=r"conics\[0, 1\]"):
        _core.splat_forward(uv, np.array([[[1.0, 0, 1], [1.0, 1.0, 1.0]]]), op_, col_, z, 8, 8)   # det = 0
    with pytest.raises(ProfrobotError, match="colors must have shape"):
        _core.splat_forward(uv, conic, op_, col_[..., :2], z, 8, 8)
    with pytest.raises(TypeError, match="float64"):
        _core.splat_forward(uv.astype(np.float32), conic, op_, col_, z, 8, 8)
    with pytest.raises(ProfrobotError, match="empty"):
        _core.splat_forward(uv[:, :0], conic[:, :0], op_[:, :0], col_[:, :0], z[:, :0], 8, 8)
    with pytest.raises(ProfrobotError, match="image size"):
        _core.splat_forward(uv, conic, op_, col_, z, 8, 0)
    with pytest.raises(ProfrobotError, match=r"depths\[0, 0\] is inf"):
        _core.splat_forward(uv, conic, op_, col_, np.array([[np.inf, 1.0]]), 8, 8)
    with pytest.raises(ProfrobotError, match="cutoff"):
        _core.splat_forward(uv, conic, op_, col_, z, 8, 8, cutoff="fuzzy")
    with pytest.raises(ProfrobotError, match="threads"):
        _core.splat_forward(uv, conic, op_, col_, z, 8, 8, threads=0)
    *_, state = _core.splat_forward(uv, conic, op_, col_, z, 8, 8)
    with pytest.raises(ProfrobotError, match="grad_rgb must have shape"):
        _core.splat_backward(state, np.ones((1, 8, 8)), np.ones((1, 8, 8)), np.ones((1, 8, 8)))
    with pytest.raises(ProfrobotError, match="non-finite"):
        _core.splat_backward(state, np.ones((1, 8, 8, 3)), np.full((1, 8, 8), np.nan), np.ones((1, 8, 8)))


def test_auto_backend_is_rust_on_cpu():
    means, covs, op, col = _small_scene(3)
    vm, K = _cam()
    a = rasterize(means, covs, op, col, vm, K, 16, 12)
    b = rasterize(means, covs, op, col, vm, K, 16, 12, backend="rust")
    c = rasterize(means, covs, op, col, vm, K, 16, 12, backend="torch")
    assert torch.equal(a.rgb, b.rgb)
    torch.testing.assert_close(b.rgb, c.rgb, atol=1e-12, rtol=0)
    with pytest.raises(ProfrobotError, match="backend"):
        rasterize(means, covs, op, col, vm, K, 16, 12, backend="opengl")


def test_fortran_ordered_inputs_regression():
    """The kernel reads its arrays in logical order: a Fortran-ordered or strided view gives the
    same image and gradients as the C-ordered copy (rust-numpy's as_slice accepts Fortran order
    and would hand back storage order)."""
    g = torch.Generator().manual_seed(4)
    C, N = 2, 6
    uv = (torch.rand(C, N, 2, generator=g, dtype=torch.float64) * 10 + 2).numpy()
    conic = np.tile([0.2, 0.03, 0.1], (C, N, 1))
    conic[..., 0] += torch.rand(C, N, generator=g, dtype=torch.float64).numpy() * 0.2
    op = (0.3 + 0.5 * torch.rand(C, N, generator=g, dtype=torch.float64)).numpy()
    col = torch.rand(C, N, 3, generator=g, dtype=torch.float64).numpy()
    z = (1 + torch.rand(C, N, generator=g, dtype=torch.float64)).numpy()
    ref = _core.splat_forward(uv, conic, op, col, z, 14, 12)
    fort = _core.splat_forward(np.asfortranarray(uv), np.asfortranarray(conic), np.asfortranarray(op),
                               np.asfortranarray(col), np.asfortranarray(z[:, ::-1])[:, ::-1], 14, 12)
    for a, b in zip(ref[:4], fort[:4]):
        np.testing.assert_array_equal(a, b)
    gr = np.random.default_rng(0).random((C, 12, 14, 3))
    ga, gd = np.ones((C, 12, 14)), np.ones((C, 12, 14))
    for a, b in zip(_core.splat_backward(ref[5], gr, ga, gd), _core.splat_backward(fort[5], np.asfortranarray(gr), ga, gd)):
        np.testing.assert_array_equal(a, b)
