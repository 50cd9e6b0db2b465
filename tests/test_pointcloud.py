"""Point-cloud obstacles (issue 36): the balls labelled exactly (against MuJoCo's sphere geoms),
certified motions and plans that MuJoCo finds free, the oracle and resolve against a cloud, depth
to cloud (the self-filter, conservative downsampling), pickling, bad input."""

from __future__ import annotations

import pickle

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot import scenes
from profrobot.perception.clouds import cloud_from_depth, cloud_picture, self_filter
from profrobot.exact.crosscheck import mujoco_labels
from profrobot.perception.layouts.depth import backproject, cast_depth, expected_depth
from profrobot.robot.pointcloud import PointCloud, reference_model
from profrobot.render import Cameras

Q0 = np.array([0.0, -0.6, 0.0, -2.3, 0.0, 1.7, 0.785, 0.04, 0.04])


@pytest.fixture(scope="module")
def blocks():
    return scenes.load("panda_blocks")


def clutter_points(seed: int = 0, n: int = 300) -> np.ndarray:
    """Five clumps of points in the Panda's workspace (metres)."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform([0.3, -0.4, 0.1], [0.7, 0.4, 0.6], (5, 3))
    return np.concatenate([c + rng.normal(0, 0.03, (n, 3)) for c in centres])


@pytest.fixture(scope="module")
def cloudy(blocks):
    return blocks.with_points(clutter_points(), 0.008)


def test_cloud_labels_and_pairs_agree_with_mujoco_spheres(cloudy, blocks):
    poses = profrobot.sample_poses(cloudy, 1500, seed=3)
    rep = profrobot.crosscheck(cloudy, poses, progress=False)
    assert rep.agreement == 1.0 and rep.pair_agreement == 1.0, rep.summary()
    hit = profrobot.label_poses(cloudy, poses).collides
    assert hit.mean() > profrobot.label_poses(blocks, poses).collides.mean() + 0.05  # the cloud is in the way
    assert (profrobot.collides(cloudy, poses) == hit).all()
    # with a margin on the balls too
    rep = profrobot.crosscheck(cloudy.with_margin(0.02), poses[:600], progress=False)
    assert rep.agreement == 1.0, rep.summary()


def test_distances_are_the_least_over_the_balls(cloudy):
    """min_distance of a pose: MuJoCo's mj_geomDistance over every ball and robot geom agrees."""
    poses = profrobot.sample_poses(cloudy, 40, seed=5)
    ours = profrobot.label_poses(cloudy, poses, distance=True).min_distance
    m = reference_model(cloudy)
    d = mujoco.MjData(m)
    from profrobot.robot.pointcloud import cloud_geom_ids, robot_geom_ids
    balls = cloud_geom_ids(cloudy)
    ids = robot_geom_ids(cloudy)
    robot_geoms = {int(np.flatnonzero(ids == g)[0]) for g1, g2 in cloudy.pair_geoms if -1 in (g1, g2)
                   for g in (g1, g2) if g != -1}
    checked = 0
    for q, dist in zip(poses, ours):
        d.qpos[cloudy.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        best = min(mujoco.mj_geomDistance(m, d, int(b), g, 0.05, None) for b in balls for g in robot_geoms)
        if best < 0.04 and dist < 0.04:  # both within MuJoCo's distmax
            assert dist <= best + 1e-6  # the pose's least distance: over every pair, the cloud's included
            checked += 1
    assert checked >= 5


def test_empty_cloud_is_free_space_and_replacing_clouds(blocks, cloudy):
    poses = profrobot.sample_poses(blocks, 500, seed=1)
    empty = blocks.with_points(PointCloud(np.zeros((0, 3))))
    assert empty.fingerprint == blocks.fingerprint
    assert (profrobot.collides(empty, poses) == profrobot.collides(blocks, poses)).all()
    assert cloudy.with_points(None).fingerprint == blocks.fingerprint
    # with_obstacles adds to the cloud, with_points replaces it
    more = cloudy.with_obstacles([PointCloud([[0.5, 0.0, 0.3]], 0.05)])
    assert len(more.cloud) == len(cloudy.cloud) + 1
    assert len(cloudy.with_points([[0.5, 0.0, 0.3]]).cloud) == 1


def test_certified_motions_and_plans_are_free_to_mujoco(cloudy):
    rng = np.random.default_rng(2)
    free = profrobot.exact.problems.free_poses(cloudy, 40, seed=4)
    a, b = free[:20], free[20:]
    cert = profrobot.certify_motions(cloudy, a, b)
    ok = np.flatnonzero(cert.certified)
    assert 0 < len(ok) < 20
    dense = np.concatenate([profrobot.interpolate(cloudy, a[i], b[i], 400) for i in ok])
    assert not mujoco_labels(cloudy, dense, progress=False).collides.any()
    starts, goals = profrobot.exact.problems.hard_pairs(cloudy, 4, seed=6)
    for s, g in zip(starts, goals):
        r = profrobot.plan_path(cloudy, s, g, seed=0)
        assert r.found and r.certified
        seg = np.concatenate([profrobot.interpolate(cloudy, p, q, 300) for p, q in zip(r.path[:-1], r.path[1:])])
        assert not mujoco_labels(cloudy, seg, progress=False).collides.any()
    del rng


def test_oracle_and_exact_resolve_leave_the_cloud(cloudy):
    poses = profrobot.exact.problems.colliding_poses(cloudy, 12, seed=7)
    near = profrobot.nearest_free(cloudy, poses)
    assert np.isfinite(near.distance).sum() >= 10
    got = near.poses[near.certified]  # (a found pose may sit on the boundary; a certified one is clear)
    assert len(got) >= 8 and not mujoco_labels(cloudy, got, progress=False).collides.any()
    res = profrobot.resolve(None, poses, robot=cloudy)
    assert res.certified.all()
    assert not mujoco_labels(cloudy, res.poses, progress=False).collides.any()


def test_ik_answers_keep_clear_of_the_cloud(cloudy):
    """Hand positions among the clumps: every certified answer is free to MuJoCo's spheres."""
    free = profrobot.exact.problems.free_poses(cloudy, 8, seed=9)
    m = cloudy.mj_model
    d = mujoco.MjData(m)
    hand = m.body("hand").id
    targets = []
    for q in free:
        d.qpos[cloudy.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        targets.append(d.xpos[hand].copy())
    r = profrobot.ik(cloudy, np.array(targets), frame="hand")
    assert r.certified.sum() >= 6
    assert not mujoco_labels(cloudy, r.poses[r.certified], progress=False).collides.any()


def test_downsampling_is_conservative_and_deterministic():
    rng = np.random.default_rng(0)
    cloud = PointCloud(rng.uniform(-0.2, 0.2, (5000, 3)), rng.uniform(0.001, 0.004, 5000))
    small = cloud.downsample(0.08)
    assert len(small) < len(cloud) / 10
    d = np.linalg.norm(cloud.points[:, None] - small.points[None], axis=2) + cloud.radius[:, None]
    assert (d <= small.radius[None] + 1e-12).any(axis=1).all()  # each ball inside a kept one
    assert small == cloud.downsample(0.08)
    with pytest.raises(profrobot.InputError, match="voxel"):
        cloud.downsample(0.0)


def test_bad_clouds_are_refused_by_name(blocks):
    pts = np.zeros((4, 3))
    pts[2, 1] = np.nan
    with pytest.raises(profrobot.InputError, match=r"points\[2, 1\] is nan"):
        PointCloud(pts)
    with pytest.raises(profrobot.InputError, match=r"radius\[1\] is -0.1"):
        PointCloud(np.zeros((3, 3)), [0.1, -0.1, 0.1])
    with pytest.raises(profrobot.InputError, match=r"shape \(N, 3\)"):
        PointCloud(np.zeros((3, 2)))
    with pytest.raises(profrobot.InputError, match="radius"):
        PointCloud(np.zeros((3, 3)), [0.1, 0.1])
    with pytest.raises(profrobot.InputError, match="finite"):
        profrobot._core.voxel_downsample(pts, np.zeros(4), 0.1)
    with pytest.raises(profrobot.InputTypeError, match="PointCloud"):
        blocks.with_obstacles(["cloud"])
    with pytest.raises(AttributeError):
        PointCloud(np.zeros((1, 3))).points = None


def test_cloud_robot_pickles_and_labels_alike(cloudy):
    poses = profrobot.sample_poses(cloudy, 800, seed=11)
    back = pickle.loads(pickle.dumps(cloudy))
    assert back.fingerprint == cloudy.fingerprint and back.cloud == cloudy.cloud
    assert (profrobot.label_poses(back, poses).collides == profrobot.label_poses(cloudy, poses).collides).all()
    assert back.mj_model is not None  # the spec rebuilt and checked against the fingerprint (cloud included)
    one = profrobot.label_poses(cloudy, poses, threads=1, pairs=True)
    two = profrobot.label_poses(cloudy, poses, threads=2, pairs=True)
    assert (one.collides == two.collides).all() and (one.colliding_pairs == two.colliding_pairs).all()
    assert pickle.loads(pickle.dumps(cloudy.cloud)) == cloudy.cloud


def test_depth_to_cloud_removes_the_robot_and_covers_the_objects(tmp_path):
    true = scenes.panda_clutter()
    base = profrobot.Robot.from_menagerie("franka_emika_panda", "panda").with_obstacles([scenes.FLOOR])
    K = np.array([[[131.0, 0, 80.6], [0, 131.7, 59.1], [0, 0, 1]], [[125.5, 0, 78.8], [0, 125.1, 60.9], [0, 0, 1]]])
    cams = Cameras.look_at([(1.6, -0.9, 1.2), (-0.6, 0.9, 1.5)], [(0.45, 0.0, 0.2), (0.45, 0.0, 0.15)],
                           width=160, height=120, K=K)
    qpos = true.mj_model.qpos0.copy()
    qpos[true.qpos_adr] = Q0
    depth = cast_depth(true.mj_model, qpos, cams)
    build = cloud_from_depth(base, depth, cams, pose=Q0)
    assert build.robot_points > 500 and len(build.cloud) > 300, build.summary()
    # no robot pixel survives: the robot's own points are those its ray meets first
    m = true.mj_model
    d = mujoco.MjData(m)
    d.qpos[true.qpos_adr] = Q0
    mujoco.mj_kinematics(m, d)
    robot_bodies = {b for b in range(m.nbody) if b != 0 and m.body_rootid[b] == m.body_rootid[m.jnt_bodyid[0]]}
    dp = backproject(depth, cams)
    own, static = self_filter(base, Q0, dp.points, padding=0.02, static=0.005)
    seen = []
    for c in range(len(cams)):
        _, gid = expected_depth(m, d, cams, c)
        seen.append(np.array([g >= 0 and m.geom_bodyid[g] in robot_bodies for g in gid]))
    seen = np.concatenate(seen)[np.concatenate([np.flatnonzero(depth[c].ravel() > 0) for c in range(len(cams))])
                                + np.repeat(np.arange(len(cams)) * depth[0].size, [(depth[c] > 0).sum() for c in range(len(cams))])]
    assert seen.sum() > 200 and not (seen & ~(own | static)).any()
    # every obstacle point the cameras saw lies inside a ball
    obstacle = ~own & ~static
    scene = base.with_points(build.cloud)
    tiny = PointCloud(dp.points[obstacle][::7], 0.0)
    dist = np.linalg.norm(tiny.points[:, None] - build.cloud.points[None], axis=2) - build.cloud.radius[None]
    assert (dist.min(axis=1) <= 1e-9).all()
    # the cloud scene blocks what the true scene blocks, where the cameras saw it
    poses = profrobot.sample_poses(scene, 3000, seed=0)
    t, c = profrobot.collides(true, poses), profrobot.collides(scene, poses)
    assert (c[t]).mean() > 0.9
    fig = cloud_picture(scene, tmp_path / "cloud.png", waypoints=np.stack([Q0, Q0 * 0.5]))
    assert (tmp_path / "cloud.png").stat().st_size > 10_000
    del fig


def test_self_filter_refuses_bad_input(blocks):
    with pytest.raises(profrobot.InputError, match="padding"):
        self_filter(blocks, Q0, np.zeros((3, 3)), padding=-0.1)
    with pytest.raises(profrobot.InputError, match="not finite"):
        self_filter(blocks, Q0, np.full((3, 3), np.nan))
