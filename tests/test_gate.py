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
