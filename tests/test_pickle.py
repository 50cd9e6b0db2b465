"""Objects that travel (issue 19): Robot, PoseSDF, GaussianRobot, Dataset, cameras, views and every
result type pickle (``pickle``, ``torch.save``, a spawned process) and deep-copy, and the copies
give the same labels, field values and gradients, renders and fingerprints. A pickled robot
carries its MJCF files, so ``with_obstacles`` works where they are not (``Robot.__getstate__``)."""

from __future__ import annotations

import collections
import copy
import dataclasses
import io
import multiprocessing
import pickle
import shutil

import mujoco
import numpy as np
import pytest
import torch

import profrobot
from profrobot import Box, Mesh, Robot, Sphere
from profrobot.exact import problems
from profrobot.errors import CorruptFileError, InputError, RobotMismatchError

PROTOCOLS = (2, pickle.HIGHEST_PROTOCOL)   # torch.save's default, and the newest

# Two mesh links; written to disk for from_mjcf (meshes in a folder, an included file), the
# numbers long enough that MjSpec.to_xml (6 significant digits) would not reproduce them.
MAIN_XML = """<mujoco model="two_bars">
  <compiler angle="radian" meshdir="meshes"/>
  <include file="parts.xml"/>
  <worldbody>
    <geom type="plane" size="1 1 .1"/>
    <body name="l1" pos="0 0 0.0512345678"><joint name="j1" type="hinge" axis="0 0 1" range="-3 3"/>
      <geom type="mesh" mesh="bar"/>
      <body name="l2" pos="0 0 0.3123456789" quat="0.9987654321 0.0123456789 0 0">
        <joint name="j2" type="hinge" axis="0 1 0" range="-2.123456789 2.123456789"/>
        <geom type="mesh" mesh="bar"/>
      </body>
    </body>
  </worldbody>
</mujoco>"""
PARTS_XML = '<mujoco><asset><mesh name="bar" file="bar.obj"/></asset></mujoco>'

ARM = """<mujoco><compiler angle="radian"/>
  <asset><mesh name="bar" vertex="-.04 -.04 0  .04 -.04 0  .04 .04 0  -.04 .04 0  -.04 -.04 .3  .04 -.04 .3  .04 .04 .3  -.04 .04 .3"/></asset>
  <worldbody>
    <geom type="plane" size="1 1 .1"/>
    <body name="l1" pos="0 0 0.05"><joint name="j1" type="hinge" axis="0 0 1" range="-3 3"/>
      <geom type="mesh" mesh="bar" rgba="0.1 0.1 0.1 1"/>
      <body name="l2" pos="0 0 0.3"><joint name="j2" type="hinge" axis="0 1 0" range="-2 2"/>
        <geom type="mesh" mesh="bar" rgba="0.2 0.6 0.9 1"/></body>
    </body>
  </worldbody></mujoco>"""

OBSTACLES = (Box(pos=(0.3, 0.0, 0.2), half_size=(0.05, 0.1, 0.2), name="crate"),
             Sphere(pos=(-0.25, 0.1, 0.4), radius=0.07),
             Mesh(pos=(0.0, -0.3, 0.3), vertices=np.random.default_rng(0).random((12, 3)) * 0.15, name="rock"))


def _box_obj(hx: float, hy: float, z0: float, z1: float) -> str:
    v = [(x, y, z) for z in (z0, z1) for x, y in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy))]
    f = [(1, 3, 2), (1, 4, 3), (5, 6, 7), (5, 7, 8), (1, 2, 6), (1, 6, 5), (2, 3, 7), (2, 7, 6),
         (3, 4, 8), (3, 8, 7), (4, 1, 5), (4, 5, 8)]
    return "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in v) + "".join(f"f {a} {b} {c}\n" for a, b, c in f)


def _write_model(folder) -> str:
    (folder / "meshes").mkdir(parents=True)
    (folder / "meshes" / "bar.obj").write_text(_box_obj(0.0412345678, 0.0398765432, 0.0, 0.30123456789))
    (folder / "parts.xml").write_text(PARTS_XML)
    (folder / "two_bars.xml").write_text(MAIN_XML)
    return str(folder / "two_bars.xml")


# ---- comparisons ---------------------------------------------------------------------------------

