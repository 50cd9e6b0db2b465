"""The native renderer (``backend="rust"``: ``rust/bindings/render.rs`` projection and SH colour,
``rust/render/splat.rs`` tile rasterizer) against the torch reference:
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
        g_rgb, g_q = torch.autograd.grad((out.rgb * w).sum(), (th, model.quats), retain_graph=True)
        g_d = torch.autograd.grad((out.depth * w[..., 0]).sum(), th)[0][0]
        grads[backend] = (g_rgb[0], g_d, out, g_q)
    # the quaternions' gradient (the kernel's, through its normalisation, in its parallel chunks of
    # 1024 Gaussians: 3 here) against torch's quat_to_matrix
    a, b = grads["torch"][3], grads["rust"][3]
    assert ((a - b).abs().max() / a.abs().max()).item() < 1e-6
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


def _sh_scene(n=5, seed=3, dtype=torch.float64):
    """``n`` Gaussians with degree-2 SH in random frames, two cameras (one rotated, off-centre
    principal point, fx != fy): every input of the native renderer."""
    g = torch.Generator().manual_seed(seed)
    means, covs, op, _ = _small_scene(n, seed)
    sh = 0.3 * torch.randn(n, 9, 3, generator=g, dtype=dtype)
    frames = torch.linalg.qr(torch.randn(1, n, 3, 3, generator=g, dtype=dtype))[0]
    vm = torch.eye(4, dtype=dtype).repeat(2, 1, 1)
    c, s_ = np.cos(0.2), np.sin(0.2)
    vm[1, :3, :3] = torch.tensor([[c, 0, s_], [0, 1, 0], [-s_, 0, c]], dtype=dtype)
    vm[1, :3, 3] = torch.tensor([0.05, -0.03, 0.1], dtype=dtype)
    K = torch.tensor([[[20.0, 0, 7.5], [0, 22.0, 5.5], [0, 0, 1]], [[18.0, 0, 8.2], [0, 19.0, 4.9], [0, 0, 1]]],
                     dtype=dtype)
    return means[None], covs[None], op, sh, frames, vm, K


@pytest.mark.parametrize("cutoff", ["soft", "hard"])
def test_gradcheck_native_renderer_every_input(cutoff):
    """Acceptance 1 (gradcheck in f64): the fused native forward and backward (projection, SH
    colour in each Gaussian's frame, rasterization) w.r.t. means, covariances, opacities, SH
    coefficients, frames, world-to-camera matrices and intrinsics, two cameras."""
    from profrobot.render.rasterizer import render_native

    ins = _sh_scene()
    views = [(0, 0), (0, 1)]

    def f(means, covs, op, sh, frames, vm, K):
        out = render_native(views, 16, 12, means=means, covs=covs, opacities=op, sh=sh, frames=frames, viewmats=vm,
                            Ks=K, cutoff=cutoff, background=torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64))
        return out.rgb, out.alpha, out.depth * out.alpha

    inputs = tuple(t.clone().requires_grad_(True) for t in ins)
    # eps 1e-7: a pixel of this scene sits 1e-6 from the soft cutoff's kink (alpha = 0)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-7, atol=1e-5, rtol=1e-4)


def test_gradcheck_native_rigid_skinning():
    """The rigid mode (Gaussians on bodies: ``μ = R_b m + x_b``, ``Σ = R_b Q S² Qᵀ R_bᵀ``, SH in
    the body frame) against gradcheck w.r.t. body rotations and positions of two poses, local
    means, rotations and scales; four views (2 poses x 2 cameras)."""
    from profrobot.render.rasterizer import render_native

    g = torch.Generator().manual_seed(7)
    means, _, op, sh, _, vm, K = _sh_scene(6, 5)
    n = means.shape[1]
    body = torch.tensor([0, 1, 0, 1, 1, 0])
    R = torch.linalg.qr(torch.randn(2, 2, 3, 3, generator=g, dtype=torch.float64))[0]
    R = R * torch.linalg.det(R).sign()[..., None, None]                       # proper rotations
    x = 0.02 * torch.randn(2, 2, 3, generator=g, dtype=torch.float64) + torch.tensor([0, 0, 0.1], dtype=torch.float64)
    local = means[0] - torch.tensor([0, 0, 0.1], dtype=torch.float64)
    local = torch.einsum("nji,nj->ni", R[0, body], local - x[0, body])       # pose 0 puts them where _sh_scene had them
    Q = torch.linalg.qr(torch.randn(n, 3, 3, generator=g, dtype=torch.float64))[0]
    scales = 0.03 + 0.03 * torch.rand(n, 3, generator=g, dtype=torch.float64)
    views = [(0, 0), (0, 1), (1, 0), (1, 1)]

    def f(R, x, local, Q, scales, sh):
        out = render_native(views, 16, 12, body_rot=R, body_pos=x, body=body, local_means=local, local_rots=Q,
                            scales=scales, opacities=op, sh=sh, viewmats=vm, Ks=K)
        return out.rgb, out.alpha, out.depth * out.alpha

    inputs = tuple(t.clone().requires_grad_(True) for t in (R, x, local, Q, scales, sh))
    assert f(*inputs)[1].sum() > 1.0                       # the Gaussians are on screen
    assert torch.autograd.gradcheck(f, inputs, eps=1e-7, atol=1e-5, rtol=1e-4)


def test_native_local_quats_are_local_rots_of_the_normalised_quaternion():
    """``local_quats`` (any nonzero norm) draws what ``local_rots = quat_to_matrix(q)`` draws, and
    its gradient is gradcheck's through the kernel's normalisation; a zero quaternion is an
    error that names it."""
    from profrobot.kinematics.fk import quat_to_matrix
    from profrobot.render.rasterizer import render_native

    g = torch.Generator().manual_seed(3)
    means, _, op, sh, _, vm, K = _sh_scene(6, 5)
    n = means.shape[1]
    body = torch.tensor([0, 1, 0, 1, 1, 0])
    R = torch.eye(3, dtype=torch.float64).repeat(1, 2, 1, 1)
    x = torch.zeros(1, 2, 3, dtype=torch.float64)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64) * 1.7     # not unit: the kernel normalises
    scales = 0.03 + 0.03 * torch.rand(n, 3, generator=g, dtype=torch.float64)
    kw = dict(body_rot=R, body_pos=x, body=body, local_means=means[0], scales=scales, opacities=op, sh=sh,
              viewmats=vm, Ks=K)
    a = render_native([(0, 0), (0, 1)], 16, 12, local_quats=q, **kw)
    b = render_native([(0, 0), (0, 1)], 16, 12, local_rots=quat_to_matrix(q), **kw)
    assert a.alpha.sum() > 1.0
    for k in ("rgb", "alpha", "depth"):
        torch.testing.assert_close(getattr(a, k), getattr(b, k), rtol=1e-12, atol=1e-12)

    def f(q, scales):
        out = render_native([(0, 0), (0, 1)], 16, 12, **{**kw, "scales": scales}, local_quats=q)
        return out.rgb, out.alpha, out.depth * out.alpha

    inputs = (q.clone().requires_grad_(True), scales.clone().requires_grad_(True))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-7, atol=1e-5, rtol=1e-4)
    bad = q.clone()
    bad[4] = 0.0
    with pytest.raises(ValueError, match=r"local_quats\[4\].*nonzero quaternion"):
        render_native([(0, 0)], 16, 12, local_quats=bad, **kw)
    with pytest.raises(ValueError, match="local_rots= or local_quats=, not both"):
        render_native([(0, 0)], 16, 12, local_quats=q, local_rots=quat_to_matrix(q), **kw)


def test_same_bits_for_one_and_two_threads(panda_model, cams128):
    """Acceptance 5: forward outputs and every gradient identical for 1 and 2 threads (float32,
    two poses x four cameras in one call)."""
    th = torch.tensor(THETA * 2, dtype=torch.float32)
    th[1, 0] += 0.3
    w = torch.rand(8, 128, 128, 3, generator=torch.Generator().manual_seed(1))
    vm = torch.as_tensor(cams128.world_to_cam, dtype=torch.float32)
    Ks = torch.as_tensor(cams128.K, dtype=torch.float32)
    res = []
    for threads in (1, 2):
        panda_model.zero_grad()
        out = panda_model.render(th, vm, Ks, 128, 128, backend="rust", threads=threads)
        ((out.rgb * w).sum() + out.alpha.sum() - 0.5 * out.depth.sum()).backward()
        res.append([out.rgb, out.alpha, out.depth, out.contrib] + [p.grad.clone() for p in panda_model.parameters()])
    for a, b in zip(*res):
        assert torch.equal(a, b)


def test_batched_views_equal_one_call_per_pose(panda_model, cams128):
    """B poses x C cameras in one native call give the images and gradients of B calls."""
    th = torch.tensor(THETA * 3, dtype=torch.float32)
    th[1, 1] -= 0.2
    th[2, 3] += 0.3
    one = [panda_model.render_views(th[b:b + 1], cams128, backend="rust") for b in range(3)]
    all_ = panda_model.render_views(th, cams128, backend="rust")
    for k in ("rgb", "alpha", "depth"):
        assert torch.equal(getattr(all_, k), torch.cat([getattr(o, k) for o in one]))
    assert all_.npairs == sum(o.npairs for o in one)


def test_bad_input_raises_python_errors():
    """Acceptance 5: NaN/inf, wrong shapes or dtypes, empty sets, zero-size images and singular
    covariances give exceptions naming the problem, never a Rust panic."""
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
    # a covariance that is not positive semi-definite projects to a 2D covariance that is not
    # positive definite: the kernel names the covariance and the camera
    bad = covs.clone()
    bad[1] = -bad[1]
    with pytest.raises(ProfrobotError, match=r"covs\[0, 1\] projects .* not positive definite in camera 0"):
        r(means, bad, op, col, vm, K, 16, 12)

    # the native entry point directly
    m, c, o, sh, fr, vmn, Kn = (t.numpy() for t in _sh_scene(2))
    views = np.array([[0, 0], [0, 1]])
    call = lambda **kw: _core.render_forward(*[kw.pop(k, d) for k, d in (("o", o), ("vm", vmn), ("K", Kn),
                                                                          ("views", views))], 16, 12,
                                             **{"means": m, "covs": c, "sh": sh, "frames": fr, **kw})
    call()
    with pytest.raises(ProfrobotError, match=r"means\[0, 1\] is inf"):
        call(means=np.where(np.arange(6).reshape(1, 2, 3) == 3, np.inf, m))
    with pytest.raises(ProfrobotError, match="sh must have shape"):
        call(sh=sh[:1])
    with pytest.raises(TypeError, match="float64"):
        call(covs=c.astype(np.float32))
    with pytest.raises(ProfrobotError, match=r"views\[1\] = \(0, 5\) is out of range"):
        call(views=np.array([[0, 0], [0, 5]]))
    with pytest.raises(ProfrobotError, match="need the Gaussians' frames"):
        call(frames=None)
    with pytest.raises(ProfrobotError, match="exactly one of colors= and sh="):
        call(colors=np.ones((2, 3)))
    with pytest.raises(ProfrobotError, match="focal lengths must be positive"):
        call(K=Kn * np.array([-1.0, 1, 1])[:, None])
    with pytest.raises(ProfrobotError, match="cutoff"):
        call(cutoff="fuzzy")
    with pytest.raises(ProfrobotError, match="threads"):
        call(threads=0)
    with pytest.raises(ProfrobotError, match=r"body\[1\] = 4 is out of range"):
        _core.render_forward(o, vmn, Kn, views, 16, 12, body_rot=np.tile(np.eye(3), (1, 2, 1, 1)),
                             body_pos=np.zeros((1, 2, 3)), body=np.array([0, 4]), local_means=m[0],
                             local_rots=np.tile(np.eye(3), (2, 1, 1)), scales=np.full((2, 3), 0.02), sh=sh)
    with pytest.raises(ProfrobotError, match="too many for one call"):
        _core.render_forward(o, vmn, Kn, views, 50_000, 50_000, means=m, covs=c, sh=sh, frames=fr)
    *_, state = call()
    with pytest.raises(ProfrobotError, match="grad_rgb must have shape"):
        _core.render_backward(state, np.ones((2, 12, 16)), np.ones((2, 12, 16)), np.ones((2, 12, 16)))
    with pytest.raises(ProfrobotError, match="non-finite"):
        _core.render_backward(state, np.ones((2, 12, 16, 3)), np.full((2, 12, 16), np.nan), np.ones((2, 12, 16)))


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
    m, c, o, sh, fr, vm, K = (t.numpy() for t in _sh_scene(6, 4))
    views = np.array([[0, 0], [0, 1]])
    ref = _core.render_forward(o, vm, K, views, 14, 12, means=m, covs=c, sh=sh, frames=fr)
    f = np.asfortranarray
    fort = _core.render_forward(f(o[::-1])[::-1], f(vm), f(K), views, 14, 12, means=f(m), covs=f(c), sh=f(sh),
                                frames=f(fr))
    for a, b in zip(ref[:4], fort[:4]):
        np.testing.assert_array_equal(a, b)
    gr = np.random.default_rng(0).random((2, 12, 14, 3))
    ga, gd = np.ones((2, 12, 14)), np.ones((2, 12, 14))
    ga_, gb_ = _core.render_backward(ref[5], gr, ga, gd), _core.render_backward(fort[5], f(gr), ga, gd)
    assert ga_.keys() == gb_.keys() == {"means", "covs", "frames", "sh", "opacities", "viewmats", "Ks"}
    for k in ga_:
        np.testing.assert_array_equal(ga_[k], gb_[k])


def test_regression_background_as_a_list_on_the_native_path(panda_model, cams128):
    """A background given as a list (or float64 array) is converted to the images' dtype and
    device, as the torch path does."""
    th = torch.tensor(THETA, dtype=torch.float32)
    with torch.no_grad():
        a = panda_model.render_views(th, cams128, background=torch.tensor([0.2, 0.3, 0.4]), backend="rust")
        b = panda_model.render_views(th, cams128, background=[0.2, 0.3, 0.4], backend="rust")
        c = panda_model.render_views(th, cams128, background=np.array([0.2, 0.3, 0.4]), backend="rust")
    assert b.rgb.dtype == c.rgb.dtype == torch.float32
    assert torch.equal(a.rgb, b.rgb) and torch.equal(a.rgb, c.rgb)


def test_backward_computes_only_the_gradients_asked_for(panda):
    """``needs``: a frozen model's render (a pose fit) skips the colour, opacity, camera and local
    gradients; the pose gradient is the same, bit for bit, as with every gradient computed."""
    from profrobot.render import frozen

    model = GaussianRobot.from_robot(panda, 2000, seed=0)
    cams = ring_cameras(2, size=24, distance=1.5, lookat=(0.0, 0.0, 0.45))
    grads = {}
    for name in ("all", "frozen"):
        th = torch.tensor(THETA, dtype=torch.float32, requires_grad=True)
        model.zero_grad(set_to_none=True)
        if name == "frozen":
            with frozen(model):
                out = model.render_views(th, cams, background=torch.ones(3), backend="rust")
                (out.rgb.sum() + out.depth.sum()).backward()
            assert all(p.grad is None for p in model.parameters())
        else:
            out = model.render_views(th, cams, background=torch.ones(3), backend="rust")
            (out.rgb.sum() + out.depth.sum()).backward()
            assert all(p.grad is not None for p in model.parameters() if p.requires_grad)
        grads[name] = th.grad
    assert torch.equal(grads["all"], grads["frozen"])
    # the native call itself: only the keys asked for, an unknown name named
    m, c, o, col = _small_scene()
    vm, K = _cam()
    views = np.array([[0, 0]], np.int64)
    state = _core.render_forward(o.numpy(), vm.numpy(), K.numpy(), views, 16, 12, means=m[None].numpy(),
                                 covs=c[None].numpy(), colors=col.numpy())[5]
    g = [np.ones((1, 12, 16, 3)), np.ones((1, 12, 16)), np.ones((1, 12, 16))]
    full = _core.render_backward(state, *g)
    some = _core.render_backward(state, *g, needs=["means", "covs"])
    assert set(some) == {"means", "covs"} and set(full) >= {"means", "covs", "colors", "opacities", "viewmats", "Ks"}
    assert all(np.array_equal(full[k], some[k]) for k in some)
    with pytest.raises(ProfrobotError, match='needs names "colour"'):
        _core.render_backward(state, *g, needs=["colour"])
