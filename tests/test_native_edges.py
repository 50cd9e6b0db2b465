"""Native edges (issue 15): array layouts at the native surface, MuJoCo's geom_sameframe frames,
coupled joints. Regression tests are named after the bug they pin."""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot import _core
from profrobot.robot.equalities import EqualityWarning, equality_residual

from conftest import scene


# --------------------------------------------------------------------------------------------
# 1. Array layouts: every native entry point reads rows, never storage order
# --------------------------------------------------------------------------------------------

def _layouts(q: np.ndarray) -> dict[str, np.ndarray]:
    """The same (B, K) values in layouts that are not C-contiguous."""
    b, k = q.shape
    wide = np.zeros((b, 2 * k))
    wide[:, ::2] = q
    tall = np.zeros((2 * b, k))
    tall[::2] = q
    return {"fortran": np.asfortranarray(q), "negative_column_strides": np.ascontiguousarray(q[:, ::-1])[:, ::-1],
            "reversed_view": np.ascontiguousarray(q[::-1])[::-1], "column_slice": wide[:, ::2],
            "row_slice": tall[::2], "transposed": np.ascontiguousarray(q.T).T}


def test_fortran_order_label_regression():
    """core.label read a Fortran-ordered array as if it were C-ordered (521 of 1000 labels wrong)."""
    robot = scene("ur5e_wall_box")
    q = profrobot.sample_poses(robot, 1000, seed=3)
    want = robot.core.label(q, distance=True)
    for name, v in _layouts(q).items():
        assert not v.flags.c_contiguous and np.array_equal(v, q), name
        got = robot.core.label(v, distance=True)
        for key in want:
            np.testing.assert_array_equal(got[key], want[key], err_msg=f"{name}: {key}")


def test_every_layout_forward_kinematics_and_pairs():
    robot = scene("panda_blocks")
    q = profrobot.sample_poses(robot, 300, seed=4)
    xpos, xquat = robot.core.forward_kinematics(q)
    lab = robot.core.label(q, pairs=True)
    for name, v in _layouts(q).items():
        p, r = robot.core.forward_kinematics(v)
        np.testing.assert_array_equal(p, xpos, err_msg=name)
        np.testing.assert_array_equal(r, xquat, err_msg=name)
        np.testing.assert_array_equal(robot.core.label(v, pairs=True)["colliding_pairs"], lab["colliding_pairs"])


def test_every_layout_interpolate():
    robot = scene("ur5e_wall_box")
    s = profrobot.sample_poses(robot, 20, seed=5)
    g = profrobot.sample_poses(robot, 20, seed=6)
    cont = np.ascontiguousarray(robot.continuous)
    want = _core.interpolate(s, g, 7, cont)
    for name, v in _layouts(s).items():
        np.testing.assert_array_equal(_core.interpolate(v, g, 7, cont), want, err_msg=f"start {name}")
        np.testing.assert_array_equal(_core.interpolate(s, _layouts(g)[name], 7, cont), want, err_msg=f"goal {name}")
    wide = np.zeros(2 * len(cont), dtype=bool)
    wide[::2] = cont
    np.testing.assert_array_equal(_core.interpolate(s, g, 7, wide[::2]), want)


def test_model_arrays_in_any_layout_build_the_same_model():
    robot = scene("panda_blocks")
    arrays = robot.core_arrays()
    strided = {k: (np.asfortranarray(v) if isinstance(v, np.ndarray) and v.ndim == 2 else v) for k, v in arrays.items()}
    core = _core.RobotModel(strided)
    q = profrobot.sample_poses(robot, 2000, seed=7)
    for key, v in robot.core.label(q, distance=True).items():
        np.testing.assert_array_equal(core.label(q, distance=True)[key], v, err_msg=key)


