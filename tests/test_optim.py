"""Collision-aware optimisation: the penalty, batched resolution with per-pose freezing, limits,
trajectories, and certification by the exact labeller catching what the field gets wrong."""

import numpy as np
import pytest
import torch

import profrobot
from profrobot.exact import problems
from profrobot.field import PoseSDF
from profrobot.optim import (PenaltyOptions, TangentOptions, check_path, collision_penalty, plan_trajectories,
                             plan_trajectory,
                             resolve)
from profrobot.errors import RobotMismatchError
from profrobot.kinematics.limits import LIMIT_INSET


class LinearField(torch.nn.Module):
    """A field with the PoseSDF interface and a known answer: g(θ) = w·θ + b."""

    def __init__(self, robot, w, b):
        super().__init__()
        self.robot_name, self.fingerprint, self.njoint = robot.name, robot.fingerprint, robot.njoint
        self.register_buffer("joint_limits", torch.as_tensor(robot.joint_limits, dtype=torch.float32))
        self.register_buffer("w", torch.as_tensor(w, dtype=torch.float32))
        self.b = float(b)

    def forward(self, theta):
        return theta.to(torch.float32) @ self.w + self.b


def shifted_field(robot, shift):
    """An untrained PoseSDF whose output is moved by ``shift``: −100 calls every pose free."""
    torch.manual_seed(0)
    sdf = PoseSDF(robot, hidden=(16,))
    with torch.no_grad():
        sdf.head[-1].bias += shift
    return sdf


def colliding_and_free(robot, n=40, seed=3):
    return problems.colliding_poses(robot, n, seed), problems.free_poses(robot, n, seed)


# ---- the penalty -----------------------------------------------------------------------------

def test_penalty_is_relu_of_g_minus_threshold_with_its_gradient(panda):
    torch.manual_seed(0)
    sdf = PoseSDF(panda, hidden=(16, 16)).double()
    q = torch.as_tensor(profrobot.sample_poses(panda, 16, seed=1), dtype=torch.float64)
    g = sdf(q).detach()
    l_thres = float(g.median())                       # half the poses above, half below
    theta = q.clone().requires_grad_(True)
    p = collision_penalty(sdf, theta, l_thres)
    assert torch.allclose(p, torch.relu(g - l_thres))
    (grad,) = torch.autograd.grad(p.sum(), theta)
    x = q.clone().requires_grad_(True)
    (grad_g,) = torch.autograd.grad(sdf(x).sum(), x)
    above = g > l_thres
    assert torch.allclose(grad[above], grad_g[above]) and (grad[~above] == 0).all()
    assert torch.autograd.gradcheck(lambda t: collision_penalty(sdf, t, l_thres), (q[above].clone().requires_grad_(),))


def test_penalty_keeps_leading_dimensions(panda):
    sdf = shifted_field(panda, 0.0)
    theta = torch.as_tensor(profrobot.sample_poses(panda, 12, seed=2), dtype=torch.float32).reshape(3, 4, -1)
    assert collision_penalty(sdf, theta).shape == (3, 4)


def test_penalty_bad_input(panda):
    sdf = shifted_field(panda, 0.0)
    with pytest.raises(ValueError, match="shape"):
        collision_penalty(sdf, torch.zeros(2, panda.njoint + 1))
    with pytest.raises(ValueError, match="NaN"):
        collision_penalty(sdf, torch.full((2, panda.njoint), float("nan")))
    with pytest.raises(TypeError, match="floating"):
        collision_penalty(sdf, torch.zeros(2, panda.njoint, dtype=torch.long))
    with pytest.raises(TypeError, match="Tensor"):
        collision_penalty(sdf, np.zeros((2, panda.njoint)))
    with pytest.raises(ValueError, match="l_thres"):
        collision_penalty(sdf, torch.zeros(2, panda.njoint), float("nan"))
    with pytest.raises(TypeError, match="PoseSDF"):
        collision_penalty(object(), torch.zeros(2, panda.njoint))


# ---- resolution ------------------------------------------------------------------------------

