"""The pure-PyTorch rasterizer: one Gaussian against its formula, occlusion, cutoffs, input
checks, and pose gradients (RGB and depth) against finite differences on the Panda."""

import numpy as np
import pytest
import torch

from profrobot.render import GaussianRobot, rasterize, ring_cameras
from profrobot.render.rasterizer import ALPHA_MIN, LOWPASS


def _cam(W=16, H=12, f=20.0):
    vm = torch.eye(4, dtype=torch.float64)[None]
    K = torch.tensor([[[f, 0, W / 2 - 0.5], [0, f, H / 2 - 0.5], [0, 0, 1]]], dtype=torch.float64)
    return vm, K


def test_single_gaussian_matches_formula():
    vm, K = _cam()
    mean = torch.tensor([[0.02, -0.01, 1.0]], dtype=torch.float64)
    s = 0.05
    cov = torch.eye(3, dtype=torch.float64)[None] * s * s
    out = rasterize(mean, cov, torch.tensor([0.8], dtype=torch.float64), torch.tensor([[1.0, 0.5, 0.25]], dtype=torch.float64),
                    vm, K, 16, 12, cutoff="hard")
    u, v = 20 * 0.02 + 7.5, 20 * -0.01 + 5.5
    # EWA at the centre of an isotropic Gaussian: variance (f s / z)^2 in pixels (+ low-pass), the
    # depth derivative adds (f x / z^2)^2 s^2 along x, (f y / z^2)^2 s^2 along y, their product across
    a = (20 * s) ** 2 * (1 + 0.02 ** 2) + LOWPASS
    c = (20 * s) ** 2 * (1 + 0.01 ** 2) + LOWPASS
    b = (20 * s) ** 2 * (0.02 * -0.01)
    ys, xs = torch.meshgrid(torch.arange(12.0, dtype=torch.float64), torch.arange(16.0, dtype=torch.float64), indexing="ij")
    dx, dy = xs - u, ys - v
    det = a * c - b * b
    q = (c * dx * dx - 2 * b * dx * dy + a * dy * dy) / det
    alpha = torch.clamp(0.8 * torch.exp(-0.5 * q), max=0.99)
    alpha = torch.where(alpha >= ALPHA_MIN, alpha, torch.zeros_like(alpha))
    torch.testing.assert_close(out.alpha[0], alpha)
    torch.testing.assert_close(out.rgb[0, ..., 1], alpha * 0.5)
    drawn = alpha > 0
    torch.testing.assert_close(out.depth[0][drawn], torch.full_like(out.depth[0][drawn], 1.0))
    assert (out.depth[0][~drawn] == 0).all()


def test_front_gaussian_occludes_back_and_background_shows_through():
    vm, K = _cam(15, 11)     # odd sizes: the optical axis hits pixel (5, 7)
    means = torch.tensor([[0, 0, 2.0], [0, 0, 1.0]], dtype=torch.float64)       # back listed first
    cov = torch.eye(3, dtype=torch.float64).expand(2, 3, 3) * 0.06 ** 2
    cols = torch.tensor([[1.0, 0, 0], [0, 1.0, 0]], dtype=torch.float64)
    out = rasterize(means, cov, torch.tensor([0.99, 0.99], dtype=torch.float64), cols, vm, K, 15, 11,
                    background=torch.tensor([0, 0, 1.0], dtype=torch.float64))
    centre = out.rgb[0, 5, 7]
    assert centre[1] > 0.9 and centre[0] < 0.1                    # green (front) wins
    assert out.depth[0, 5, 7] == pytest.approx(1.0, abs=0.05)     # ~3 % of the back one shows
    assert out.rgb[0, 0, 0, 2] > 0.99                             # corner: background
    # colour + background weights sum to one everywhere
    torch.testing.assert_close(out.rgb[0].sum(-1), torch.ones(11, 15, dtype=torch.float64), atol=1e-9, rtol=0)