@pytest.mark.parametrize("dtype", [np.float32, np.int64, np.complex128])
def test_wrong_dtype_names_the_dtype_it_wants(dtype):
    """core.label on float32 said "'ndarray' object is not an instance of 'ndarray'"."""
    robot = scene("ur5e_wall_box")
    q = np.zeros((3, robot.njoint), dtype=dtype)
    with pytest.raises(TypeError, match=rf"float64.*\(B, 6\).*{np.dtype(dtype).name}"):
        robot.core.label(q)
    with pytest.raises(TypeError, match="float64"):
        robot.core.forward_kinematics(q)
    with pytest.raises(TypeError, match="start must be a 2-D float64"):
        _core.interpolate(q, q.astype(np.float64), 3, np.zeros(6, dtype=bool))
    with pytest.raises(TypeError, match="1-D bool"):
        _core.interpolate(q.astype(np.float64), q.astype(np.float64), 3, np.zeros(6))


def test_wrong_shapes_and_objects_at_the_native_surface():
    robot = scene("ur5e_wall_box")
    with pytest.raises(ValueError, match=r"shape \(B, 6\)"):
        robot.core.label(np.zeros((4, 5)))
    with pytest.raises(TypeError, match="2-D float64.*1-D float64"):
        robot.core.label(np.zeros(6))
    with pytest.raises(TypeError, match="got a list"):
        robot.core.label([[0.0] * 6])
    with pytest.raises(profrobot.errors.ProfrobotError if hasattr(profrobot, "errors") else ValueError):
        robot.core.label(np.full((2, 6), np.nan))


def test_model_errors_are_model_error():
    robot = scene("panda_blocks")
    arrays = robot.core_arrays()
    arrays["geom_body"] = arrays["geom_body"] + 1000
    with pytest.raises(_core.ModelError, match="invalid robot model"):
        _core.RobotModel(arrays)
    assert issubclass(_core.ModelError, _core.InputError) and issubclass(_core.InputError, _core.ProfrobotError)
    assert issubclass(_core.ModelError, ValueError) and not issubclass(_core.ProfrobotError, ValueError)