def same(a, b, path: str = "x") -> None:
    """``a`` and ``b`` equal to the bit: arrays and tensors byte for byte (NaN included),
    dataclasses and plain objects field by field, robots by everything that labels."""
    assert type(a) is type(b), f"{path}: {type(a).__name__} != {type(b).__name__}"
    if isinstance(a, Robot):
        same_robot(a, b)
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), path
    elif isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and a.shape == b.shape, path
        assert a.detach().cpu().numpy().tobytes() == b.detach().cpu().numpy().tobytes(), path
    elif dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            same(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
    elif isinstance(a, dict):
        assert list(a) == list(b), path
        for k in a:
            same(a[k], b[k], f"{path}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{path}[{i}]")
    elif isinstance(a, (float, np.floating)):
        assert a == b or (np.isnan(a) and np.isnan(b)), path
    elif isinstance(a, (str, bytes, int, bool, set, frozenset, np.integer, np.bool_, type(None))):
        assert a == b, path
    else:
        keys = vars(a) if hasattr(a, "__dict__") else [k for c in type(a).__mro__ for k in getattr(c, "__slots__", ())]
        for k in keys:
            same(getattr(a, k), getattr(b, k), f"{path}.{k}")


def same_robot(a: Robot, b: Robot) -> None:
    assert (a.fingerprint, a.name, repr(a)) == (b.fingerprint, b.name, repr(b))
    for key in ("joint_names", "joint_types", "qpos_adr", "continuous", "joint_parents", "body_names",
                "equalities", "tendons", "pair_geoms", "pair_is_self", "pair_margin", "joint_limits"):
        same(getattr(a, key), getattr(b, key), key)
    same(a.core_arrays(), b.core_arrays(), "core_arrays")
    same(a.couplings.rows, b.couplings.rows, "couplings")


def model_diff(m1: mujoco.MjModel, m2: mujoco.MjModel) -> list[str]:
    """Names of the compiled-model arrays that differ (bytes)."""
    out = []
    for name in dir(m1):
        if name.startswith("_"):
            continue
        try:
            a = getattr(m1, name)
        except Exception:
            continue
        if isinstance(a, np.ndarray):
            b = getattr(m2, name)
            if a.shape != b.shape or a.tobytes() != b.tobytes():
                out.append(name)
    return out


def same_labels(robot: Robot, other: Robot, poses: np.ndarray) -> None:
    same(profrobot.label_poses(robot, poses), profrobot.label_poses(other, poses))
    same(profrobot.label_poses(robot, poses[:50], pairs=True, distance=True),
         profrobot.label_poses(other, poses[:50], pairs=True, distance=True))
    same(profrobot.collides(robot, poses), profrobot.collides(other, poses))


def copies(x):
    """``x`` through pickle (each protocol) and deepcopy: the copies, all checked equal to ``x``."""
    out = [pickle.loads(pickle.dumps(x, protocol=p)) for p in PROTOCOLS] + [copy.deepcopy(x)]
    for y in out:
        same(x, y)
    return out


# ---- fixtures ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def arm():
    return Robot.from_spec(mujoco.MjSpec.from_string(ARM), name="arm")


@pytest.fixture(scope="module")
def panda_poses(panda):
    return profrobot.sample_poses(panda, 3000, seed=5)


@pytest.fixture(scope="module")
def panda_sdf(panda):
    torch.manual_seed(0)
    return profrobot.PoseSDF(panda, hidden=(32, 32))


@pytest.fixture(scope="module")
def splats(panda):
    torch.manual_seed(0)
    return profrobot.render.GaussianRobot.from_robot(panda, n=400, seed=0)


# ---- Robot ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_robot_pickle_labels_byte_identical(panda, panda_poses, protocol):
    data = pickle.dumps(panda, protocol=protocol)
    assert len(data) < 12e6          # the Panda's mesh files, compressed (no compiled model)
    back = pickle.loads(data)
    same_robot(panda, back)
    same_labels(panda, back, panda_poses)
    again = pickle.dumps(back, protocol=protocol)        # passed on as it came: no file read, no compile
    assert back._mj_model is None and abs(len(again) - len(data)) < 1e4
    same_robot(panda, pickle.loads(again))


def test_robot_pickle_rebuilds_the_same_mujoco_model_and_obstacles_work(panda, panda_poses):
    back = pickle.loads(pickle.dumps(panda))
    assert back._mj_model is None                          # left out: the source compiles it again
    assert model_diff(panda.mj_model, back.mj_model) == []
    want, got = panda.with_obstacles(OBSTACLES, name="more"), back.with_obstacles(OBSTACLES, name="more")
    same_robot(want, got)
    assert model_diff(want.mj_model, got.mj_model) == []
    same_labels(want, got, panda_poses[:500])
    same_robot(want, pickle.loads(pickle.dumps(got)))     # a derived robot travels too


def test_robot_deepcopy_is_an_independent_equal_robot(panda, panda_poses):
    twin = copy.deepcopy(panda)
    same_robot(panda, twin)
    same_labels(panda, twin, panda_poses[:500])
    assert twin.mj_model is not panda.mj_model and model_diff(panda.mj_model, twin.mj_model) == []
    assert twin.spec is not panda.spec
    same_robot(panda.with_obstacles(OBSTACLES[:1]), twin.with_obstacles(OBSTACLES[:1]))
    shallow = copy.copy(panda)                            # cheap: shares everything
    assert shallow.core is panda.core and shallow.mj_model is panda.mj_model
    copies(panda.equalities)
    copies(panda.tendons)


def test_from_mjcf_robot_carries_its_files(tmp_path):
    path = _write_model(tmp_path / "model")
    robot = Robot.from_mjcf(path)
    want = robot.with_obstacles(OBSTACLES)
    more = [Sphere(pos=(0.1, 0.2, 0.6), radius=0.05)]
    want_more = want.with_obstacles(more)                 # the originals read their files from disk
    data = pickle.dumps(robot)
    shutil.rmtree(tmp_path / "model")                     # the pickle needs no file any more
    back = pickle.loads(data)
    same_robot(robot, back)
    assert model_diff(robot.mj_model, back.mj_model) == []
    got = back.with_obstacles(OBSTACLES)
    same_robot(want, got)
    poses = profrobot.sample_poses(robot, 2000, seed=1)
    same_labels(want, got, poses)
    assert profrobot.collides(want, poses).any() and not profrobot.collides(want, poses).all()
    # derived robots travel too (their obstacles with them), and derive the same again
    again = pickle.loads(pickle.dumps(got))
    same_robot(want, again)
    same_robot(want_more, again.with_obstacles(more))
    assert model_diff(want_more.mj_model, pickle.loads(pickle.dumps(again.with_obstacles(more))).mj_model) == []


def test_from_spec_and_from_model_robots(tmp_path, arm):
    poses = profrobot.sample_poses(arm, 1000, seed=2)
    for back in copies(arm):
        same_labels(arm, back, poses)
        assert model_diff(arm.mj_model, back.mj_model) == []
        same_robot(arm.with_obstacles(OBSTACLES), back.with_obstacles(OBSTACLES))

    # a from_spec spec that MjSpec.to_xml (6 significant digits) does not reproduce: labels and the
    # compiled model travel exactly (the model is carried); obstacles refuse, saying why
    lossy = Robot.from_spec(mujoco.MjSpec.from_file(_write_model(tmp_path / "lossy")), name="lossy")
    back = pickle.loads(pickle.dumps(lossy))
    same_labels(lossy, back, profrobot.sample_poses(lossy, 500, seed=0))
    assert model_diff(lossy.mj_model, back.mj_model) == []
    with pytest.raises(RobotMismatchError, match="to_xml"):
        back.with_obstacles(OBSTACLES)

    model = Robot.from_model(mujoco.MjModel.from_xml_string(ARM), name="compiled")
    for back in copies(model):
        same_labels(model, back, poses)
        assert back.spec is None and model_diff(model.mj_model, back.mj_model) == []
        with pytest.raises(InputError, match="from_model"):
            back.with_obstacles(OBSTACLES)


def test_robot_state_of_another_format_is_refused():
    robot = Robot.__new__(Robot)
    with pytest.raises(CorruptFileError, match="profrobot.Robot/1"):
        robot.__setstate__({"format": "profrobot.Robot/0"})


def test_robot_through_a_spawned_process(tmp_path, panda, panda_poses):
    path = _write_model(tmp_path / "model")
    bars = Robot.from_mjcf(path)
    want = bars.with_obstacles(OBSTACLES)
    pickle.dumps(bars)                                    # reads the files once, kept with the robot
    shutil.rmtree(tmp_path / "model")
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(1) as pool:
        same(profrobot.label_poses(panda, panda_poses), pool.apply(profrobot.label_poses, (panda, panda_poses)))
        same(profrobot.collides(panda, panda_poses), pool.apply(profrobot.collides, (panda, panda_poses)))
        assert pool.apply(getattr, (panda, "fingerprint")) == panda.fingerprint
        same_robot(want, pool.apply(Robot.with_obstacles, (bars, OBSTACLES)))


# ---- torch modules -------------------------------------------------------------------------------

def _g_and_grad(sdf, theta: torch.Tensor):
    theta = theta.clone().requires_grad_()
    g = sdf(theta)
    (grad,) = torch.autograd.grad(g.sum(), theta)
    return g.detach(), grad


def test_pose_sdf_pickle_torch_save_deepcopy(panda, panda_sdf, panda_poses):
    sdf = panda_sdf
    sdf.metrics = dict(accuracy=0.5)
    theta = torch.as_tensor(panda_poses[:64], dtype=torch.float32)
    g, grad = _g_and_grad(sdf, theta)
    buf = io.BytesIO()
    torch.save(sdf, buf)
    assert buf.tell() < 20e6
    buf.seek(0)
    loaded = torch.load(buf, weights_only=False)
    twins = [pickle.loads(pickle.dumps(sdf, protocol=p)) for p in PROTOCOLS] + [loaded, copy.deepcopy(sdf)]
    for twin in twins:
        g2, grad2 = _g_and_grad(twin, theta)
        same((g, grad), (g2, grad2))
        same(sdf.state_dict(), twin.state_dict())
        assert (twin.config, twin.metrics, twin.fingerprint) == (sdf.config, sdf.metrics, sdf.fingerprint)
        same_robot(sdf.robot, twin.robot)
    assert twins[-1].robot is sdf.robot                   # deepcopy shares the immutable robot
    same_labels(panda, loaded.robot, panda_poses[:200])


@pytest.mark.parametrize("options", [dict(encoder="hierarchical", lipschitz=True), dict(objective="ndf")])
def test_pose_sdf_variants(arm, options):
    torch.manual_seed(0)
    sdf = profrobot.PoseSDF(arm, hidden=(16, 16), **options)
    theta = torch.as_tensor(profrobot.sample_poses(arm, 32, seed=0), dtype=torch.float32)
    want = _g_and_grad(sdf, theta)
    for twin in [pickle.loads(pickle.dumps(sdf, protocol=p)) for p in (0, *PROTOCOLS)] + [copy.deepcopy(sdf)]:
        same(want, _g_and_grad(twin, theta))


@pytest.mark.parametrize("skinning", ["rigid", "lbs"])
def test_gaussian_robot_pickle_torch_save_deepcopy(panda, panda_poses, splats, skinning):
    from profrobot.render import GaussianRobot, ring_cameras

    torch.manual_seed(0)
    model = splats if skinning == "rigid" else GaussianRobot.from_robot(panda, n=300, skinning="lbs", seed=1)
    cams = ring_cameras(2, size=24)
    theta = torch.as_tensor(panda_poses[:2], dtype=torch.float32)
    with torch.no_grad():
        want = model.render_views(theta, cams)
    buf = io.BytesIO()
    torch.save(model, buf)
    buf.seek(0)
    twins = [pickle.loads(pickle.dumps(model, protocol=p)) for p in PROTOCOLS]
    twins += [torch.load(buf, weights_only=False), copy.deepcopy(model)]
    for twin in twins:
        with torch.no_grad():
            same(want, twin.render_views(theta, cams))
        same(model.state_dict(), twin.state_dict())
        assert (twin.fingerprint, twin.skinning, twin.n) == (model.fingerprint, model.skinning, model.n)
    copies(want)                                          # RenderOut


# ---- data, cameras, views ------------------------------------------------------------------------

def test_dataset_and_cameras(panda):
    from profrobot.render import ring_cameras

    data = profrobot.make_dataset(panda, 200, batch=2000, progress=False)
    for back in copies(data):
        assert back.metadata["robot_fingerprint"] == panda.fingerprint and len(back) == 200
    copies(data.split(0.2)[1])
    copies(ring_cameras(3, size=16))


def test_views(arm, renderer):
    from profrobot.render import make_views, ring_cameras

    views = make_views(arm, np.array([[0.0, 0.3], [0.5, -0.4]]), ring_cameras(2, size=16, distance=1.2,
                                                                              lookat=(0, 0, 0.3)), progress=False)
    assert views.mask.any()
    copies(views)


# ---- result types --------------------------------------------------------------------------------

def test_labelling_results(panda, panda_poses):
    copies(profrobot.label_poses(panda, panda_poses[:200], pairs=True, distance=True))
    report = profrobot.crosscheck(panda, panda_poses[:60])
    copies(report)                                        # with its MujocoLabels and Labels
    copies(report.reference)
    hit = panda_poses[profrobot.collides(panda, panda_poses)][:3]
    copies(profrobot.nearest_free(panda, hit, directions=16, refine=32))


def test_planning_results(panda):
    from profrobot.exact.certification import check_path

    start, goal = problems.free_poses(panda, 2, seed=1)
    found = profrobot.plan_path(panda, start, goal, max_time=2.0, seed=0)
    copies(found)
    if found.found:
        copies(check_path(panda, found.path))
    traj = profrobot.plan_trajectory(None, start, goal, steps=20, robot=panda)
    copies(traj)                                          # with its PathCheck (and PathResult)
    copies(check_path(panda, profrobot.interpolate(panda, start, goal, steps=10)))


def test_field_results(panda, panda_sdf):
    from profrobot.field.train import TrainConfig
    from profrobot.optim.paths import PenaltyOptions, TangentOptions

    colliding = problems.colliding_poses(panda, 3, seed=2)
    copies(profrobot.resolve(panda_sdf, colliding, iterations=3))
    theta = torch.as_tensor(colliding, dtype=torch.float32)
    copies(panda_sdf.encoder.kin(theta))                  # BodyPoses
    for options in (TrainConfig(iterations=3), PenaltyOptions(), TangentOptions()):
        copies(options)


def test_executor_run_stats():
    from profrobot.executors.ray_cluster import RunStats

    copies(RunStats(chunks=3, submitted=4, retries=1, placed=collections.Counter({0: 1, 1: 1, 2: 1})))


def test_image_results(arm):
    from profrobot.inverse import pose_from_images, pose_from_text
    from profrobot.render import GaussianRobot, fit_pose, ring_cameras
    from profrobot.render.targets import ImageTargets
    from profrobot.inverse.scorers import ImageGoalScorer

    torch.manual_seed(0)
    model = GaussianRobot.from_robot(arm, 300, seed=0)
    cams = ring_cameras(2, size=24, distance=1.4, lookat=(0, 0, 0.3))
    target = np.array([[0.3, 0.5]])
    with torch.no_grad():
        out = model.render_views(torch.as_tensor(target, dtype=torch.float32), cams)
    t = dict(rgb=out.rgb.reshape(1, 2, 24, 24, 3).numpy(), depth=out.depth.reshape(1, 2, 24, 24).numpy(),
             mask=(out.alpha > 0.5).reshape(1, 2, 24, 24).numpy())
    copies(ImageTargets.from_images(t, cams, 1))
    copies(fit_pose(model, t, cams, target + 0.05, iterations=2))                         # PoseFit
    copies(pose_from_images(model, t, cams, init=target + 0.05, image_iterations=2, robot=arm))  # InverseResult
    torch.manual_seed(0)
    sdf = profrobot.PoseSDF(arm, hidden=(16,))
    copies(pose_from_images(model, t, cams, init=target + 0.05, image_iterations=2, sdf=sdf,
                            field_iterations=2))
    cam = ring_cameras(1, size=24, distance=1.4, lookat=(0, 0, 0.3))
    scorer = ImageGoalScorer(out.rgb[0].numpy(), size=8)
    copies(pose_from_text(model, "bent", scorer, camera=cam, init=[0.0, 0.6], iterations=3, robot=arm))  # TextResult


@pytest.mark.parametrize("name", ["_Mjcf", "_SpecSource", "RobotLoading"])
def test_a_robot_file_from_before_0_1_0_is_refused_naming_the_version(name, tmp_path):
    """Before 0.1.0 a pickle named these classes in ``profrobot.robot``'s old module; a robot file
    that does is refused with a ProfrobotError saying it was written before 0.1.0 (no shims)."""
    from profrobot.robot.file import _RobotUnpickler

    data = b"\x80\x02cprofrobot.robot\n" + name.encode() + b"\n."
    with pytest.raises(CorruptFileError, match=r"written by another profrobot \(one before 0\.1\.0"):
        _RobotUnpickler(io.BytesIO(data), "old.pkl").load()
    old = tmp_path / "old.pkl"
    old.write_bytes(data)
    with pytest.raises(CorruptFileError, match=r"before 0\.1\.0"):
        profrobot.Robot.load(old)


def test_every_robot_methods_annotations_resolve():
    """``Robot``'s methods are its own (composition: they call functions of robot/loading.py,
    layouts.py and state.py); ``typing.get_type_hints`` resolves every one's annotations
    (documentation tools and runtime type checkers call it)."""
    import typing

    checked = 0
    for name in dir(Robot):
        f = getattr(Robot, name)
        if callable(f) and getattr(f, "__annotations__", None) and getattr(f, "__module__", "").startswith("profrobot"):
            typing.get_type_hints(f)
            checked += 1
    assert checked > 20
    assert typing.get_type_hints(Robot.at)["return"] is Robot
