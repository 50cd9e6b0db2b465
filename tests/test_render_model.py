"""The Gaussian robot (initialisation, rigid and LBS motion, save/load), the appearance fit and
pose from images, on a two-link toy arm at tiny image sizes."""

import os

import mujoco
import numpy as np
import pytest
import torch

import profrobot
from profrobot.render import GaussianRobot, fit_gaussians, fit_pose, make_views, ring_cameras
from profrobot.errors import CorruptFileError, RobotMismatchError

ARM = """<mujoco><compiler angle="radian"/><statistic extent="1" center="0 0 0.3"/>
  <asset><mesh name="bar" vertex="-.04 -.04 0  .04 -.04 0  .04 .04 0  -.04 .04 0  -.04 -.04 .3  .04 -.04 .3  .04 .04 .3  -.04 .04 .3"/>
         <material name="red" rgba="0.8 0.2 0.2 1"/></asset>
  <worldbody>
    <body name="l1"><joint name="j1" type="hinge" axis="0 0 1" range="-3 3"/><geom type="mesh" mesh="bar" material="red"/>
      <body name="l2" pos="0 0 0.3"><joint name="j2" type="hinge" axis="0 1 0" range="-2 2"/>
        <geom type="mesh" mesh="bar" rgba="0.2 0.6 0.9 1"/></body>
    </body>
  </worldbody></mujoco>"""


@pytest.fixture(scope="module")
def arm():
    return profrobot.Robot.from_spec(mujoco.MjSpec.from_string(ARM), name="arm")


@pytest.fixture(scope="module")
def cams():
    return ring_cameras(3, size=32, distance=1.4, elevation=-20, lookat=(0, 0, 0.3))


def test_init_on_visual_meshes(arm):
    g = GaussianRobot.from_robot(arm, 400, seed=1)
    assert g.n == 400 and set(g.body.tolist()) == {1, 2}
    # points on the bar surfaces: |x|, |y| <= 4 cm, 0 <= z <= 30 cm in the body frame
    m = g.means.detach().numpy()
    assert (np.abs(m[:, :2]) <= 0.04 + 1e-6).all() and (m[:, 2] >= -1e-6).all() and (m[:, 2] <= 0.3 + 1e-6).all()
    mu, A = g.world(torch.zeros(1, 2))
    assert mu.shape == (1, 400, 3) and A.shape == (1, 400, 3, 3)


def test_render_shapes_and_close_to_mujoco_before_fitting(arm, cams, renderer):
    g = GaussianRobot.from_robot(arm, 1500, seed=0)
    v = make_views(arm, np.array([[0.3, 0.8]]), cams, progress=False)
    with torch.no_grad():
        out = g.render_views(torch.tensor(v.poses, dtype=torch.float32), cams, background=torch.tensor(v.background, dtype=torch.float32))
    assert out.rgb.shape == (3, 32, 32, 3) and out.depth.shape == (3, 32, 32) and out.alpha.shape == (3, 32, 32)
    drawn = out.alpha.numpy() > 0.5
    # every robot pixel is drawn (unfitted discs overhang the silhouette by ~1 px, which at this
    # size is as wide as the bar: no IoU test here; benches/render.py measures fitted IoU)
    assert (drawn & v.mask[0]).sum() / v.mask[0].sum() > 0.9
    err = np.abs(out.depth.numpy() - v.depth[0])[v.mask[0] & drawn]
    assert np.median(err) < 0.02


def test_lbs_starts_as_rigid_and_trains(arm, cams):
    torch.manual_seed(0)
    rigid = GaussianRobot.from_robot(arm, 300, seed=0)
    lbs = GaussianRobot.from_robot(arm, 300, seed=0, skinning="lbs")
    theta = torch.tensor([[0.4, -0.7]])
    mu_r, _ = rigid.world(theta)
    mu_l, _ = lbs.world(theta)
    assert (mu_r - mu_l).norm(dim=-1).max() < 5e-3          # softmax weights start ~one-hot
    lbs.render_views(theta, cams).rgb.sum().backward()
    # the output layer starts at zero (weights = softmax of the body prior), so it learns first
    assert lbs.skin_mlp[-1].weight.grad is not None and lbs.skin_mlp[-1].weight.grad.abs().sum() > 0