def _bad_core_calls(robot):
    """(what, call, the class it must raise, the built-in base it must have): every deliberate
    error path of the native surface that a Python caller can reach with bad input."""
    core, k = robot.core, robot.njoint
    q = np.zeros((2, k))
    arrays = robot.core_arrays()
    missing = {key: v for key, v in arrays.items() if key != "exclude"}
    wrong_dtype = dict(arrays, jnt_axis=arrays["jnt_axis"].astype(np.float32))
    bad_model = dict(arrays, geom_body=arrays["geom_body"] + 1000)
    cam = dict(opacities=np.full(1, 0.5), viewmats=np.eye(4)[None], Ks=np.array([[[8.0, 0, 2], [0, 8, 2], [0, 0, 1]]]),
               views=np.zeros((1, 2), np.int64), means=np.array([[[0.0, 0, 1]]]), covs=np.eye(3)[None, None] * 1e-3,
               colors=np.ones((1, 3)))

    def render(**kw):
        a = {**cam, **kw}
        return _core.render_forward(a.pop("opacities"), a.pop("viewmats"), a.pop("Ks"), a.pop("views"), 4, 4, **a)
    return [
        ("label: wrong width", lambda: core.label(np.zeros((2, k + 1))), _core.InputError, ValueError),
        ("label: NaN", lambda: core.label(np.full((2, k), np.nan)), _core.InputError, ValueError),
        ("label: empty", lambda: core.label(np.zeros((0, k))), _core.InputError, ValueError),
        ("label: float32", lambda: core.label(q.astype(np.float32)), _core.InputTypeError, TypeError),
        ("label: a list", lambda: core.label(q.tolist()), _core.InputTypeError, TypeError),
        ("label: threads=0", lambda: core.label(q, threads=0), _core.InputError, ValueError),
        ("collides: 1-D", lambda: core.collides(np.zeros(k)), _core.InputTypeError, TypeError),
        ("collides: inf", lambda: core.collides(np.full((1, k), np.inf)), _core.InputError, ValueError),
        ("forward_kinematics: wrong width", lambda: core.forward_kinematics(np.zeros((1, k - 1))), _core.InputError,
         ValueError),
        ("nearest_free: directions=0", lambda: core.nearest_free(q, directions=0), _core.InputError, ValueError),
        ("nearest_free: tolerance > step", lambda: core.nearest_free(q, step=0.01, tolerance=0.1), _core.InputError,
         ValueError),
        ("plan_path: max_time=0", lambda: core.plan_path(q[0], q[0], max_time=0.0), _core.InputError, ValueError),
        ("plan_path: wrong length", lambda: core.plan_path(q[0, :-1], q[0], max_time=1.0), _core.InputError,
         ValueError),
        ("plan_path: 2-D start", lambda: core.plan_path(q, q[0]), _core.InputTypeError, TypeError),
        ("sample: n=0", lambda: core.sample(0, 0), _core.InputError, ValueError),
        ("RobotModel: missing key", lambda: _core.RobotModel(missing), _core.InputError, ValueError),
        ("RobotModel: float32 array", lambda: _core.RobotModel(wrong_dtype), _core.InputTypeError, TypeError),
        ("RobotModel: bad body index", lambda: _core.RobotModel(bad_model), _core.ModelError, ValueError),
        ("_from_state: not bytes", lambda: _core.RobotModel._from_state("x"), _core.InputTypeError, TypeError),
        ("_from_state: garbage", lambda: _core.RobotModel._from_state(b"garbage"), _core.ProfrobotError, ValueError),
        ("interpolate: steps=1", lambda: _core.interpolate(q, q, 1, np.zeros(k, bool)), _core.InputError, ValueError),
        ("interpolate: NaN", lambda: _core.interpolate(q * np.nan, q, 3, np.zeros(k, bool)), _core.InputError,
         ValueError),
        ("interpolate: float flags", lambda: _core.interpolate(q, q, 3, np.zeros(k)), _core.InputTypeError, TypeError),
        ("render_forward: cutoff", lambda: render(cutoff="x"), _core.InputError, ValueError),
        ("render_forward: NaN", lambda: render(means=np.full((1, 1, 3), np.nan)), _core.InputError, ValueError),
        ("render_forward: shapes", lambda: render(covs=np.ones((1, 2, 3, 3))), _core.InputError, ValueError),
        ("render_forward: int dtype", lambda: render(means=np.ones((1, 1, 3), np.int64)), _core.InputTypeError,
         TypeError),
        ("render_forward: view out of range", lambda: render(views=np.array([[1, 0]])), _core.InputError, ValueError),
    ]


def test_every_core_error_is_a_profrobot_error():
    """Issue 19: every deliberate error from Rust is a ProfrobotError, and still the built-in
    error (ValueError, TypeError) callers catch; the classes are profrobot.errors'."""
    from profrobot import errors

    assert (errors.ProfrobotError, errors.InputError, errors.InputTypeError, errors.ModelError) == (
        _core.ProfrobotError, _core.InputError, _core.InputTypeError, _core.ModelError)
    robot = scene("ur5e_wall_box")
    for what, call, cls, base in _bad_core_calls(robot):
        with pytest.raises(Exception) as info:
            call()
        e = info.value
        assert isinstance(e, cls) and isinstance(e, base) and isinstance(e, errors.ProfrobotError), (what, type(e), e)
        assert str(e), what


def test_core_error_classes_and_instances_pickle():
    import pickle

    for cls in (_core.ProfrobotError, _core.InputError, _core.InputTypeError, _core.ModelError):
        assert cls.__module__ == "profrobot._core" and pickle.loads(pickle.dumps(cls)) is cls
        e = pickle.loads(pickle.dumps(cls("pose 3: why")))
        assert type(e) is cls and e.args == ("pose 3: why",)
    robot = scene("ur5e_wall_box")
    with pytest.raises(_core.InputError) as info:
        robot.core.label(np.zeros((1, robot.njoint + 1)))
    back = pickle.loads(pickle.dumps(info.value))
    assert type(back) is _core.InputError and back.args == info.value.args


# --------------------------------------------------------------------------------------------
# 2. Geom frames as mj_kinematics takes them (geom_sameframe)
# --------------------------------------------------------------------------------------------

