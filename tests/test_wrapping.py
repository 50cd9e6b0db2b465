"""One angle wrap (issue 19): ``rust/joints/angles.rs`` in the core (interpolation and planner alike) and
its Python twin ``profrobot.robot.angles.wrap`` (joints, planning helpers, path unwrapping), equal bit
for bit, with pi going to -pi: a half turn moves the negative way everywhere."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

import profrobot
from profrobot import _core
from profrobot.robot.angles import unwrap, wrap
from profrobot.kinematics.limits import Limits, _wrap
from profrobot.exact.planning import so2_steps

PI = math.pi
BELOW = np.nextafter(-PI, -np.inf)  # the float just below -pi: its remainder rounds up to 2 pi
EDGES = np.array([PI, -PI, 3 * PI, -3 * PI, 5 * PI, -5 * PI, 0.0, -0.0, 5e-324, -5e-324, 1e-300, -1e-300, 1e-17,
                  BELOW, np.nextafter(PI, np.inf), np.nextafter(PI, 0.0), np.nextafter(-PI, 0.0),
                  2 * PI, -2 * PI, np.nextafter(2 * PI, 0.0), 1.0, -1.0, 4.0, -4.0, 7.0, -7.0, 1e6, -1e6, 1e15])


def rust_wrap(x: np.ndarray) -> np.ndarray:
    """The core's ``angles::wrap``, read through ``interpolate``: the end of ``0 -> x`` in two steps
    is ``0 + 1 * wrap(x - 0)``, i.e. ``wrap(x)`` exactly (a -0.0 comes back as 0.0)."""
    x = np.asarray(x, dtype=np.float64).reshape(-1, 1)
    return _core.interpolate(np.zeros_like(x), x, 2, np.array([True]))[:, 1, 0]


def bits(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).view(np.int64)


def test_python_wrap_is_the_rust_wrap_bit_for_bit():
    rng = np.random.default_rng(0)
    xs = np.concatenate([EDGES, rng.uniform(-20, 20, 20_000), rng.normal(0, 1e3, 2000),
                         PI * rng.integers(-9, 10, 200), np.nextafter(PI * rng.integers(-9, 10, 200), np.inf)])
    np.testing.assert_array_equal(bits(0.0 + wrap(xs)), bits(rust_wrap(xs)))


def test_wrap_semantics_at_the_edges():
    assert wrap(PI) == -PI and wrap(-PI) == -PI and wrap(BELOW) == -PI
    assert wrap(3 * PI) == -PI and wrap(-3 * PI) == -PI
    for x in (0.0, -0.0, 5e-324, 1e-300, -1e-300, 0.3, np.nextafter(PI, 0.0)):  # in range: untouched
        assert bits(wrap(x)) == bits(x), x
    w = wrap(EDGES)
    assert ((w >= -PI) & (w < PI)).all()
    np.testing.assert_array_equal(bits(wrap(w)), bits(w))  # idempotent
    assert isinstance(wrap(1.0), float) and wrap(np.ones((2, 3))).shape == (2, 3)
    assert math.isnan(wrap(np.nan)) and math.isnan(wrap(np.inf))


def test_torch_twin_equals_wrap_bit_for_bit():
    t = torch.tensor(EDGES, dtype=torch.float64, requires_grad=True)
    out = _wrap(t)
    np.testing.assert_array_equal(bits(out.detach().numpy()), bits(wrap(EDGES)))
    out.sum().backward()
    assert (t.grad == 1).all()
    # float32: the same formula, into [-pi, pi) of float32.
    w32 = _wrap(torch.tensor(EDGES, dtype=torch.float32))
    pi32 = torch.tensor(PI, dtype=torch.float32)
    assert ((w32 >= -pi32) & (w32 < pi32)).all() and w32[0] == -pi32


def test_every_python_wrap_site_agrees():
    cont = np.array([True, False])
    lim = Limits([-PI, -1.0], [PI, 1.0], cont, like=torch.zeros((), dtype=torch.float64))
    q = np.stack([EDGES, np.zeros_like(EDGES)], axis=1)
    np.testing.assert_array_equal(bits(lim.numpy(q)[:, 0]), bits(wrap(EDGES)))
    np.testing.assert_array_equal(bits(lim.diff(q, np.zeros_like(q))[:, 0]), bits(wrap(EDGES)))
    np.testing.assert_array_equal(bits(lim.clamp_or_wrap(torch.from_numpy(q))[:, 0].numpy()), bits(wrap(EDGES)))
    # normalised coordinates wrap into [-1, 1) the same way (1 goes to -1)
    u = torch.tensor([[1.0, 0.0], [-1.0, 0.0], [3.0, 0.0], [0.25, 0.0]], dtype=torch.float64)
    assert lim.clamp_or_wrap_normalised_(u)[:, 0].tolist() == [-1.0, -1.0, -1.0, 0.25]


def test_unwrap_takes_the_same_arcs_as_interpolate():
    path = np.array([[0.0], [PI], [0.0], [-PI], [BELOW], [3.0], [-3.0]])
    un = unwrap(path, axis=0)
    steps = np.diff(un, axis=0)[:, 0]
    np.testing.assert_array_equal(steps[:2], [-PI, -PI])  # half turns: the negative way, out and back
    assert np.abs(np.diff(un[:, 0])).max() <= PI
    for i in range(len(path) - 1):  # each step is interpolate's, and lands on the same angle
        ends = _core.interpolate(path[i:i + 1], path[i + 1:i + 2], 2, np.array([True]))[0]
        assert steps[i] == pytest.approx(ends[1, 0] - ends[0, 0], abs=1e-12)
        assert wrap(un[i + 1, 0]) == pytest.approx(wrap(path[i + 1, 0]), abs=1e-12)
    assert unwrap(np.zeros((1, 3)), axis=0).shape == (1, 3)


# --------------------------------------------------------------------------------------------
# The planner replays through interpolate, also at exactly ±pi
# --------------------------------------------------------------------------------------------

# An arm on a continuous hinge about z over a post at angle -pi/2: the short way from pi to 0
# (through +pi/2) is free; between -pi/2 +- 0.6 the short way is blocked and the path must go
# round through ±pi.
_SPIN_XML = """
<mujoco>
  <worldbody>
    <geom name="post" type="box" size="0.05 0.05 0.05" pos="0 -0.4 0.1"/>
    <body name="arm" pos="0 0 0.1">
      <joint name="spin" type="hinge" axis="0 0 1" limited="false"/>
      <geom name="link" type="capsule" fromto="0.15 0 0 0.5 0 0" size="0.03"/>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def spin():
    robot = profrobot.Robot.from_spec(mujoco.MjSpec.from_string(_SPIN_XML), name="spin")
    assert list(robot.continuous) == [True] and robot.core.npair == 1
    return robot