def test_each_pose_stops_at_its_threshold_and_stays_there(panda):
    """g = θ0 + b: Adam's first steps move θ0 by ≈ lr each, so a pose needs about
    (g0 − l_thres)/lr steps; once frozen it must not drift while the others go on."""
    w = np.zeros(panda.njoint); w[0] = 1.0
    field = LinearField(panda, w, 0.0)
    q = np.tile(panda.joint_limits.mean(1), (4, 1))   # mid-range: inside every limit
    q[:, 0] = [-0.2, 0.0, 0.05, 0.2]                 # g0 = θ0
    res = resolve(field, q, l_thres=-0.1, lr=0.01, refine=False, method="adam", shrink=False)
    assert res.iterations[0] == 0 and res.poses[0, 0] == pytest.approx(-0.2)   # already below
    assert list(res.iterations[1:]) == sorted(res.iterations[1:])
    for i in range(1, 4):
        need = (q[i, 0] + 0.1) / 0.01
        assert need <= res.iterations[i] <= need + 3
        # frozen on the first step past the threshold: within one step of it
        assert -0.1 - 0.0101 <= res.poses[i, 0] <= -0.1
    assert np.all(res.poses[:, 1:] == q[:, 1:])      # zero gradient: the other joints never move
    assert res.reached.all()
    np.testing.assert_allclose(res.delta, np.abs(res.poses[:, 0] - q[:, 0]), atol=1e-6)


def test_joint_limits_are_respected(panda):
    w = np.zeros(panda.njoint); w[3] = -1.0           # g falls as joint 3 rises: pushes it to its upper limit
    field = LinearField(panda, w, 100.0)
    q = profrobot.sample_poses(panda, 5, seed=0)
    res = resolve(field, q, lr=0.5, iterations=50, refine=False, method="adam", shrink=False)
    lim = panda.joint_limits
    assert (res.poses >= lim[:, 0]).all() and (res.poses <= lim[:, 1]).all()
    # a joint it moves stops LIMIT_INSET short of its limit (see the regression test below)
    np.testing.assert_allclose(res.poses[:, 3], lim[3, 1] - LIMIT_INSET, atol=1e-6)
    assert (res.iterations == 50).all() and not res.reached.any()


def test_regression_resolved_fingers_stop_short_of_touching(panda):
    """The Panda's fingers closed (0 m) press their pads together at clearance 0: not a
    collision, never certified. A field that closes the fingers used to clamp them there, and
    such poses came back uncertified (6 % of resolved poses at some layouts); they now stop
    LIMIT_INSET (0.1 mm) short of the limit, apart, and are certified."""
    touching = problems.free_poses(panda, 8, 4)
    touching[:, 7:] = 0.0
    assert not profrobot.certify_poses(panda, touching).any()      # clearance 0 at the limit
    w = np.zeros(panda.njoint); w[7:] = 1.0                         # g falls as the fingers close
    q = problems.free_poses(panda, 8, 4)
    res = resolve(LinearField(panda, w, 100.0), q, lr=0.01, iterations=60, refine=False, method="adam", shrink=False)
    np.testing.assert_allclose(res.poses[:, 7:], LIMIT_INSET, atol=1e-6)
    assert res.certified.all()
    np.testing.assert_array_equal(res.poses[:, :7], q[:, :7])       # the rest did not move


def test_certification_catches_poses_the_field_wrongly_calls_free(panda):
    colliding, _ = colliding_and_free(panda)
    sdf = shifted_field(panda, -100.0)               # calls everything free: nothing to optimise
    res = resolve(sdf, colliding[:20], refine_rounds=2, iterations=5, method="adam")
    assert (res.iterations == 0).all()               # the field was satisfied at once ...
    assert not res.certified.any()                    # ... but the exact labeller was not
    assert len(res.failures) == 20 and res.rounds == 2
    assert "20 failures" in res.summary()
    res = resolve(sdf, colliding[:20], refine=False)  # the projection: the same, without the exact search
    assert (res.iterations == 0).all() and not res.certified.any() and len(res.failures) == 20
    # with it (the default), the labeller's own nearest-free search answers what the field cannot
    res = resolve(sdf, colliding[:20])
    assert (res.iterations == 0).all() and res.certified.all()
    assert profrobot.certify_poses(panda, res.poses).all()
    near = profrobot.nearest_free(panda, colliding[:20], directions=32, refine=64)
    assert np.median(res.delta / near.distance) <= 1.5


