"""MuJoCo multi-view data: cameras that match MuJoCo's pixels, masks, depth, saved datasets."""

import copy
import pickle

import numpy as np
import pytest

import profrobot
from profrobot.render import Cameras, Views, make_views, ring_cameras, robot_visual_model, sphere_cameras
from profrobot.render.mjviews import MjViews

# A ball on a hinge: its projected centre must land where Cameras.K @ world_to_cam puts it.
BALL = """<mujoco><statistic extent="1" center="0 0 0.3"/><worldbody>
  <geom type="plane" size="1 1 .1" rgba=".2 .2 .2 1"/>
  <body pos="0.1 0.05 0.3"><joint name="j" type="hinge"/><geom type="sphere" size="0.04" rgba="0 1 0 1"/></body>
</worldbody></mujoco>"""


@pytest.fixture(scope="module")
def ball():
    import mujoco
    return profrobot.Robot.from_spec(mujoco.MjSpec.from_string(BALL), name="ball")


def test_cameras_match_mujoco_gl_camera(ball):
    cams = sphere_cameras(5, size=32, seed=3)
    mv = MjViews(robot_visual_model(ball), cams)
    pos, fwd, up = cams.frames()
    for c in range(len(cams)):
        g = mv.gl_camera(c)
        np.testing.assert_allclose(g.pos, pos[c], atol=1e-6)
        np.testing.assert_allclose(g.forward, fwd[c], atol=1e-6)
        np.testing.assert_allclose(g.up, up[c], atol=1e-6)
        assert g.frustum_top / g.frustum_near == pytest.approx(np.tan(np.deg2rad(cams.fovy) / 2), rel=1e-6)
    mv.close()


def test_projection_matches_pixels_and_depth(ball, renderer):
    cams = Cameras.free(np.tile([0, 0, 0.3], (4, 1)), 1.0, [0, 77, 200, 300], [0, -33, 10, 40], width=192, height=144)
    v = make_views(ball, np.zeros((1, 1)), cams, progress=False)
    centre = np.array([0.1, 0.05, 0.3, 1.0])
    for c in range(len(cams)):
        pc = cams.world_to_cam[c] @ centre
        uv = (cams.K[c] @ pc[:3])[:2] / pc[2]
        ys, xs = np.nonzero(v.mask[0, c])
        # the silhouette's centroid is the projected centre up to pixel quantisation (< 0.2 px
        # here); a wrong half-pixel convention would be off by 0.5 px
        assert abs(xs.mean() - uv[0]) < 0.25 and abs(ys.mean() - uv[1]) < 0.25, (c, xs.mean(), ys.mean(), uv)
        # metric depth along the camera axis: the nearest surface point is z - r
        assert v.depth[0, c][v.mask[0, c]].min() == pytest.approx(pc[2] - 0.04, abs=2e-3)
    assert not v.mask[0][v.depth[0] == 0].any()     # floor (a world geom) is not drawn nor masked
    assert v.rgb.dtype == np.uint8 and v.rgb.shape == (1, 4, 144, 192, 3)


def test_views_save_load_roundtrip_and_robot_check(ball, panda, tmp_path, renderer):
    v = make_views(ball, np.array([[0.0], [0.5]]), ring_cameras(3, size=16, distance=1.0, lookat=(0, 0, .3)), progress=False)
    p = tmp_path / "v.npz"
    v.save(p)
    w = Views.load(p, robot=ball)
    assert (w.rgb == v.rgb).all() and (w.mask == v.mask).all() and np.allclose(w.depth, v.depth)
    assert w.cameras.to_dict() == v.cameras.to_dict() and np.allclose(w.background, v.background)
    with pytest.raises(profrobot.RobotMismatchError, match="made for robot 'ball'"):
        Views.load(p, robot=panda)
    p.write_bytes(b"not a dataset")
    with pytest.raises(ValueError, match="not a readable"):
        Views.load(p)


@pytest.mark.slow  # spawns two worker processes (each imports mujoco and torch)
def test_parallel_matches_serial(ball, renderer):
    poses = np.linspace(-1, 1, 4)[:, None]
    cams = ring_cameras(2, size=16, distance=1.0, lookat=(0, 0, .3))
    a = make_views(ball, poses, cams, progress=False)
    b = make_views(ball, poses, cams, progress=False, processes=2, chunk=2)
    assert (a.rgb == b.rgb).all() and (a.mask == b.mask).all()


def test_bad_input(ball):
    cams = ring_cameras(2, size=16)
    with pytest.raises(ValueError, match="shape"):
        make_views(ball, np.zeros((2, 3)), cams, progress=False)
    with pytest.raises(ValueError, match="NaN"):
        make_views(ball, np.full((1, 1), np.nan), cams, progress=False)
    with pytest.raises(TypeError):
        make_views(ball, np.zeros((1, 1)), "front", progress=False)
    with pytest.raises(ValueError, match="distance"):
        Cameras.free(np.zeros((1, 3)), -1.0, 0.0, 0.0)


def test_cameras_and_views_pickle_and_deepcopy(ball, renderer):
    cams = sphere_cameras(3, size=16, seed=1, jitter=0.05).resized(20, 12)
    for other in (pickle.loads(pickle.dumps(cams)), copy.deepcopy(cams), copy.copy(cams)):
        assert other == cams and hash(other) == hash(cams) and other.to_dict() == cams.to_dict()
        assert (other.width, other.height) == (20, 12) and np.array_equal(other.world_to_cam, cams.world_to_cam)
    assert cams != cams.resized(16) and cams != "cams"
    v = make_views(ball, np.array([[0.0], [0.4]]), ring_cameras(2, size=12, distance=1.0, lookat=(0, 0, .3)),
                   progress=False)
    for w in (pickle.loads(pickle.dumps(v)), copy.deepcopy(v)):
        assert w.cameras == v.cameras and w.metadata == v.metadata and w.metadata is not v.metadata
        assert (w.fingerprint, w.robot_name) == (v.fingerprint, v.robot_name)
        for k in ("poses", "rgb", "depth", "mask"):
            a, b = getattr(w, k), getattr(v, k)
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes() and a is not b