# The box's frame differs from the body's explicit inertial frame by 1e-7 m: within the
# compiler's tolerance, so MuJoCo flags geom_sameframe = 2 and *copies* the inertial frame.
_SAMEFRAME_XML = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 .1"/>
    <body name="link" pos="0 0 0.5">
      <joint name="lift" type="slide" axis="0 0 1" range="-1 1"/>
      <joint name="tilt" type="hinge" axis="1 0 0" range="-1 1"/>
      <inertial pos="0.02 0 -0.0999999" quat="0.9238795 0.3826834 0 0" mass="1" diaginertia="0.01 0.02 0.03"/>
      <geom name="box" type="box" size="0.05 0.08 0.1" pos="0.02 0 -0.1" quat="0.9238795 0.3826834 0 0"/>
    </body>
  </worldbody>
</mujoco>
"""


def _mujoco_distance(m, d, q, g1, g2):
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    return mujoco.mj_geomDistance(m, d, g1, g2, 1.0, None)


@pytest.mark.parametrize("tilt", [0.0, 0.3, -0.7])
def test_geom_sameframe_inertia_boundary_regression(tilt):
    """A geom flagged geom_sameframe = 2 sat 1e-7 m off MuJoCo's: poses bisected onto the
    collision boundary disagreed. Now they agree within 1e-10 m, bisected with either labeller."""
    robot = profrobot.Robot.from_spec(mujoco.MjSpec.from_string(_SAMEFRAME_XML), name="sameframe")
    m = robot.mj_model
    assert list(m.geom_sameframe) == [1, 2] and abs(m.body_ipos[1, 2] - m.geom_pos[1, 2]) > 5e-8
    d = mujoco.MjData(m)
    g_floor, g_box = 0, 1

    def ours_collides(q):
        return bool(robot.core.label(np.array([q]))["collides"][0])

    def mujoco_collides(q):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        return d.ncon > 0

    for collides in (ours_collides, mujoco_collides):
        lo, hi = 0.0, -0.45  # lift: free at 0, box deep in the floor at -0.45
        assert not collides([lo, tilt]) and collides([hi, tilt])
        for _ in range(48):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if collides([mid, tilt]) else (mid, hi)
        for z in (lo, hi):
            q = np.array([[z, tilt]])
            ours = robot.core.label(q, distance=True)["min_distance"][0]
            theirs = _mujoco_distance(m, d, q[0], g_floor, g_box)
            assert abs(ours - theirs) < 1e-10, (collides.__name__, z, ours, theirs)
            assert abs(theirs) < 1e-10
        assert ours_collides([hi, tilt]) == mujoco_collides([hi, tilt])


def test_geom_local_frames_follow_every_sameframe_flag():
    """body · frame reproduces MuJoCo's geom_xpos/xmat for every flag used by the bundled scenes."""
    from profrobot.robot.arrays import geom_local_frames

    for name in ("panda_blocks", "xarm7_table"):
        robot = scene(name)
        m = robot.mj_model
        d = mujoco.MjData(m)
        q = profrobot.sample_poses(robot, 5, seed=1)
        gids = np.arange(m.ngeom)
        pos, quat = geom_local_frames(m, gids)
        xpos, xquat = robot.core.forward_kinematics(q)
        for b in range(len(q)):
            d.qpos[robot.qpos_adr] = q[b]
            mujoco.mj_kinematics(m, d)
            for g in gids:
                body = m.geom_bodyid[g]
                R = np.zeros(9)
                mujoco.mju_quat2Mat(R, xquat[b, body])
                np.testing.assert_allclose(xpos[b, body] + R.reshape(3, 3) @ pos[g], d.geom_xpos[g], atol=1e-12)
                qg = np.zeros(4)
                mujoco.mju_mulQuat(qg, xquat[b, body], quat[g])
                mujoco.mju_quat2Mat(R, qg)
                np.testing.assert_allclose(R, d.geom_xmat[g], atol=1e-12)


# --------------------------------------------------------------------------------------------
# 3. Coupled joints
# --------------------------------------------------------------------------------------------

