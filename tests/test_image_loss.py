"""The images finished and compared natively (``rust/bindings/images.rs``): the background and expected
depth inside the renderer's autograd node, and ``pose_loss`` in one pass each way, against the
torch formulas they replace (values and gradients), ``gradcheck`` in float64, and bad input
named."""

import numpy as np
import pytest
import torch

from profrobot import _core
from profrobot.errors import InputError, InputTypeError
from profrobot.render import GaussianRobot, ring_cameras
from profrobot.render.rasterizer import RenderOut
from profrobot.render.targets import _ImageLoss, _pose_loss_torch, pose_loss


def _frame(dtype, N=3, H=9, W=11, seed=0):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(N, H, W, 3, generator=g, dtype=dtype)
    alpha = torch.rand(N, H, W, generator=g, dtype=dtype)
    alpha[0, :2] = 0.0                                      # nothing drawn there
    depth = torch.rand(N, H, W, generator=g, dtype=dtype)
    targets = (torch.rand(N, H, W, 3, generator=g), torch.rand(N, H, W, generator=g),
               torch.rand(N, H, W, generator=g) > 0.5)
    valid = torch.rand(N, H, W, generator=g) > 0.2
    return [t.requires_grad_(True) for t in (rgb, alpha, depth)], targets, valid


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
@pytest.mark.parametrize("w_depth", [0.0, 5.0])
@pytest.mark.parametrize("with_valid", [False, True])
def test_native_pose_loss_equals_torch(dtype, tol, w_depth, with_valid):
    (rgb, alpha, depth), (rgb_t, depth_t, mask_t), valid = _frame(dtype)
    valid = valid if with_valid else None
    seed = torch.tensor([1.0, -2.0, 0.5], dtype=dtype)
    out = RenderOut(rgb, depth, alpha)
    res = {}
    for name, f in (("native", pose_loss), ("torch", _pose_loss_torch)):
        loss = f(out, rgb_t.to(dtype), depth_t.to(dtype), mask_t, w_depth=w_depth, w_mask=0.5, valid=valid)
        grads = torch.autograd.grad((loss * seed).sum(), (rgb, alpha, depth), allow_unused=True, materialize_grads=True)
        res[name] = (loss, *grads)
    assert res["native"][0].grad_fn.name().startswith("_ImageLoss")
    for a, b in zip(res["native"], res["torch"]):
        assert a.dtype == b.dtype == dtype
        assert torch.allclose(a, b, rtol=tol, atol=tol), (a - b).abs().max()


def test_native_pose_loss_gradcheck():
    (rgb, alpha, depth), (rgb_t, depth_t, mask_t), valid = _frame(torch.float64, N=2, H=5, W=6, seed=3)
    # |x| and the alpha > 1/2 selection have kinks: keep every value away from them
    with torch.no_grad():
        alpha.copy_(torch.where((alpha - 0.5).abs() < 0.02, alpha + 0.05, alpha))
        depth.copy_(depth_t.double() + torch.where(depth > 0.5, 0.1, -0.1))
    f = lambda r, a, d: _ImageLoss.apply(r, a, d, rgb_t.double(), depth_t.double(), mask_t, valid, 3.0, 0.5)
    assert torch.autograd.gradcheck(f, (rgb, alpha, depth), eps=1e-6, atol=1e-8)


def test_pose_loss_falls_back_to_torch_for_a_target_that_needs_a_gradient():
    (rgb, alpha, depth), (rgb_t, depth_t, mask_t), _ = _frame(torch.float64)
    rgb_t = rgb_t.double().requires_grad_(True)
    loss = pose_loss(RenderOut(rgb, depth, alpha), rgb_t, depth_t.double(), mask_t)
    (g,) = torch.autograd.grad(loss.sum(), rgb_t)
    assert g.abs().sum() > 0


@pytest.fixture(scope="module")
def small_panda(panda):
    return GaussianRobot.from_robot(panda, 2000, seed=0).double()


def test_background_and_depth_finished_in_the_kernel_equal_torch_finishing(small_panda):
    """A background that needs a gradient is finished in torch (the old path); a constant one in
    the kernel: the same images, and the same pose gradients, per-camera backgrounds included."""
    cams = ring_cameras(3, size=24, distance=1.5, lookat=(0.0, 0.0, 0.45))
    bg = torch.tensor([[0.2, 0.4, 0.6], [1.0, 0.0, 0.5], [0.1, 0.1, 0.1]], dtype=torch.float64)
    w = torch.rand(6, 24, 24, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    res = {}
    for name, b in (("kernel", bg), ("torch", bg.clone().requires_grad_(True))):
        th = torch.tensor([[0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5, 0.02, 0.02]] * 2, dtype=torch.float64,
                          requires_grad=True)
        out = small_panda.render_views(th, cams, background=b, backend="rust")
        loss = (out.rgb * w).sum() + (out.depth * w[..., 0]).sum() + (out.alpha * w[..., 1]).sum()
        res[name] = (out.rgb, out.depth, out.alpha, torch.autograd.grad(loss, th)[0])
    assert res["kernel"][0].grad_fn is not None
    for a, b in zip(res["kernel"], res["torch"]):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-12), (a - b).abs().max()
    assert (res["kernel"][1] == 0).any() and (res["kernel"][1] > 0).any()     # depth 0 off the robot