def test_refinement_lowers_the_threshold_until_certified(panda):
    """g = θ0 − c makes a colliding pose look free once θ0 < c − 0.1; the labeller disagrees, so
    refinement keeps pushing θ0 down (lower threshold each round) and reports what it achieved."""
    colliding, _ = colliding_and_free(panda)
    w = np.zeros(panda.njoint); w[0] = 1.0
    field = LinearField(panda, w, -colliding[0, 0])   # g(start) = 0
    res = resolve(field, colliding[:1], lr=0.05, refine_rounds=3, refine_step=0.2, method="adam")
    assert res.iterations[0] > 0
    if not res.certified[0]:
        assert res.rounds == 3 and res.threshold[0] == pytest.approx(-0.1 - 3 * 0.2)
    else:
        assert profrobot.label_poses(panda, res.poses).collides.sum() == 0


def test_projection_is_the_exact_box_halfspace_projection():
    """project_box_halfspace against SLSQP on min ½‖x − θ₀‖² s.t. a·x ≤ b, lo ≤ x ≤ hi: random
    problems where the half-space cuts the box, misses θ₀, or already holds it."""
    from scipy.optimize import minimize

    from profrobot.optim.resolution import project_box_halfspace

    rng = np.random.default_rng(0)
    n, K = 40, 7
    theta0 = rng.uniform(-1, 1, (n, K))
    a = rng.normal(size=(n, K))
    b = (a * theta0).sum(1) - rng.uniform(-0.5, 2.0, n)     # some rows already satisfied (b above a·θ₀)
    lo, hi = np.full((n, K), -1.2), np.full((n, K), 1.2)
    lo[:, 3], hi[:, 3] = -np.inf, np.inf                    # an unbounded (continuous) joint
    t = lambda x: torch.as_tensor(x, dtype=torch.float64)  # noqa: E731
    x = project_box_halfspace(t(theta0), t(a), t(b), t(lo), t(hi)).numpy()
    for i in range(n):
        t0, ai, bi = theta0[i], a[i], b[i]
        ref = minimize(lambda y, t0=t0: 0.5 * ((y - t0) ** 2).sum(), np.clip(t0, -1.2, 1.2),
                       jac=lambda y, t0=t0: y - t0, method="SLSQP",
                       bounds=[(None if np.isinf(l) else l, None if np.isinf(u) else u) for l, u in zip(lo[i], hi[i])],
                       constraints=[dict(type="ineq", fun=lambda y, ai=ai, bi=bi: bi - ai @ y, jac=lambda y, ai=ai: -ai)],
                       options=dict(ftol=1e-14, maxiter=500))
        np.testing.assert_allclose(x[i], ref.x, atol=2e-6)
        assert a[i] @ x[i] <= b[i] + 1e-9 and (x[i] >= lo[i]).all() and (x[i] <= hi[i]).all()


def test_project_on_a_linear_field_is_one_exact_step(panda):
    """g = w·θ + b: the nearest pose with g ≤ l_thres is θ₀ − (g₀ − l_thres) w/‖w‖², reached by the
    first projection step and confirmed (a fixed point) by the second."""
    colliding, _ = colliding_and_free(panda)
    q = colliding[:6]
    w = np.zeros(panda.njoint); w[1], w[2] = 0.6, -0.8       # ‖w‖ = 1, joints 1 and 2 only
    b = 0.3 - q[:, 1:3] @ w[1:3]                              # g₀ = 0.3 for row 0 ...
    field = LinearField(panda, w, float(b[0]))
    res = resolve(field, q, l_thres=-0.1, refine=False, shrink=False)
    g0 = q @ w + b[0]
    want = q - (g0 + 0.1)[:, None] * w[None, :]
    moved = g0 > -0.1
    np.testing.assert_allclose(res.poses[moved], want[moved], atol=2e-6)
    assert (res.iterations[moved] == 1).all()                 # one step, then the fixed point stops it
    np.testing.assert_allclose(res.delta[moved], (g0 + 0.1)[moved], atol=2e-6)


