"""Grasped objects (Robot.attach / Robot.detach, python/profrobot/robot/grasp.py): the object
moves with the hand, labels and pair sets agree with MuJoCo's collision on a box and a mesh
held, it may touch what it is allowed to, a path planned while holding keeps it off the world
(MuJoCo replay), and letting go leaves it where it was put."""

from __future__ import annotations

import pickle

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot import Box, InputError, Mesh, Sphere, crosscheck, interpolate, mujoco_labels

from conftest import scene


def _kinematics(robot, q) -> mujoco.MjData:
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_adr] = q
    mujoco.mj_kinematics(m, d)
    return d


def _world_pose(robot, q, geom: str):
    """(position (3,), rotation (3, 3)) of geom ``geom`` at pose ``q``, by MuJoCo."""
    g = _kinematics(robot, q).geom(geom)
    return g.xpos.copy(), g.xmat.reshape(3, 3).copy()


def _body_pose(robot, q, body: str):
    """(position (3,), rotation (3, 3)) of body ``body`` at pose ``q``, by MuJoCo."""
    b = _kinematics(robot, q).body(body)
    return b.xpos.copy(), b.xmat.reshape(3, 3).copy()


def _grasp_pose(robot, seed=0):
    """A free pose of the Panda with its hand about 0.25 m above the floor and away from the base."""
    poses = profrobot.sample_poses(robot, 4000, seed=seed)
    poses = poses[~profrobot.collides(robot, poses)]
    for q in poses:
        p, _ = _body_pose(robot, q, "hand")
        if 0.2 < p[2] < 0.45 and np.hypot(p[0], p[1]) > 0.35:
            return q
    raise AssertionError("no grasp pose")


def _cloud_part():
    """A convex mesh whose vertices are off its centroid (the compiler re-centres it)."""
    rng = np.random.default_rng(4)
    v = rng.normal(size=(40, 3)) * [0.03, 0.02, 0.05] + [0.01, -0.02, 0.03]
    return v


@pytest.fixture(scope="module")
def held():
    """panda_blocks with a box and a mesh in the world, each then held by the hand at a grasp."""
    base = scene("panda_blocks")
    q = _grasp_pose(base)
    hp, hr = _body_pose(base, q, "hand")
    box_at = hp + hr @ [0.0, 0.0, 0.15]
    mesh_at = hp + hr @ [0.0, 0.06, 0.16]
    world = base.with_obstacles([Box(pos=tuple(box_at), half_size=(0.02, 0.03, 0.04), name="part"),
                                 Mesh(pos=tuple(mesh_at), quat=(0.9, 0.1, 0.3, 0.2), vertices=_cloud_part(),
                                      name="rock")])
    box = world.attach("part", to="hand", at=q)
    both = box.attach("rock", to="hand", at=q)
    return world, box, both, q


def test_the_held_object_stays_put_at_the_grasp_and_moves_with_the_hand(held):
    world, box, both, q = held
    for name in ("part", "rock"):
        p0, r0 = _world_pose(world, q, name)
        p1, r1 = _world_pose(both, q, name)
        np.testing.assert_allclose(p1, p0, atol=1e-12)
        np.testing.assert_allclose(r1, r0, atol=1e-12)
    q2 = profrobot.sample_poses(world, 1, seed=9)[0]
    hp, hr = _body_pose(world, q, "hand")
    hp2, hr2 = _body_pose(world, q2, "hand")
    for name in ("part", "rock"):
        p0, r0 = _world_pose(world, q, name)
        p2, r2 = _world_pose(both, q2, name)
        np.testing.assert_allclose(p2, hp2 + hr2 @ hr.T @ (p0 - hp), atol=1e-12)
        np.testing.assert_allclose(r2, hr2 @ hr.T @ r0, atol=1e-12)
    # Before the grasp the world does not move them.
    np.testing.assert_allclose(_world_pose(world, q2, "part")[0], _world_pose(world, q, "part")[0])


def test_labels_and_pair_sets_of_a_held_box_and_mesh_agree_with_mujoco(held):
    _, box, both, _ = held
    for robot in (box, both):
        poses = profrobot.sample_poses(robot, 20_000, seed=2)
        report = crosscheck(robot, poses)
        assert report.agreement == 1.0 and report.pair_agreement == 1.0, report.summary()
        labels = profrobot.label_poses(robot, poses, pairs=True)
        names = {robot.pair_names(int(k)) for k in np.unique(labels.colliding_pairs[:, 1])}
        assert any("part" in n for n in names)       # the held box does hit things
    assert any("rock" in n for k in range(len(both.pair_geoms)) for n in [both.pair_names(k)])