def test_soft_cutoff_is_continuous_hard_is_not():
    vm, K = _cam()
    cov = torch.eye(3, dtype=torch.float64)[None] * 0.02 ** 2
    col = torch.ones(1, 3, dtype=torch.float64)
    op = torch.tensor([0.9], dtype=torch.float64)
    xs = torch.linspace(0.0, 0.05, 200, dtype=torch.float64)
    soft, hard = [], []
    for x in xs:
        m = torch.tensor([[x, 0, 1.0]], dtype=torch.float64)
        soft.append(float(rasterize(m, cov, op, col, vm, K, 16, 12, cutoff="soft").alpha.sum()))
        hard.append(float(rasterize(m, cov, op, col, vm, K, 16, 12, cutoff="hard").alpha.sum()))
    # moving 1/200 px: the soft total changes smoothly; with the hard cutoff a pixel whose alpha
    # crosses 1/255 appears at once
    assert np.abs(np.diff(soft)).max() < 0.1 * ALPHA_MIN
    assert np.abs(np.diff(hard)).max() > 0.9 * ALPHA_MIN


def test_bad_input():
    vm, K = _cam()
    m = torch.zeros(1, 3, dtype=torch.float64)
    cov = torch.eye(3, dtype=torch.float64)[None]
    op, col = torch.ones(1, dtype=torch.float64), torch.ones(1, 3, dtype=torch.float64)
    with pytest.raises(ValueError, match="means"):
        rasterize(torch.zeros(1, 2), cov, op, col, vm, K, 16, 12)
    with pytest.raises(ValueError, match="NaN"):
        rasterize(torch.full((1, 3), float("nan")), cov, op, col, vm, K, 16, 12)
    with pytest.raises(ValueError, match="Ks"):
        rasterize(m, cov, op, col, vm, K[:, :2], 16, 12)
    with pytest.raises(ValueError, match="cutoff"):
        rasterize(m, cov, op, col, vm, K, 16, 12, cutoff="fuzzy")
    with pytest.raises(TypeError):
        rasterize(m.numpy(), cov, op, col, vm, K, 16, 12)


@pytest.mark.parametrize("backend", ["torch", "rust"])
@pytest.mark.parametrize("cutoff", ["soft"])
def test_pose_gradients_match_finite_differences(panda, cutoff, backend):
    """dRGB/dtheta and dDepth/dtheta (through random pixel weights) against central differences,
    float64, on a fixed Panda pose seen by two cameras (depth weighted by alpha: the expected
    depth of a barely covered pixel is a ratio of two tiny numbers)."""
    torch.manual_seed(0)
    model = GaussianRobot.from_robot(panda, 800, seed=0).double()
    cams = ring_cameras(2, size=32, distance=1.6)
    theta = torch.tensor([[0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5, 0.02, 0.02]], dtype=torch.float64)
    w_rgb = torch.rand(2, 32, 32, 3, dtype=torch.float64)
    w_d = torch.rand(2, 32, 32, dtype=torch.float64)

    def f(th):
        out = model.render_views(th, cams, background=torch.ones(3, dtype=torch.float64), cutoff=cutoff, backend=backend)
        return (out.rgb * w_rgb).sum(), (out.depth * out.alpha * w_d).sum()

    th = theta.clone().requires_grad_(True)
    l_rgb, l_d = f(th)
    g_rgb = torch.autograd.grad(l_rgb, th, retain_graph=True)[0][0]
    g_d = torch.autograd.grad(l_d, th)[0][0]
    # The render is piecewise smooth in theta: two overlapping Gaussians swapping depth order, or a
    # pair dropped by the transmittance stop (T < 1e-4), are small jumps that autograd does not
    # see and a wide difference does (at eps = 1e-3 this coarse model crosses many). With the soft
    # alpha cutoff there is no other jump, so at eps = 1e-6 (float64) the two agree to 1e-4.
    eps = 1e-6
    fd_rgb, fd_d = torch.zeros(9, dtype=torch.float64), torch.zeros(9, dtype=torch.float64)
    with torch.no_grad():
        for j in range(7):                           # the arm joints (fingers barely move pixels)
            e = torch.zeros_like(theta)
            e[0, j] = eps
            (a1, b1), (a0, b0) = f(theta + e), f(theta - e)
            fd_rgb[j], fd_d[j] = (a1 - a0) / (2 * eps), (b1 - b0) / (2 * eps)
    for g, fd in ((g_rgb, fd_rgb), (g_d, fd_d)):
        err = (g[:7] - fd[:7]).abs().max() / fd[:7].abs().max()
        assert err < 1e-4, (g[:7], fd[:7])