def test_shrink_returns_the_first_certified_pose_on_the_segment(panda):
    """A field that overshoots (threshold −1 on a linear field): every shrunk move is certified, no
    longer than the unshrunk one, and the pose a bisection step before it is not certified; rays
    whose end the labeller does not certify are extended until it does."""
    colliding, _ = colliding_and_free(panda, n=40)
    w = np.zeros(panda.njoint); w[1] = 1.0
    field = LinearField(panda, w, -float(colliding[:, 1].min()) + 0.05)   # every pose starts at g ≥ 0.05
    far = resolve(field, colliding, l_thres=-1.0, refine=False, shrink=False)
    near = resolve(field, colliding, l_thres=-1.0, refine=False)
    ok = far.certified
    assert ok.any()
    assert (near.certified >= far.certified).all()      # where the field's answer falls short, the ray goes on
    assert profrobot.certify_poses(panda, near.poses[near.certified]).all()
    assert (near.delta[ok] <= far.delta[ok] + 1e-12).all() and (near.delta[ok] < 0.9 * far.delta[ok]).any()
    # just short of each shrunk pose (2^-8 / 8 of its segment) the labeller does not certify
    d = far.poses[ok] - colliding[ok]
    step = 1.0 / (8 * 2 ** 8)
    t = np.linalg.norm(near.poses[ok] - colliding[ok], axis=1) / np.linalg.norm(d, axis=1)
    before = colliding[ok] + np.clip(t - step, 0, 1)[:, None] * d
    assert not profrobot.certify_poses(panda, before[t < 1]).any()


def test_regression_a_flat_field_does_not_crash_the_projection(panda):
    """A field with no gradient (g = 1 everywhere) used to send the projection's multiplier to
    inf and the poses to NaN, so resolve raised instead of reporting failures."""
    colliding, _ = colliding_and_free(panda, n=6)
    flat = LinearField(panda, np.zeros(panda.njoint), 1.0)
    res = resolve(flat, colliding, refine=False)
    np.testing.assert_array_equal(res.poses, colliding)         # no direction: nothing moves
    assert not res.certified.any() and len(res.failures) == 6
    res = resolve(flat, colliding)                                # the exact search needs no field
    assert res.certified.all() and profrobot.certify_poses(panda, res.poses).all()


def test_project_returns_certified_inputs_unchanged(panda):
    colliding, free = colliding_and_free(panda, n=10)
    q = np.concatenate([free[:5], colliding[:5]])
    ok = profrobot.certify_poses(panda, q)
    res = resolve(shifted_field(panda, 5.0), q, refine=False)      # the field calls everything colliding
    np.testing.assert_array_equal(res.poses[ok], q[ok])
    assert (res.iterations[ok] == 0).all() and (res.delta[ok] == 0).all()


def test_resolve_bad_input(panda, ur5e):
    sdf = shifted_field(panda, 0.0)
    q = profrobot.sample_poses(panda, 3, seed=0)
    with pytest.raises(ValueError, match=r"shape \(B, 9\)"):
        resolve(sdf, q[:, :-1])
    bad = q.copy(); bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="finite"):
        resolve(sdf, bad)
    out = q.copy(); out[0, 0] = 10.0
    with pytest.raises(ValueError, match="outside the limits"):
        resolve(sdf, out)
    with pytest.raises(RobotMismatchError, match="made for robot"):
        resolve(sdf, q, robot=ur5e)
    with pytest.raises(ValueError, match="lr"):
        resolve(sdf, q, lr=0, method="adam")
    with pytest.raises(ValueError, match="method='adam'"):
        resolve(sdf, q, lr=0.01)                       # the projection has no step size
    with pytest.raises(ValueError, match="method"):
        resolve(sdf, q, method="newton")
    with pytest.raises(ValueError, match="iterations"):
        resolve(sdf, q, iterations=-1)
    with pytest.raises(TypeError, match="floating"):
        resolve(sdf, q.astype(np.complex128))


# ---- trajectories ----------------------------------------------------------------------------

