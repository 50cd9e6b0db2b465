"""The one gate (profrobot.robot.gate): every exact entry point that takes a robot takes the same
``layout=`` and ``margin=`` keywords and means the same by them; a family at a layout works in each
and answers as the family pinned there (``robot.at(layout)``); a family without a layout, where one
scene is needed, is refused with one message."""

from __future__ import annotations

import inspect
import typing

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot.exact import problems

ENTRY_POINTS = [profrobot.label_poses, profrobot.collides, profrobot.sample_poses, profrobot.interpolate,
                profrobot.certify_poses, profrobot.certify_motions, profrobot.check_path, profrobot.plan_path,
                profrobot.nearest_free, profrobot.ik, profrobot.plan_to_pose, profrobot.crosscheck,
                profrobot.mujoco_labels, profrobot.make_dataset, problems.colliding_poses, problems.free_poses,
                problems.hard_pairs]
#: the torch side's entry points (a field first; the robot is ``robot=``): the same two keywords
FIELD_ENTRY_POINTS = ["resolve", "plan_trajectory", "pose_from_images", "trajectory_from_images", "pose_from_text",
                      "actions_from_video"]


@pytest.mark.parametrize("fn", ENTRY_POINTS + FIELD_ENTRY_POINTS, ids=lambda f: getattr(f, "__name__", f))
def test_every_entry_point_takes_layout_and_margin_by_keyword(fn):
    fn = getattr(profrobot, fn) if isinstance(fn, str) else fn
    params = inspect.signature(fn).parameters
    for name in ("layout", "margin"):
        assert name in params and params[name].kind is inspect.Parameter.KEYWORD_ONLY, (fn.__name__, name)
    assert params["layout"].default is None
    assert params["margin"].default == profrobot.CLEARANCE
    # the annotations resolve at run time (documentation tools and runtime checkers call this):
    # the Layout alias is a real type, not a string
    hints = typing.get_type_hints(fn)
    assert type(None) in typing.get_args(hints["layout"]) and dict[str, float] != hints["layout"]


@pytest.fixture(scope="module")
def family():
    return profrobot.scenes.load("panda_blocks_moving")


@pytest.fixture(scope="module")
def at(family):
    return np.zeros(len(family.scene_joints))


def test_a_family_at_a_layout_answers_as_the_family_pinned_there(family, at):
    pinned = family.at(at)
    theta = profrobot.sample_poses(family, 200, seed=1, layout=at)
    assert theta.shape == (200, len(family.robot_index))
    np.testing.assert_array_equal(theta, profrobot.sample_poses(pinned, 200, seed=1))
    np.testing.assert_array_equal(profrobot.collides(family, theta, layout=at), profrobot.collides(pinned, theta))
    np.testing.assert_array_equal(profrobot.label_poses(family, theta, layout=at).collides,
                                  profrobot.label_poses(pinned, theta).collides)
    np.testing.assert_array_equal(profrobot.certify_poses(family, theta, layout=at),
                                  profrobot.certify_poses(pinned, theta))
    a, b = problems.free_poses(pinned, 2, seed=3)
    np.testing.assert_array_equal(profrobot.interpolate(family, a, b, 5, layout=at), profrobot.interpolate(pinned, a, b, 5))
    assert profrobot.certify_motions(family, a[None], b[None], layout=at).certified[0] == \
        profrobot.certify_motions(pinned, a[None], b[None]).certified[0]
    res = profrobot.plan_path(family, a, b, layout=at, seed=2, max_time=20)
    assert res.found and res.certified
    assert profrobot.check_path(family, res.path, layout=at).certified
    hit = problems.colliding_poses(pinned, 2, seed=4)
    near = profrobot.nearest_free(family, hit, layout=at, seed=0)
    np.testing.assert_array_equal(near.poses, profrobot.nearest_free(pinned, hit, seed=0).poses)
    np.testing.assert_array_equal(problems.colliding_poses(family, 2, seed=4, layout=at), hit)
    np.testing.assert_array_equal(profrobot.make_dataset(family, 20, seed=1, layout=at, progress=False).poses,
                                  profrobot.make_dataset(pinned, 20, seed=1, progress=False).poses)
    s2, g2 = problems.hard_pairs(family, 1, seed=6, layout=at)
    s1, g1 = problems.hard_pairs(pinned, 1, seed=6)
    np.testing.assert_array_equal(s2, s1)
    np.testing.assert_array_equal(g2, g1)
    m = pinned.mj_model
    d = mujoco.MjData(m)
    d.qpos[pinned.qpos_adr] = b
    mujoco.mj_kinematics(m, d)
    target = d.body("hand").xpos.copy()
    motion = profrobot.plan_to_pose(family, a, target, frame="hand", layout=at)
    assert motion.certified and motion.outcome == "certified"
    np.testing.assert_array_equal(motion.goal, profrobot.plan_to_pose(pinned, a, target, frame="hand").goal)
    assert profrobot.check_path(pinned, motion.path).certified
    report = profrobot.crosscheck(family, theta[:50], layout=at, progress=False)
    assert report.summary() == profrobot.crosscheck(pinned, theta[:50], progress=False).summary()