def _replay(robot, path: np.ndarray, per_segment: int = 200) -> np.ndarray:
    return np.concatenate([profrobot.interpolate(robot, path[i], path[i + 1], per_segment)
                           for i in range(len(path) - 1)])


@pytest.mark.parametrize("start", [PI, -PI, BELOW])
@pytest.mark.parametrize("goal", [0.0, PI / 2])
def test_planned_half_turns_replay_through_interpolate(spin, start, goal):
    res = profrobot.plan_path(spin, [start], [goal], resolution=0.01, seed=0)
    assert res.status == "direct"
    np.testing.assert_array_equal(res.path, [[-PI], [goal]])  # start wrapped: pi and -pi are -pi
    replay = profrobot.interpolate(spin, res.path[0], res.path[1], 101)
    assert (np.diff(replay[:, 0]) < 0).all()  # the planner checked -pi -> -3pi/2 (+pi/2) -> ...
    np.testing.assert_allclose(so2_steps(spin, res.path)[0], replay[-1] - replay[0], rtol=0, atol=1e-15)
    # from -pi to 0 is a half turn: the negative way (through +pi/2), in both the planner and here
    if goal == 0.0:
        assert replay[-1, 0] == -2 * PI and replay[50, 0] == pytest.approx(-1.5 * PI)
    assert not profrobot.label_poses(spin, replay).collides.any()


def test_a_path_round_through_pi_replays_free(spin):
    start, goal = np.array([-PI / 2 + 0.6]), np.array([-PI / 2 - 0.6])
    assert profrobot.label_poses(spin, _core.interpolate(start[None], goal[None], 50, np.array([True]))[0]).collides.any()
    res = profrobot.plan_path(spin, start, goal, resolution=0.01, seed=1)
    assert res.found and res.status == "connected"
    assert ((res.path >= -PI) & (res.path < PI)).all()
    replay = _replay(spin, res.path)
    assert not profrobot.label_poses(spin, replay).collides.any()
    # the replay goes the long way, through pi (the post blocks the short one)
    turned = unwrap(replay, axis=0)[:, 0]
    assert turned.max() - turned.min() > PI and turned.max() > PI / 2
    np.testing.assert_allclose(wrap(replay[-1]), wrap(goal), atol=1e-12)
