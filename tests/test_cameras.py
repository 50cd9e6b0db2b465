"""One camera model: OpenCV pinholes (fx != fy, off-centre principal point, roll, H != W) drawn by
MuJoCo exactly, checked against MuJoCo's own cameras and against projected points."""

import json
import pickle

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot import gl
from profrobot.errors import CorruptFileError, InputError
from profrobot.render import Cameras, make_views, ring_cameras, robot_visual_model
from profrobot.render.mjviews import MjViews

# A ball on a hinge arm, and two MJCF cameras: one fixed to the world with a fovy, one mounted on
# the moving body with calibrated intrinsics (focal/principal in pixels, a sensor, a resolution).
SCENE = """<mujoco><statistic extent="1" center="0 0 0.3"/><worldbody>
  <geom type="plane" size="1 1 .1" rgba=".2 .2 .2 1"/>
  <camera name="fixed" pos="0.9 -0.6 0.8" xyaxes="0.55 0.83 0 -0.4 0.27 0.87" fovy="50"/>
  <body name="arm" pos="0 0 0.3"><joint name="j" type="hinge" axis="0 0 1"/>
    <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" rgba="0.8 0.3 0.2 1"/>
    <geom type="sphere" pos="0.25 0.05 0.02" size="0.05" rgba="0 1 0 1"/>
    <geom type="box" pos="0.12 -0.1 0.05" size="0.04 0.02 0.06" rgba="0.2 0.3 1 1"/>
  </body>
  <body name="mount" pos="0 0 0.3"><joint name="k" type="hinge" axis="0 0 1"/>
    <geom type="sphere" size="0.01" pos="0 0 -0.2" rgba="1 1 1 1"/>
    <camera name="mounted" pos="-0.5 -0.6 0.4" xyaxes="0.77 -0.64 0 0.3 0.36 0.88"
            focalpixel="150 110" principalpixel="12 -9" resolution="160 96" sensorsize="0.0064 0.0048"/>
  </body>
</worldbody></mujoco>"""


@pytest.fixture(scope="module")
def scene():
    return profrobot.Robot.from_spec(mujoco.MjSpec.from_string(SCENE), name="cams")


def rolled_camera(width=120, height=90):
    """fx != fy, off-centre principal point, rolled 30 degrees about its axis, H != W."""
    eye, target = np.array([0.8, -0.7, 0.75]), np.array([0.1, 0.0, 0.3])
    base = Cameras.look_at(eye, target, width=width, height=height)
    a = np.deg2rad(30)
    roll = np.eye(4)
    roll[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    K = np.array([[140.0, 0, 47.3], [0, 105.0, 51.8], [0, 0, 1]])
    return Cameras.from_opencv(K, roll @ base.world_to_cam[0], width, height)


def own_render(robot, qpos, name, width, height):
    """MuJoCo's own drawing of its named camera (robot geoms only, like make_views)."""
    m = robot_visual_model(robot)
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_adr] = qpos
    mujoco.mj_kinematics(m, d)
    mujoco.mj_camlight(m, d)
    with gl.renderer(m, height, width) as r:
        r.update_scene(d, camera=name)
        rgb = r.render()
        r.enable_segmentation_rendering()
        seg = r.render()
    return rgb, seg[..., 0] >= 0


def test_free_camera_as_opencv_renders_the_same_pixels(scene, renderer):
    free = ring_cameras(3, size=40, distance=1.3, elevation=-30, lookat=(0.1, 0, 0.3)).resized(48, 36)
    calib = Cameras.from_opencv(free.K, free.world_to_cam, free.width, free.height)
    assert not calib.is_free and free.is_free
    q = np.array([[0.7, 0.0]])
    a, b = make_views(scene, q, free, progress=False), make_views(scene, q, calib, progress=False)
    assert a.mask.sum() > 80
    assert (a.mask != b.mask).mean() < 1e-3
    assert np.abs(a.rgb.astype(int) - b.rgb.astype(int)).max() <= 2
    np.testing.assert_allclose(a.depth, b.depth, atol=1e-4)


@pytest.mark.parametrize("name", ["fixed", "mounted"])
def test_from_mujoco_draws_what_mujoco_draws(scene, renderer, name):
    q = np.array([0.4, -0.8])        # the mounted camera has turned with its body
    cams = Cameras.from_mujoco(scene, name, q, width=160, height=96)
    rgb, mask = own_render(scene, q, name, 160, 96)
    v = make_views(scene, q[None], cams, progress=False)
    assert mask.sum() > 200, "the test scene must be in view"
    assert (v.mask[0, 0] != mask).mean() < 1e-3
    assert np.abs(v.rgb[0, 0].astype(int) - rgb.astype(int)).mean() < 0.5
    if name == "mounted":
        # focalpixel / principalpixel reach K (MuJoCo's principal offset is from the image centre, y up)
        K = cams.K[0]
        assert K[0, 0] == pytest.approx(150, rel=1e-4) and K[1, 1] == pytest.approx(110, rel=1e-4)
        assert abs(K[0, 2] - (80 - 0.5)) > 5 and abs(K[1, 2] - (48 - 0.5)) > 5
        other = Cameras.from_mujoco(scene, name, np.array([0.4, 0.3]), width=160, height=96)
        assert not np.allclose(other.world_to_cam, cams.world_to_cam)