def _hard_pair(robot, seed=5):
    """Two free poses whose straight SO(2) interpolation collides."""
    (a,), (b,) = problems.hard_pairs(robot, 1, seed, steps=30)
    return a, b


def test_check_path_finds_collisions_between_free_waypoints(panda):
    a, b = _hard_pair(panda)
    chk = check_path(panda, np.stack([a, b]), density=50, method="sampled")
    assert not chk.waypoint_uncertified.any() and chk.segment_uncertified.all() and not chk.certified
    assert len(chk.dense) == 51
    cont = check_path(panda, np.stack([a, b]))  # the continuous certificate refuses it too
    assert cont.method == "continuous" and cont.segment_uncertified.all() and not cont.certified
    path = profrobot.interpolate(panda, a, b, 30)
    full = check_path(panda, path, density=4, method="sampled")
    assert not full.certified and full.uncertified_segments.size > 0
    hit = np.flatnonzero(full.dense_uncertified)
    assert set(np.minimum(hit // 4, 28)) <= set(full.uncertified_segments)
    # every segment a sample finds colliding is refused continuously (the proof covers the samples)
    assert set(full.uncertified_segments) <= set(check_path(panda, path).uncertified_segments)


def test_plan_reports_collisions_the_field_misses(panda):
    """A field that calls everything free leaves the straight path as it is (init="straight":
    the field alone); the dense check must say where it collides."""
    a, b = _hard_pair(panda)
    for method in ("penalty", "tangent"):
        res = plan_trajectory(shifted_field(panda, -100.0), a, b, steps=20, method=method, init="straight",
                              penalty=PenaltyOptions(iterations=10), tangent=TangentOptions(iterations=500, delta=0.05))
        assert not res.certified and res.uncertified_segments.size > 0
        np.testing.assert_array_equal(res.path[0], a)
        np.testing.assert_array_equal(res.path[-1], b)
        assert res.path.shape == (20, panda.njoint)
        assert profrobot.label_poses(panda, res.check.dense).collides.any()


def test_plan_penalty_moves_waypoints_along_the_field_gradient(panda):
    """g = θ0 + b, all waypoints above the threshold: the interior moves to lower θ0, end points
    stay, limits hold, and batches give one result per problem."""
    pairs = [_hard_pair(panda, seed) for seed in (5, 6)]   # straight paths collide: work to do
    starts, goals = np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])
    w = np.zeros(panda.njoint); w[0] = 1.0
    field = LinearField(panda, w, 5.0)
    res = plan_trajectories(field, starts, goals, steps=10, penalty=PenaltyOptions(iterations=20, check_every=1000),
                          init="straight")
    assert len(res) == 2
    for r, a, b in zip(res, starts, goals):
        straight = profrobot.interpolate(panda, a, b, 10)
        assert (r.path[1:-1, 0] < straight[1:-1, 0]).all()
        np.testing.assert_array_equal(r.path[[0, -1]], np.stack([a, b]))
        assert r.iterations == 20 and r.relative_length > 1
        lim = panda.joint_limits
        assert (r.path >= lim[:, 0]).all() and (r.path <= lim[:, 1]).all()


def test_plan_tangent_walk_reaches_the_goal_in_free_space(panda):
    """Far from the threshold the projection is off: the walk is straight to the goal."""
    _, free = colliding_and_free(panda)
    field = LinearField(panda, np.zeros(panda.njoint), -10.0)
    res = plan_trajectory(field, free[0], free[1], steps=15, method="tangent",
                          tangent=TangentOptions(delta=0.05, goal_norm="l2"), init="straight")
    np.testing.assert_allclose(res.path, profrobot.interpolate(panda, free[0], free[1], 15), atol=1e-4)
    l1 = plan_trajectory(field, free[0], free[1], steps=15, method="tangent", tangent=TangentOptions(delta=0.05),
                         init="straight")   # the paper's L1
    np.testing.assert_array_equal(l1.path[[0, -1]], np.stack([free[0], free[1]]))
    assert l1.iterations > 0 and l1.relative_length >= 1 - 1e-6