def test_a_family_without_a_layout_is_refused_with_one_message(family):
    a, b = problems.free_poses(family.at(np.zeros(len(family.scene_joints))), 2, seed=5)
    message = r"is a family of scenes .*: pass layout=δ, the layout to work at, or pin it first, robot.at\(δ\)"
    with pytest.raises(profrobot.InputError, match=message):
        profrobot.plan_path(family, a, b)
    with pytest.raises(profrobot.InputError, match=message):
        profrobot.nearest_free(family, a)
    with pytest.raises(profrobot.InputError, match=message):
        profrobot.plan_to_pose(family, a, np.array([0.4, 0.0, 0.4]), frame="hand")


def test_a_layout_for_a_robot_that_is_no_family_is_refused_everywhere():
    robot = profrobot.scenes.load("panda_blocks")
    q = profrobot.sample_poses(robot, 2, seed=0)
    for call in (lambda: profrobot.collides(robot, q, layout=[0.0]),
                 lambda: profrobot.plan_path(robot, q[0], q[1], layout=[0.0]),
                 lambda: profrobot.sample_poses(robot, 2, layout=[0.0])):
        with pytest.raises(profrobot.InputError, match="layout= is a layout of a family of scenes"):
            call()


def test_margin_means_the_same_everywhere():
    """The labeller, the fast path and the certificate agree at every margin, and a larger margin
    puts more free poses in contact (none of them leaves contact)."""
    robot = profrobot.scenes.load("panda_blocks")
    q = problems.free_poses(robot, 400, seed=6)
    before = np.zeros(len(q), dtype=bool)
    for m in (0.02, 0.05):
        labels = profrobot.label_poses(robot, q, margin=m)
        np.testing.assert_array_equal(labels.collides, profrobot.collides(robot, q, margin=m))
        assert not (profrobot.certify_poses(robot, q, margin=m) & labels.collides).any()
        assert (labels.collides >= before).all()
        before = labels.collides
    assert before.any()
    with pytest.raises(profrobot.InputError, match="margin"):
        profrobot.collides(robot, q, margin=-1.0)


# ---- the table: every public function that takes a robot -----------------------------------------

#: Where a gate keyword means nothing, the reason (the closing note's and the docs' table is made
#: from this and the signatures). Every other public function that takes a robot takes both.
NOT_APPLICABLE: dict[str, dict[str, str]] = {
    "make_views": {"margin": "the renderer draws the robot as modelled; a margin widens obstacles for exact answers"},
    "render_depth": {"margin": "the renderer draws the scene as modelled"},
    "cloud_from_depth": {"margin": "padding= is the self-filter's; a margin is given to the answers about the cloud"},
    "estimate_layout": {"layout": "the layout is what it estimates (a family is required)",
                        "margin": "it suggests one (LayoutEstimate.margin)"},
    "train_sdf": {"layout": "the field learns what its dataset holds: make_dataset(..., layout=) and pass that",
                  "margin": "likewise: make_dataset(..., margin=)"},
    "robot_visual_model": {"layout": "a model, no poses", "margin": "a model, no poses"},
    "Kinematics.from_robot": {"layout": "FK of every joint the robot has (a family's θ and δ)",
                              "margin": "FK only"},
    "GaussianRobot.from_robot": {"layout": "the robot's bodies only", "margin": "rendering"},
    "LayoutEstimate.robot": {"layout": "the estimate's own layout", "margin": "the estimate's own margin"},
    "LayoutEstimate.picture": {"layout": "the estimate's own layout", "margin": "a picture"},
    "RayExecutor.worker_pids": {"layout": "no poses", "margin": "no poses"},
}
#: an executor runs chunk functions on the robot an entry point has already passed through the gate
NOT_APPLICABLE.update({f"{e}.{m}": {"layout": "given to the entry point that fills the executor",
                                    "margin": "given to the entry point that fills the executor"}
                       for e in ("Executor", "LocalExecutor", "RayExecutor") for m in ("map", "ordered")})
#: loaders: ``robot=`` is the robot the file must have been written for (its fingerprint is checked)
LOADERS = {"Dataset.load", "PoseSDF.load", "GaussianRobot.load", "Views.load", "TimedPath.load"}


def _public_functions_taking_a_robot():
    import importlib
    import pkgutil

    packages = ["profrobot"] + [m.name for m in pkgutil.iter_modules(profrobot.__path__, "profrobot.") if m.ispkg]
    found = {}
    for package in packages:
        if package == "profrobot.cli":
            continue   # the command line's own helpers take parsed arguments
        mod = importlib.import_module(package)
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name)
            members = [(name, obj)] if inspect.isfunction(obj) else \
                [(f"{name}.{k}", getattr(v, "__func__", v)) for k, v in vars(obj).items()
                 if not k.startswith("_") and (inspect.isfunction(v) or isinstance(v, (classmethod, staticmethod)))] \
                if inspect.isclass(obj) else []
            for label, fn in members:
                params = inspect.signature(fn).parameters
                if {"robot", "family"} & set(params):
                    found[label] = params
    return found