def test_rolled_off_centre_camera_puts_points_where_K_says(scene, renderer):
    cams = rolled_camera()
    q = np.array([[0.3, 0.0]])
    v = make_views(scene, q, cams, progress=False)
    # the green ball's centre in the world, at this pose
    m = scene.mj_model
    d = mujoco.MjData(m)
    d.qpos[scene.qpos_adr] = q[0]
    mujoco.mj_kinematics(m, d)
    gid = [i for i in range(m.ngeom) if m.geom_rgba[i][1] == 1 and m.geom_rgba[i][0] == 0][0]
    centre = d.geom_xpos[gid]
    uv = cams.project(centre)[0, 0]
    r, g, b = np.moveaxis(v.rgb[0, 0].astype(int), -1, 0)
    green = (g > r + 15) & (g > b + 15) & v.mask[0, 0]
    ys, xs = np.nonzero(green)
    assert len(xs) > 50
    assert abs(xs.mean() - uv[0]) < 0.5 and abs(ys.mean() - uv[1]) < 0.5, (xs.mean(), ys.mean(), uv)
    z = (cams.world_to_cam[0] @ np.append(centre, 1))[2]
    assert v.depth[0, 0][green].min() == pytest.approx(z - 0.05, abs=5e-3)


def test_gl_frustum_and_from_gl_are_inverse():
    cams = rolled_camera()
    pos, fwd, up, fr = cams.gl_frustum(0, 0.01)
    back = Cameras.from_gl(pos, fwd, up, (*fr, 0.01), cams.width, cams.height)
    np.testing.assert_allclose(back.K, cams.K, atol=1e-9)
    np.testing.assert_allclose(back.world_to_cam, cams.world_to_cam, atol=1e-9)


def test_gl_camera_of_free_cameras_is_mujocos(scene):
    free = ring_cameras(2, size=30, distance=1.1, lookat=(0, 0, 0.3)).resized(30, 20)
    mv = MjViews(robot_visual_model(scene), free)
    for c in range(2):
        g = mv.gl_camera(c)
        half = 0.5 * 30 / 20 * (g.frustum_top - g.frustum_bottom)
        back = Cameras.from_gl(g.pos, g.forward, g.up, (g.frustum_center, half, g.frustum_bottom, g.frustum_top,
                                                       g.frustum_near), 30, 20)
        np.testing.assert_allclose(back.K[0], free.K[c], atol=1e-4)
        np.testing.assert_allclose(back.world_to_cam[0], free.world_to_cam[c], atol=1e-6)


def test_look_at_centres_the_target_and_keeps_up_up():
    cams = Cameras.look_at([[1, 0, 0.5], [0, 1.2, 1.0]], [0, 0, 0.3], width=64, height=48)
    uv = cams.project([0, 0, 0.3])
    np.testing.assert_allclose(uv[:, 0], [[31.5, 23.5]] * 2, atol=1e-9)
    above = cams.project([0, 0, 0.4])
    assert (above[:, 0, 1] < 23.5).all()         # higher in the world: higher in the image (smaller v)


def test_resized_keeps_pixel_edges():
    cams = rolled_camera(120, 90)
    half = cams.resized(60, 45)
    p = np.array([[0.1, 0.0, 0.35], [0.2, -0.1, 0.3]])
    a, b = cams.project(p)[0], half.project(p)[0]
    np.testing.assert_allclose((a + 0.5) * 0.5 - 0.5, b, atol=1e-9)


def test_json_pickle_and_earlier_files(tmp_path):
    cams = Cameras.from_opencv(np.diag([100.0, 90.0, 1.0]) + [[0, 0, 30], [0, 0, 20], [0, 0, 0]],
                               np.stack([np.eye(4), rolled_camera().world_to_cam[0]]), 64, 40,
                               distortion=[0.1, -0.05, 0.001, 0.0, 0.01])
    assert len(cams) == 2 and cams.distortion.shape == (2, 5)
    p = cams.save(tmp_path / "cams.json")
    assert Cameras.load(p) == cams and pickle.loads(pickle.dumps(cams)) == cams
    assert json.loads(p.read_text())["format"] == "profrobot.cameras/1"
    free = ring_cameras(2, size=16)
    assert Cameras.from_dict(json.loads(json.dumps(free.to_dict()))) == free
    old = dict(lookat=[[0, 0, 0.4]], distance=[1.8], azimuth=[0.0], elevation=[-20.0], width=16, height=16, fovy=45.0)
    assert Cameras.from_dict(old) == ring_cameras(1, size=16)
    with pytest.raises(InputError, match="world_to_cam.*Cameras.free"):   # free cameras: Cameras.free only
        Cameras(np.zeros((1, 3)) + [0, 0, 0.4], 1.8, 0.0, -20.0)
    with pytest.raises(InputError, match="Cameras.free"):
        Cameras(np.zeros((1, 3)) + [0, 0, 0.4], 1.8, 0.0, -20.0, 16, 16)
    with pytest.raises(InputError, match="'lookat'.*Cameras.free"):
        Cameras(lookat=[0, 0, 0.4], distance=1.8, azimuth=0.0, elevation=-20.0)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(CorruptFileError, match="bad.json"):
        Cameras.load(tmp_path / "bad.json")