def test_plan_bad_input(panda):
    sdf = shifted_field(panda, 0.0)
    q = profrobot.sample_poses(panda, 2, seed=0)
    with pytest.raises(ValueError, match="method"):
        plan_trajectory(sdf, q[0], q[1], method="rrt")
    with pytest.raises(ValueError, match="plans one problem"):
        plan_trajectory(sdf, q[0], q)
    with pytest.raises(ValueError, match=r"takes \(B, K\)"):
        plan_trajectories(sdf, q[0], q[1])
    with pytest.raises(ValueError, match="shape"):
        plan_trajectory(sdf, q[0, :-1], q[1, :-1])
    with pytest.raises(ValueError, match="steps"):
        plan_trajectory(sdf, q[0], q[1], steps=2)
    bad = q[1].copy(); bad[0] = np.inf
    with pytest.raises(ValueError, match="finite"):
        plan_trajectory(sdf, q[0], bad)


# ---- pictures --------------------------------------------------------------------------------

def test_gif_and_plot(tmp_path, panda, renderer):
    pytest.importorskip("PIL")
    from PIL import Image

    from profrobot.optim.pictures import plot_trajectory, render_trajectory

    a, b = _hard_pair(panda)
    res = plan_trajectory(shifted_field(panda, -100.0), a, b, steps=6, penalty=PenaltyOptions(iterations=0))
    gif = render_trajectory(panda, res.path, tmp_path / "t.gif", size=(96, 72))
    with Image.open(gif) as im:
        assert im.n_frames == 6 and im.size == (96, 72)
    png = plot_trajectory(res, tmp_path / "t.png", joint_names=panda.joint_names)
    assert png.stat().st_size > 0
    with pytest.raises(ValueError, match="gif"):
        render_trajectory(panda, res.path, tmp_path / "t.avi")


# ---- with a trained field --------------------------------------------------------------------

@pytest.mark.slow
def test_trained_field_resolves_and_plans(panda):
    torch.manual_seed(0)
    sdf = profrobot.train_sdf(panda, hidden=(64, 64), n_poses=50_000, iterations=150, progress=False)
    colliding, _ = colliding_and_free(panda, 100, seed=11)
    res = resolve(sdf, colliding[:100])
    assert res.certified.mean() >= 0.9
    assert profrobot.label_poses(panda, res.poses[res.certified]).collides.sum() == 0
    a, b = _hard_pair(panda, seed=12)
    path = plan_trajectory(sdf, a, b, steps=50)
    if path.certified:   # a path reported free must be free under the exact labeller
        assert not profrobot.label_poses(panda, path.check.dense).collides.any()


# ---- command line ----------------------------------------------------------------------------

def test_cli_resolve_and_plan(tmp_path, panda, capsys):
    from profrobot import gl
    from profrobot.cli.main import main

    ckpt = shifted_field(panda, -100.0).save(tmp_path / "field")
    # a field that calls everything free, without the exact search: the labeller's failures must
    # show in the exit status
    assert main(["resolve", "--field", str(ckpt), "-n", "5", "--iterations", "3", "--no-refine",
                 "--out", str(tmp_path / "r.npz")]) == 1
    out = capsys.readouterr().out
    assert "5 failures" in out and "still colliding" in out
    saved = np.load(tmp_path / "r.npz")
    assert saved["poses"].shape == (5, panda.njoint) and not saved["certified"].any()
    # with it (the default), every pose is certified: exit status 0; Adam through the CLI too
    assert main(["resolve", "--field", str(ckpt), "-n", "5"]) == 0
    assert main(["resolve", "--field", str(ckpt), "-n", "3", "--method", "adam", "--lr", "0.05", "--iterations", "4",
                 "--no-refine"]) == 1
    capsys.readouterr()
    # init straight: the field alone, which calls everything free, so the dense check must report it
    code = main(["plan", "--field", str(ckpt), "--steps", "5", "--iterations", "5", "--init", "straight",
                 "--gif", str(tmp_path / "p.gif"),
                 "--plot", str(tmp_path / "p.png")])
    if gl.status()[0] is None:   # no MuJoCo renderer here: one clear error, exit status 2
        assert code == 2 and "libosmesa6" in capsys.readouterr().err
    else:
        assert code == 1 and "NOT certified" in capsys.readouterr().out
        assert (tmp_path / "p.gif").stat().st_size > 0 and (tmp_path / "p.png").stat().st_size > 0
    assert main(["plan", "--field", str(ckpt), "--start", "0,0"]) == 2   # --goal missing: a clear error