def test_a_path_planned_while_holding_keeps_the_object_off_the_world(held):
    _, box, _, q = held
    rng = np.random.default_rng(1)
    starts = profrobot.sample_poses(box, 3000, seed=11)
    free = starts[profrobot.certify_poses(box, starts)]
    done = 0
    for i in range(0, 40, 2):
        a, b = free[i], free[i + 1]
        if profrobot.certify_motions(box, a, b).certified[0]:
            continue                                  # only problems the straight motion cannot solve
        plan = profrobot.plan_path(box, a, b, max_time=20.0, seed=int(rng.integers(1000)))
        if not plan.found:
            continue
        dense = np.concatenate([interpolate(box, x, y, 200) for x, y in zip(plan.path[:-1], plan.path[1:])])
        assert not mujoco_labels(box, dense).collides.any()
        done += 1
        if done == 3:
            break
    assert done == 3


def test_touching_lets_the_object_touch_the_named_bodies_only(held):
    world, _, _, q = held
    def pairs(robot):
        return {frozenset(robot.pair_names(k)) for k in range(len(robot.pair_geoms))}
    plain = world.attach("part", to="hand", at=q)
    links = [f"link{i}" for i in range(1, 7)]
    touching = world.attach("part", to="hand", at=q, touching=links)
    assert pairs(touching) < pairs(plain)
    gone = pairs(plain) - pairs(touching)
    assert all("part" in p for p in gone)
    # what is left of the part's pairs: the world's obstacles, the other held object, nothing of links 1-6
    m = touching.mj_model
    body_of = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}":
               mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.geom_bodyid[g]) for g in range(m.ngeom)}
    left = {body_of.get(n, "?") for p in pairs(touching) if "part" in p for n in p if n != "part"}
    assert "?" not in left and not left & set(links), left


def test_attaching_a_new_obstacle_in_the_hand_frame(held):
    world, _, _, q = held
    r = world.attach(Sphere(pos=(0.0, 0.0, 0.12), radius=0.03, name="ball"), to="hand")
    hp, hr = _body_pose(world, q, "hand")
    np.testing.assert_allclose(_world_pose(r, q, "ball")[0], hp + hr @ [0, 0, 0.12], atol=1e-12)
    poses = profrobot.sample_poses(r, 5000, seed=3)
    assert crosscheck(r, poses).agreement == 1.0


def test_detach_leaves_the_object_where_it_was_put(held):
    world, _, both, q = held
    q2 = profrobot.sample_poses(world, 1, seed=21)[0]
    for name in ("part", "rock"):
        put = both.detach(name, at=q2)
        p_at, r_at = _world_pose(both, q2, name)
        q3 = profrobot.sample_poses(world, 1, seed=22)[0]
        p3, r3 = _world_pose(put, q3, name)         # the arm moved on; the object did not
        np.testing.assert_allclose(p3, p_at, atol=1e-12)
        np.testing.assert_allclose(r3, r_at, atol=1e-12)
    back = both.detach("rock", at=q).detach("part", at=q)
    poses = profrobot.sample_poses(world, 3000, seed=5)
    np.testing.assert_array_equal(profrobot.label_poses(back, poses).collides,
                                  profrobot.label_poses(world, poses).collides)


def test_a_held_object_survives_a_pickle(held):
    _, _, both, _ = held
    poses = profrobot.sample_poses(both, 2000, seed=7)
    again = pickle.loads(pickle.dumps(both))
    assert again.fingerprint == both.fingerprint
    np.testing.assert_array_equal(profrobot.label_poses(again, poses).collides,
                                  profrobot.label_poses(both, poses).collides)


def test_bad_input_refused_by_name(held):
    world, box, _, q = held
    cases = [
        (lambda: world.attach("part", to="nowhere", at=q), "to='nowhere' is not a body"),
        (lambda: world.attach("part", to="world", at=q), "to='world' does not move"),
        (lambda: world.attach("nothing", to="hand", at=q), "obstacle='nothing' is not a geom"),
        (lambda: world.attach("floor", to="hand", at=q), "plane"),
        (lambda: world.attach("part", to="hand"), "at is required"),
        (lambda: world.attach("part", to="hand", at=q[:3]), "at"),
        (lambda: world.attach("part", to="hand", at=q, touching="link7"), "touching must be a list"),
        (lambda: world.attach("part", to="hand", at=q, touching=["nobody"]), "touching='nobody'"),
        (lambda: world.attach(Sphere(pos=(0, 0, 0.1), radius=0.02), to="hand"), "needs a name"),
        (lambda: world.attach(Sphere(pos=(0, 0, 0.1), radius=0.02, name="ball"), to="hand", at=q), "at is for"),
        (lambda: world.attach(3, to="hand", at=q), "obstacle must be"),
        (lambda: box.detach("rock", at=q), "name='rock' is not an object"),
        (lambda: box.detach("part", at=np.full(9, np.nan)), "at"),
    ]
    for call, words in cases:
        with pytest.raises(profrobot.ProfrobotError) as e:
            call()
        assert words in str(e.value), (words, str(e.value))
    assert isinstance(InputError("x"), profrobot.ProfrobotError)