def test_finish_images_in_place_and_its_gradient():
    rgb = np.zeros((1, 1, 2, 3), np.float32)
    alpha, dsum = np.array([[[0.0, 0.5]]], np.float32), np.array([[[0.0, 0.3]]], np.float32)
    _core.finish_images(rgb, alpha, dsum, background=np.array([1.0, 0.5, 0.25], np.float32))
    assert np.allclose(dsum, [[[0.0, 0.6]]], rtol=1e-7, atol=0) and np.array_equal(rgb[0, 0, 0], [1.0, 0.5, 0.25])
    g_alpha, g_dsum = _core.finish_images_backward(np.zeros_like(rgb), np.zeros_like(alpha), np.ones_like(alpha),
                                                   alpha, dsum)
    assert np.allclose(g_dsum, [[[0.0, 2.0]]]) and np.allclose(g_alpha, [[[0.0, -1.2]]])


def test_bad_image_arrays_are_named():
    f32 = lambda *s: np.zeros(s, np.float32)
    with pytest.raises(InputError, match="rgb must have shape"):
        _core.finish_images(f32(1, 2, 2, 4), f32(1, 2, 2), f32(1, 2, 2))
    with pytest.raises(InputError, match="C-contiguous"):
        _core.finish_images(f32(1, 2, 4, 3)[:, :, ::2], f32(1, 2, 2), f32(1, 2, 2))
    with pytest.raises(InputError, match="background"):
        _core.finish_images(f32(1, 2, 2, 3), f32(1, 2, 2), f32(1, 2, 2), background=f32(2))
    with pytest.raises(InputError, match=r"background\[1\] is NaN"):
        _core.finish_images(f32(1, 2, 2, 3), f32(1, 2, 2), f32(1, 2, 2), background=np.array([0, np.nan, 0], np.float32))
    with pytest.raises(InputTypeError, match="dsum must be a writeable float32"):
        _core.finish_images(f32(1, 2, 2, 3), f32(1, 2, 2), np.zeros((1, 2, 2)))
    mask = np.zeros((1, 2, 2), bool)
    with pytest.raises(InputError, match="depth_t must have shape"):
        _core.image_loss(f32(1, 2, 2, 3), f32(1, 2, 2), f32(1, 2, 2), f32(1, 2, 2, 3), f32(1, 2, 3), mask)
    with pytest.raises(InputTypeError, match="mask_t must be a bool"):
        _core.image_loss(f32(1, 2, 2, 3), f32(1, 2, 2), f32(1, 2, 2), f32(1, 2, 2, 3), f32(1, 2, 2), f32(1, 2, 2))
    with pytest.raises(InputError, match="seed must have shape"):
        _core.image_loss_backward(f32(2), f32(1, 2, 2, 3), f32(1, 2, 2), f32(1, 2, 2), f32(1, 2, 2, 3), f32(1, 2, 2), mask)
    with pytest.raises(InputError, match="must be finite"):
        _core.image_loss(f32(1, 2, 2, 3), f32(1, 2, 2), f32(1, 2, 2), f32(1, 2, 2, 3), f32(1, 2, 2), mask,
                         w_depth=float("nan"))


def test_a_large_rigid_batch_drawn_in_groups_equals_one_call(small_panda, monkeypatch):
    """More than GROUP_VIEWS views go to the kernel in groups (the bodies' poses sliced per
    group): the same image bits as one call, and the same gradients to float64 rounding."""
    import importlib

    R = importlib.import_module("profrobot.render.rasterizer")

    cams = ring_cameras(3, size=16, distance=1.5, lookat=(0.0, 0.0, 0.45))
    g = torch.Generator().manual_seed(4)
    base = torch.tensor([[0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5, 0.02, 0.02]], dtype=torch.float64)
    theta = base + 0.3 * torch.randn(7, 9, generator=g, dtype=torch.float64)             # 21 views
    bg = torch.rand(3, 3, generator=g, dtype=torch.float64)                                # per camera
    w = torch.rand(21, 16, 16, 3, generator=g, dtype=torch.float64)
    res = {}
    for name, group in (("grouped", R.GROUP_VIEWS), ("one call", 10**9)):
        monkeypatch.setattr(R, "GROUP_VIEWS", group)
        small_panda.zero_grad(set_to_none=True)
        th = theta.clone().requires_grad_(True)
        out = small_panda.render_views(th, cams, background=bg, backend="rust")
        ((out.rgb * w).sum() + (out.depth * w[..., 0]).sum() + (out.alpha * w[..., 1]).sum()).backward()
        res[name] = (out.rgb, out.depth, out.alpha, out.contrib, th.grad, small_panda.sh.grad, small_panda.means.grad)
        assert out.npairs > 0
    assert R.GROUP_VIEWS == 10**9 and 21 > 16
    for i, (a, b) in enumerate(zip(res["grouped"], res["one call"])):
        if i < 4:
            assert torch.equal(a, b), i
        else:
            assert torch.allclose(a, b, rtol=1e-10, atol=1e-12), (i, (a - b).abs().max())