def test_save_load_roundtrip_and_errors(arm, panda, tmp_path, cams):
    g = GaussianRobot.from_robot(arm, 200, seed=0, skinning="lbs")
    p = tmp_path / "arm.safetensors"
    g.save(p)
    assert sorted(os.listdir(tmp_path)) == ["arm.safetensors"]          # no temporary left
    h = GaussianRobot.load(p, arm)
    theta = torch.tensor([[0.2, 0.3]])
    with torch.no_grad():
        torch.testing.assert_close(h.render_views(theta, cams).rgb, g.render_views(theta, cams).rgb)
    assert h.skinning == "lbs" and h.sh_degree == g.sh_degree
    with pytest.raises(RobotMismatchError, match="made for robot"):
        GaussianRobot.load(p, panda)
    p.write_bytes(b"\x00" * 40)
    with pytest.raises(CorruptFileError, match="not a readable"):
        GaussianRobot.load(p, arm)
    with pytest.raises(FileNotFoundError):
        GaussianRobot.load(tmp_path / "missing.safetensors", arm)
    with pytest.raises(ValueError, match="theta"):
        g.world(torch.zeros(1, 3))
    with pytest.raises(ValueError, match="NaN"):
        g.world(torch.full((1, 2), float("nan")))


def test_fit_reduces_loss(arm, cams, renderer):
    v = make_views(arm, np.array([[0.0, 0.5], [1.0, -0.5]]), cams, progress=False)
    g = GaussianRobot.from_robot(arm, 200, seed=0)
    hist = fit_gaussians(g, v, iterations=12, cams_per_step=3, densify_every=5, log_every=4, progress=False, seed=0)
    losses = [h["total"] for h in hist if "total" in h]
    assert losses[-1] < losses[0]
    assert any(h.get("event") == "densify" for h in hist) and g.n >= 200 * 0.9


def test_fit_pose_recovers_joints_and_respects_limits(arm, cams):
    torch.manual_seed(0)
    g = GaussianRobot.from_robot(arm, 300, seed=0)
    target = torch.tensor([[0.5, 1.9]])                   # j2 near its upper limit (2.0)
    with torch.no_grad():
        out = g.render_views(target, cams)
    targets = dict(rgb=out.rgb[None].numpy(), depth=out.depth[None].numpy(), mask=(out.alpha > 0.5)[None].numpy())
    calls = []

    def extra(theta):
        calls.append(theta.shape)
        return 0.0 * theta.sum()

    g.opacity_logits.requires_grad_(False)            # a caller's own choice, kept
    fit = fit_pose(g, targets, cams, target.numpy() + np.array([[0.3, -0.3]]), iterations=40, lr=0.02, extra_loss=extra)
    assert np.abs(fit.poses - target.numpy()).max() < 0.02, fit.poses
    # the fit differentiates w.r.t. the joints only: the model gets no gradients, and its
    # parameters' requires_grad are as they were (regression: 40 steps of summed gradients)
    assert all(p.grad is None for p in g.parameters())
    assert [n for n, p in g.named_parameters() if not p.requires_grad] == ["opacity_logits"]
    g.opacity_logits.requires_grad_(True)
    assert (fit.poses[:, 1] <= 2.0 + 1e-6).all() and fit.history.shape == (40, 1) and len(calls) == 40
    with pytest.raises(ValueError, match="rgb"):
        fit_pose(g, dict(rgb=np.zeros((1, 2, 32, 32, 3)), depth=targets["depth"], mask=targets["mask"]), cams, target.numpy())
    assert all(p.requires_grad for p in g.parameters())   # restored after the error too
    with pytest.raises(ValueError, match="init"):
        fit_pose(g, targets, cams, np.zeros((1, 5)))


def test_densify_keeps_adam_moments(arm):
    """torch.optim.Adam across a split/clone/prune: survivors keep their moments and step count,
    new Gaussians start from zero, the optimiser holds the model's new parameters."""
    from profrobot.render.fit import _PARAMS, _densify, _optimizer, _remap_optimizer

    torch.manual_seed(0)
    g = GaussianRobot.from_robot(arm, 40, seed=0)
    opt = _optimizer(g)
    for _ in range(2):
        opt.zero_grad()
        for name in _PARAMS:
            getattr(g, name).grad = torch.randn_like(getattr(g, name))
        opt.step()
    with torch.no_grad():
        g.opacity_logits[:3] = -10.0                         # three transparent ones get pruned
    old = {name: getattr(g, name) for name in _PARAMS}
    before = {name: {k: v.clone() for k, v in opt.state[p].items()} for name, p in old.items()}
    n0 = g.n
    grad_acc = torch.arange(n0, dtype=torch.float32)          # the last ones are split / cloned
    info, rows = _densify(g, grad_acc, 0.25, 1000, 0.02, torch.Generator().manual_seed(0))
    _remap_optimizer(opt, old, g, rows)
    assert info["added"] == 10 and info["pruned"] == 3 and g.n == n0 + 10 - 3 == len(rows)
    new = rows < 0
    assert int(new.sum()) == 10 and rows[~new].tolist() == list(range(3, n0))
    held = {id(p) for group in opt.param_groups for p in group["params"]}
    for name in _PARAMS:
        p = getattr(g, name)
        assert id(p) in held and old[name] not in opt.state
        st = opt.state[p]
        assert float(st["step"]) == 2.0
        for key in ("exp_avg", "exp_avg_sq"):
            assert st[key].shape == p.shape
            torch.testing.assert_close(st[key][~new], before[name][key][rows[~new]], rtol=0, atol=0)
            assert not st[key][new].any()
    # and the optimiser keeps working on the new parameters
    opt.zero_grad()
    g.render_views(torch.tensor([[0.1, 0.2]]), ring_cameras(1, size=8, distance=1.4)).rgb.sum().backward()
    opt.step()