_COUPLED_XML = """
<mujoco>
  <worldbody>
    <body name="palm">
      <joint name="wrist" type="hinge" axis="0 0 1" range="-3 3"/>
      <geom type="box" size="0.04 0.02 0.02"/>
      <body name="left" pos="-0.02 0 0.04">
        <joint name="left_slide" type="slide" axis="1 0 0" range="-0.03 0.0" ref="-0.01"/>
        <geom type="box" size="0.005 0.01 0.02"/>
      </body>
      <body name="right" pos="0.02 0 0.04">
        <joint name="right_slide" type="slide" axis="-1 0 0" range="-0.03 0.0"/>
        <geom type="box" size="0.005 0.01 0.02"/>
      </body>
    </body>
  </worldbody>
  <equality>
    <joint name="mirror" joint1="right_slide" joint2="left_slide" polycoef="0.002 1 0.5 0 0"/>
  </equality>
</mujoco>
"""


def test_joint_equality_sampled_exactly():
    """Uniform sampling moved coupled joints independently; now the dependent joint is computed."""
    robot = profrobot.Robot.from_spec(mujoco.MjSpec.from_string(_COUPLED_XML), name="coupled")
    (eq,) = robot.equalities
    assert (eq.kind, eq.obj1, eq.obj2, eq.enforced_by_default) == ("joint", "right_slide", "left_slide", True)
    q = profrobot.sample_poses(robot, 5000, seed=0)
    assert robot.couplings.residual(q).max() <= 1e-12
    assert equality_residual(robot.mj_model, q[:200], robot.qpos_adr).max() <= 1e-9  # MuJoCo's own efc_pos
    # the independent joint spans what the mechanism allows: right_slide <= 0 needs left_slide <= -0.012
    assert np.ptp(q[:, 1]) > 0.017
    assert robot.feasible(q).all()   # (issue 33: 1/3 of these poses had right_slide past its limit)
    loose = profrobot.sample_poses(robot, 5000, seed=0, equalities="ignore")
    assert robot.couplings.residual(loose).max() > 1e-3
    data = profrobot.make_dataset(robot, 200, collided_fraction=0.0, seed=1, progress=False)
    assert robot.couplings.residual(data.poses).max() <= 1e-12 and data.metadata["equalities"] == "auto"


def test_bundled_gripper_couplings():
    for name in ("panda_blocks", "vx300s_clutter"):
        robot = scene(name)
        q = profrobot.sample_poses(robot, 1000, seed=2)
        assert robot.couplings and robot.couplings.residual(q).max() <= 1e-12


def test_closed_linkage_warns_and_settles():
    """A closed linkage (connect equalities) warns once and offers settled sampling."""
    robot_cls = profrobot.Robot
    import profrobot.robot.robot as robot_module

    robot_module._WARNED.clear()
    with pytest.warns(EqualityWarning, match="connect equality.*equalities='settle'"):
        robot = robot_cls.from_menagerie("ufactory_xarm7", "xarm7")
    with warnings.catch_warnings():
        warnings.simplefilter("error", EqualityWarning)
        robot_cls.from_menagerie("ufactory_xarm7", "xarm7")  # once per process
    assert sum(e.closed_loop for e in robot.equalities) == 2
    free = profrobot.sample_poses(robot, 100, seed=0)
    assert equality_residual(robot.mj_model, free, robot.qpos_adr).max() > 1e-3
    settled = profrobot.sample_poses(robot, 100, seed=0, equalities="settle")
    assert equality_residual(robot.mj_model, settled, robot.qpos_adr).max() <= 1e-9
    lim = robot.joint_limits
    assert ((settled >= lim[:, 0] - 1e-9) | robot.continuous).all() and ((settled <= lim[:, 1] + 1e-9) | robot.continuous).all()
    np.testing.assert_array_equal(settled, profrobot.sample_poses(robot, 100, seed=0, equalities="settle", threads=1))
    with pytest.raises(ValueError, match="equalities must be one of"):
        profrobot.sample_poses(robot, 10, equalities="project")