def test_the_table_of_every_public_function_that_takes_a_robot():
    found = _public_functions_taking_a_robot()
    assert len(found) >= 30, sorted(found)   # the 25 entry points and the rest: the table is not empty
    for label, params in found.items():
        if label in LOADERS:
            continue
        for keyword in ("layout", "margin"):
            if keyword in NOT_APPLICABLE.get(label, {}):
                assert keyword not in params, f"{label} takes {keyword}=: drop it from NOT_APPLICABLE"
                continue
            assert keyword in params, f"{label} takes a robot but no {keyword}= (the gate's keyword)"
            assert params[keyword].kind is inspect.Parameter.KEYWORD_ONLY, (label, keyword)
            assert params[keyword].default == (None if keyword == "layout" else profrobot.CLEARANCE), (label, keyword)
    assert not set(NOT_APPLICABLE) - set(found), f"not public or takes no robot: {set(NOT_APPLICABLE) - set(found)}"
    # the architecture page's table is this one (regenerate it from these signatures when it moves)
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "architecture.md").read_text()
    for label, params in found.items():
        row = next((line for line in page.splitlines() if line.startswith(f"| `{label}` |")), None)
        assert row is not None, f"{label} has no row in docs/architecture.md's table of the gate"
        cells = [c.strip() for c in row.split("|")[2:4]]
        if label not in LOADERS:
            assert cells == ["✓" if k in params else "—" for k in ("layout", "margin")], (label, cells)


def test_a_family_at_a_layout_in_the_cloud_and_the_slice(family, at):
    """cloud_from_depth's self-filter and sdf_slice's outline: a family at a layout is the family
    pinned there, and the field is asked at the full poses."""
    from profrobot.perception.clouds.depth import self_filter
    from profrobot.render import Cameras
    from profrobot.viz import sdf_slice

    pinned = family.at(at)
    theta = problems.free_poses(pinned, 1, seed=2)[0]
    cams = Cameras.look_at([[1.6, 0.2, 1.0]], [[0.3, 0.0, 0.4]], fovy=50.0, width=40, height=30)
    depth = np.full((1, 30, 40), 1.5)
    a = profrobot.cloud_from_depth(family, depth, cams, pose=theta, layout=at, voxel=None)
    b = profrobot.cloud_from_depth(pinned, depth, cams, pose=theta, voxel=None)
    np.testing.assert_array_equal(a.cloud.points, b.cloud.points)
    assert (a.robot_points, a.static_points) == (b.robot_points, b.static_points)
    pts = np.random.default_rng(0).uniform(-0.2, 0.8, (2000, 3))
    full = family.compose(theta[None], at)[0]
    for x, y in zip(self_filter(family, theta, pts, layout=at, static=0.01), self_filter(family, full, pts, static=0.01)):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(profrobot.InputError, match="layout= is a layout of a family"):
        profrobot.cloud_from_depth(pinned, depth, cams, pose=theta, layout=at)

    import torch

    asked = []

    def field(q: torch.Tensor) -> torch.Tensor:   # any θ → g; records what the slice asks
        asked.append(q.numpy().copy())
        return q[:, 0] - float(q[:, 0].mean())

    fig = sdf_slice(field, family, joints=(0, 1), resolution=12, layout=at)
    assert asked[0].shape == (144, family.njoint)
    np.testing.assert_allclose(asked[0][:, family.scene_index], np.broadcast_to(at, (144, len(at))), atol=1e-6)
    title = fig.axes[0].get_title()
    fig2 = sdf_slice(field, pinned, joints=(0, 1), resolution=12)
    assert title.replace(family.name, "") .split("\n")[1] == fig2.axes[0].get_title().split("\n")[1]


def test_render_a_family_at_a_layout(renderer, family, at):
    from profrobot.render import Cameras, make_views, render_depth

    theta = problems.free_poses(family.at(at), 2, seed=8)
    full = family.compose(theta, at)
    cams = Cameras.look_at([[1.6, 0.2, 1.0]], [[0.3, 0.0, 0.4]], width=32, height=24)
    np.testing.assert_array_equal(render_depth(family, theta, cams, layout=at), render_depth(family, full, cams))
    views = make_views(family, theta, cams, layout=at, progress=False)
    np.testing.assert_array_equal(views.poses, full)
    np.testing.assert_array_equal(views.depth, make_views(family, full, cams, progress=False).depth)
    with pytest.raises(profrobot.InputError, match="pass its layout too, layout=δ"):
        render_depth(family, theta, cams)