def test_fit_pose_wraps_continuous_hinges(cams):
    """j1 continuous: from -3.0 to a target at 3.0 the short way crosses ±pi; clamping there
    (as fit_pose did) stalls the fit at -pi, wrapping lets it through."""
    spec = mujoco.MjSpec.from_string(ARM.replace('axis="0 0 1" range="-3 3"', 'axis="0 0 1"'))
    arm_c = profrobot.Robot.from_spec(spec, name="arm_continuous")
    assert arm_c.continuous.tolist() == [True, False]
    torch.manual_seed(0)
    g = GaussianRobot.from_robot(arm_c, 300, seed=0)
    target = torch.tensor([[3.0, 1.0]])
    with torch.no_grad():
        out = g.render_views(target, cams)
    targets = dict(rgb=out.rgb[None].numpy(), depth=out.depth[None].numpy(), mask=(out.alpha > 0.5)[None].numpy())
    fit = fit_pose(g, targets, cams, np.array([[-3.0, 1.0]]), iterations=40, lr=0.02)
    d = np.remainder(fit.poses[0, 0] - 3.0 + np.pi, 2 * np.pi) - np.pi
    assert abs(d) < 0.02 and abs(fit.poses[0, 1] - 1.0) < 0.02, fit.poses
    assert -np.pi <= fit.poses[0, 0] < np.pi
    # a start past pi is wrapped, not clamped
    fit = fit_pose(g, targets, cams, np.array([[3.0 + 2 * np.pi, 1.0]]), iterations=0)
    np.testing.assert_allclose(fit.start[0], [3.0, 1.0], atol=1e-5)


def test_fit_pose_validates_at_entry(arm, cams):
    g = GaussianRobot.from_robot(arm, 50, seed=0)
    good = dict(rgb=np.zeros((1, 3, 32, 32, 3)), depth=np.zeros((1, 3, 32, 32)), mask=np.zeros((1, 3, 32, 32), bool))
    with pytest.raises(ValueError, match="init contains NaN"):
        fit_pose(g, good, cams, np.array([[np.nan, 0.0]]), iterations=1)
    with pytest.raises(ValueError, match="depth contains NaN"):
        fit_pose(g, dict(good, depth=np.full((1, 3, 32, 32), np.inf)), cams, np.zeros((1, 2)), iterations=1)
    with pytest.raises(ValueError, match="background"):
        fit_pose(g, good, cams, np.zeros((1, 2)), iterations=1, background=[np.nan, 0, 0])
    with torch.no_grad():
        g.means[0, 0] = float("nan")
    with pytest.raises(ValueError, match="model.means"):
        fit_pose(g, good, cams, np.zeros((1, 2)), iterations=1)