@pytest.mark.parametrize("K, T, match", [
    (np.array([[100, 1, 30], [0, 100, 20], [0, 0, 1.0]]), np.eye(4), "no skew"),
    (np.diag([-100, 100, 1.0]), np.eye(4), "positive"),
    (np.eye(3), np.diag([1, 1, -1, 1.0]), "rotation"),
    (np.eye(3), np.full((4, 4), np.nan), r"world_to_cam\[0, 0, 0\] is nan"),
    (np.stack([np.eye(3)] * 2), np.stack([np.eye(4)] * 3), "give one K for all"),
])
def test_bad_cameras_are_refused_by_name(K, T, match):
    with pytest.raises(InputError, match=match):
        Cameras.from_opencv(K, T, 32, 24)


def test_distorted_cameras_are_not_rendered_as_pinholes(scene):
    cams = Cameras.from_opencv(np.diag([50.0, 50, 1]) + [[0, 0, 16], [0, 0, 12], [0, 0, 0]], rolled_camera().world_to_cam,
                               32, 24, distortion=[0.1, 0, 0, 0, 0])
    with pytest.raises(InputError, match="undistorted"):
        MjViews(robot_visual_model(scene), cams)
    assert MjViews(robot_visual_model(scene), cams.undistorted()).cams.distortion is None


def test_trajectory_pictures_take_a_calibrated_camera(scene, renderer):
    """Pictures use the same camera model: a free camera given as a dict, and the same camera
    given as OpenCV matrices, draw the same frames; a rolled calibrated camera draws too."""
    from profrobot.optim.pictures import trajectory_frames

    view = dict(lookat=(0.1, 0.0, 0.3), distance=1.2, azimuth=40.0, elevation=-30.0)
    fovy = float(scene.mj_model.vis.global_.fovy)
    free = Cameras.free([view["lookat"]], view["distance"], view["azimuth"], view["elevation"], 64, 48, fovy)
    calib = Cameras.from_opencv(free.K, free.world_to_cam, 64, 48)
    path = np.array([[0.0, 0.0], [0.8, 0.3]])
    no = np.zeros(2, bool)
    a = np.stack([np.asarray(f) for f in trajectory_frames(scene, path, no, (64, 48), view)])
    b = np.stack([np.asarray(f) for f in trajectory_frames(scene, path, no, (64, 48), calib)])
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 2 and a.std() > 1
    rolled = trajectory_frames(scene, path, no, (60, 45), rolled_camera())
    assert rolled[0].size == (60, 45)


def test_cameras_are_values_equal_hash_equal_and_forgive_rounded_calibrations(tmp_path):
    """Review findings pinned: inputs are copied (a caller's array cannot change a camera), -0.0
    and 0.0 hash alike, a rotation written with 5 decimals is accepted (and made exactly
    orthonormal), malformed JSON is a CorruptFileError, never a raw ValueError."""
    la = np.array([[0.0, 0.0, 0.4]])
    c = Cameras.free(la, 1.8, 0.0, -20.0, 16, 16)
    la[0, 0] = 5.0
    p = c.free_params
    p["fovy"], p["lookat"][0, 0] = 10.0, 7.0
    assert c.fovy == 45.0 and c.lookat[0, 0] == 0.0 and c == pickle.loads(pickle.dumps(c))
    T = np.eye(4)
    a, b = Cameras.from_opencv(np.eye(3), T, 8, 8), Cameras.from_opencv(np.eye(3), T * np.where(T == 0, -1.0, 1.0), 8, 8)
    assert a == b and hash(a) == hash(b)
    rounded = np.round(rolled_camera().world_to_cam[0], 5)
    cam = Cameras.from_opencv(np.diag([50.0, 50, 1]), rounded, 32, 24)
    R = cam.world_to_cam[0, :3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R, rounded[:3, :3], atol=1e-4)
    bad = dict(ring_cameras(1, size=16).to_dict())
    bad["free"] = dict(bad["free"], distance=[1.0, 2.0])
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(CorruptFileError, match="bad.json"):
        Cameras.load(tmp_path / "bad.json")


def test_from_mujoco_uses_the_mjcf_resolution(scene):
    xml = SCENE.replace('fovy="50"/>', 'fovy="50" resolution="40 30"/>')
    robot = profrobot.Robot.from_spec(mujoco.MjSpec.from_string(xml), name="cams")
    cams = Cameras.from_mujoco(robot, "fixed")
    assert (cams.width, cams.height) == (40, 30)
    with pytest.raises(InputError, match="width= and height="):
        Cameras.from_mujoco(scene, "fixed")
    with pytest.raises(InputError, match="no camera named 'nope'"):
        Cameras.from_mujoco(scene, ["fixed", "nope"], width=8, height=8)