def test_plan_penalty_options_keep_the_ends_and_limits(panda):
    """midpoints and the path-energy term (beyond the paper) change the loss, not the contract."""
    a, b = _hard_pair(panda)
    w = np.zeros(panda.njoint); w[0] = 1.0
    res = plan_trajectory(LinearField(panda, w, 5.0), a, b, steps=8,
                          penalty=PenaltyOptions(iterations=5, midpoints=True, gamma3=1.0), init="straight")
    np.testing.assert_array_equal(res.path[[0, -1]], np.stack([a, b]))
    assert res.iterations == 5 and (res.path[1:-1, 0] < profrobot.interpolate(panda, a, b, 8)[1:-1, 0]).all()
    with pytest.raises(ValueError, match="gamma3"):
        plan_trajectory(LinearField(panda, w, 5.0), a, b, penalty=PenaltyOptions(gamma3=-1.0))
    with pytest.raises(TypeError, match="iterations"):   # the options live in PenaltyOptions only
        plan_trajectory(LinearField(panda, w, 5.0), a, b, steps=8, iterations=5, init="straight")


def test_limits_clamp_limited_wrap_continuous():
    from profrobot.kinematics.limits import Limits

    lim = Limits([-1.0, -np.pi, 0.0], [1.0, np.pi, 0.5], [False, True, False])
    theta = torch.tensor([[2.0, np.pi + 0.5, -0.1], [-3.0, -np.pi - 0.5, 0.7]])
    out = lim.clamp_or_wrap(theta)
    torch.testing.assert_close(out, torch.tensor([[1.0, -np.pi + 0.5, 0.0], [-1.0, np.pi - 0.5, 0.5]]))
    u = lim.normalise(out)
    assert (u >= -1).all() and (u <= 1).all()
    torch.testing.assert_close(lim.denormalise(u), out)
    u2 = torch.tensor([[1.5, 1.25, -2.0]])
    lim.clamp_or_wrap_normalised_(u2)
    torch.testing.assert_close(u2, torch.tensor([[1.0, -0.75, -1.0]]))
    torch.testing.assert_close(lim.denormalise(u2), lim.clamp_or_wrap(lim.denormalise(torch.tensor([[1.5, 1.25, -2.0]]))))
    np.testing.assert_allclose(lim.diff([np.pi - 0.1, np.pi - 0.1, 0], [0, -np.pi + 0.1, 0]), [np.pi - 0.1, -0.2, 0])
    with pytest.raises(ValueError):
        Limits([1.0], [0.0], [False])


def test_problems_are_seeded_and_what_they_say(panda):
    c = problems.colliding_poses(panda, 30, seed=4)
    f = problems.free_poses(panda, 30, seed=4)
    assert c.shape == f.shape == (30, panda.njoint)
    assert profrobot.label_poses(panda, c).collides.all() and not profrobot.label_poses(panda, f).collides.any()
    np.testing.assert_array_equal(c, problems.colliding_poses(panda, 30, seed=4))
    assert not np.array_equal(c, problems.colliding_poses(panda, 30, seed=5))
    starts, goals = problems.hard_pairs(panda, 3, seed=4, steps=20)
    assert starts.shape == goals.shape == (3, panda.njoint)
    assert not profrobot.label_poses(panda, np.concatenate([starts, goals])).collides.any()
    for a, b in zip(starts, goals):
        assert not check_path(panda, profrobot.interpolate(panda, a, b, 20)).certified
    s2, g2 = problems.hard_pairs(panda, 3, seed=4, steps=20)
    np.testing.assert_array_equal(s2, starts) and np.testing.assert_array_equal(g2, goals)
    with pytest.raises(ValueError, match="n must be"):
        problems.colliding_poses(panda, 0)
    with pytest.raises(ValueError, match="start/goal pairs"):
        problems.hard_pairs(panda, 5, seed=0, steps=20, max_pairs=2)