def test_downsampled_targets_match_a_half_resolution_render(arm):
    """downsample_targets (64^2 -> 32^2 here) lines up with rendering the same model through
    the resized cameras: the block centres are where the smaller camera's pixel centres are
    (no shift by a pixel does better), and the silhouettes mostly agree (a thin arm at 32^2
    loses edge pixels either way)."""
    from profrobot.render.pose import downsample_targets

    cams = ring_cameras(3, size=64, distance=1.4, elevation=-20, lookat=(0, 0, 0.3))
    g = GaussianRobot.from_robot(arm, 600, seed=0)
    theta = torch.tensor([[0.4, 0.8]])
    with torch.no_grad():
        full = g.render_views(theta, cams)
        half = g.render_views(theta, cams.resized(32))
    d = downsample_targets(dict(rgb=full.rgb[None].numpy(), depth=full.depth[None].numpy(),
                                mask=(full.alpha > 0.5)[None].numpy()), 2)
    assert d["rgb"].shape == (1, 3, 32, 32, 3) and d["mask"].dtype == bool
    m_half = (half.alpha > 0.5)[None].numpy()
    iou = lambda a, b: (a & b).sum() / (a | b).sum()
    shifted = [iou(d["mask"], np.roll(m_half, (dy, dx), (-2, -1))) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
    assert max(shifted) == shifted[4] > 0.7, shifted
    both = d["mask"] & m_half
    # within the 8 cm bars' thickness: a coarse pixel averages depths the fine ones see apart
    assert np.median(np.abs(d["depth"][both] - half.depth[None].numpy()[both])) < 0.03
    with pytest.raises(ValueError, match="divisible"):
        downsample_targets(dict(rgb=np.zeros((1, 3, 32, 32, 3)), depth=np.zeros((1, 3, 32, 32)),
                                mask=np.zeros((1, 3, 32, 32), bool)), 3)


def test_fit_pose_coarse_to_fine(arm, cams):
    """coarse=...: a half-resolution stage (restarts chosen there), then full resolution; both
    stages in the history; the pose is recovered as by the one-stage fit."""
    torch.manual_seed(0)
    g = GaussianRobot.from_robot(arm, 300, seed=0)
    target = torch.tensor([[0.5, 1.2]])
    with torch.no_grad():
        out = g.render_views(target, cams)
    targets = dict(rgb=out.rgb[None].numpy(), depth=out.depth[None].numpy(), mask=(out.alpha > 0.5)[None].numpy())
    fit = fit_pose(g, targets, cams, target.numpy() + np.array([[0.3, -0.3]]), iterations=20, lr=0.005,
                   coarse=dict(iterations=30, lr=0.02, restarts=2))
    assert fit.history.shape == (50, 1) and fit.all_losses.shape == (1, 3)
    assert np.abs(fit.poses - target.numpy()).max() < 0.02, fit.poses
    with pytest.raises(ValueError, match="unknown coarse"):
        fit_pose(g, targets, cams, target.numpy(), coarse=dict(steps=3))
    # image sides the factor does not divide: the coarse stage drops the last rows and columns
    odd = fit_pose(g, targets, cams, target.numpy(), iterations=2, coarse=dict(iterations=3, factor=5))
    assert odd.history.shape == (5, 1)
    with pytest.raises(ValueError, match=r"must be in \[1, 32\]"):
        fit_pose(g, targets, cams, target.numpy(), coarse=dict(iterations=3, factor=40))


def test_primitive_geoms_get_gaussians_on_their_surfaces():
    """URDF links are often boxes, cylinders and spheres: the initialiser samples them too, on the
    surface (each point's distance to the primitive's surface ~ 0), by area."""
    import mujoco

    from profrobot.render.gaussians import sample_visual_surface

    xml = """<mujoco><worldbody><body name="b" pos="0 0 0.5"><joint type="hinge"/>
      <geom type="sphere" size="0.05" pos="0.2 0 0"/>
      <geom type="capsule" size="0.03 0.1" pos="0 0.2 0" euler="90 0 0"/>
      <geom type="cylinder" size="0.04 0.06" pos="0 0 0.2"/>
      <geom type="box" size="0.05 0.02 0.03" pos="-0.2 0 0"/>
      <geom type="ellipsoid" size="0.03 0.05 0.02" pos="0 -0.2 0"/></body></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    body, pts, nrm, rgb, area = sample_visual_surface(m, 4000, seed=0)
    assert (body == 1).all() and np.isfinite(pts).all()
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    # each point's signed distance to the nearest geom (MuJoCo's own geom distance to a tiny sphere)
    xpos = d.xpos[1] + pts @ d.xmat[1].reshape(3, 3).T
    probe = mujoco.MjModel.from_xml_string(xml.replace("</worldbody>", '<body name="p" mocap="true"><geom type="sphere" '
                                                       'size="1e-4" contype="2" conaffinity="2"/></body></worldbody>'))
    pd = mujoco.MjData(probe)
    dist = []
    for p in xpos[::10]:
        pd.mocap_pos[0] = p
        mujoco.mj_kinematics(probe, pd)
        dist.append(min(mujoco.mj_geomDistance(probe, pd, g, probe.ngeom - 1, 0.1, None) for g in range(5)) + 1e-4)
    dist = np.abs(np.array(dist))
    assert np.quantile(dist, 0.95) < 2e-3, np.quantile(dist, 0.95)     # on the surface (tessellation: < 2 mm)
    n_box = (np.abs(pts[:, 0] + 0.2) < 0.06).sum()
    box_area = 8 * (0.05 * 0.02 + 0.05 * 0.03 + 0.02 * 0.03)
    assert n_box / 4000 == pytest.approx(box_area / (area * 4000), rel=0.15)   # by area
