"""``Robot.from_mjcf`` warns of body pairs that collide in every pose and offers ``from_urdf``'s
collision matrix (issue 33). Menagerie's Kinova Gen3 collides in 100 % of poses because its base
overlaps the shoulder; its meshes cannot be fetched on these offline machines, so the arm here is
built the same way: a base whose collision box reaches into the shoulder link above its joint."""

from __future__ import annotations

import pickle
import warnings

import numpy as np
import pytest

import profrobot
from profrobot.robot.urdf import CollisionWarning, UrdfWarning

# base_link (fixed to the world) overlaps shoulder_link (joint 1) for every angle of joint 1: the
# shoulder's cylinder sits inside the top of the base's box. MuJoCo checks the pair (a body welded
# to the world is not filtered against its child), so every pose collides.
GEN3_LIKE = """<mujoco model="gen3_like">
  <compiler angle="radian"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <geom name="table" type="box" pos="0.55 0 0.2" size="0.15 0.3 0.2"/>
    <body name="base_link" pos="0 0 0">
      <geom type="box" pos="0 0 0.08" size="0.06 0.06 0.08"/>
      <body name="shoulder_link" pos="0 0 0.156">
        <joint name="joint_1" axis="0 0 1" range="-3.1 3.1"/>
        <geom type="cylinder" pos="0 0 0.04" size="0.05 0.06"/>
        <body name="half_arm_1_link" pos="0 0 0.128">
          <joint name="joint_2" axis="0 1 0" range="-2.2 2.2"/>
          <geom type="capsule" fromto="0 0 0.02 0 0 0.3" size="0.045"/>
          <body name="forearm_link" pos="0 0 0.33">
            <joint name="joint_3" axis="0 1 0" range="-2.5 2.5"/>
            <geom type="capsule" fromto="0 0 0.02 0 0 0.28" size="0.04"/>
            <body name="wrist_link" pos="0 0 0.3">
              <joint name="joint_4" axis="0 0 1" range="-3 3"/>
              <geom type="box" pos="0 0 0.04" size="0.035 0.035 0.05"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def gen3_like(tmp_path_factory):
    path = tmp_path_factory.mktemp("gen3") / "gen3_like.xml"
    path.write_text(GEN3_LIKE)
    return path


def test_a_base_overlapping_the_shoulder_is_warned_about(gen3_like):
    with pytest.warns(CollisionWarning, match=r"base_link–shoulder_link \(100.0 %\).*collision_matrix='auto'"):
        robot = profrobot.Robot.from_mjcf(gen3_like)
    assert profrobot.collides(robot, profrobot.sample_poses(robot, 2000, seed=1)).all()   # every pose
    assert "base_link – shoulder_link: 100.0 %" in robot.collision_report()
    assert not issubclass(CollisionWarning, UrdfWarning) and issubclass(UrdfWarning, CollisionWarning)


def test_collision_matrix_auto_makes_it_usable_and_keeps_mujoco_agreement(gen3_like):
    with warnings.catch_warnings():
        warnings.simplefilter("error", CollisionWarning)      # nothing left to warn about
        robot = profrobot.Robot.from_mjcf(gen3_like, collision_matrix="auto")
    assert ("base_link", "shoulder_link") in {p[:2] for p in robot.disabled_pairs}
    assert all(p[0] != "world" and p[1] != "world" for p in robot.disabled_pairs)   # obstacles stay checked
    poses = profrobot.sample_poses(robot, 20_000, seed=2)
    labels = profrobot.label_poses(robot, poses)
    assert 0.02 < labels.collides.mean() < 0.9, labels.summary()
    assert labels.scene_collides.any()                     # the table and floor still count
    report = profrobot.crosscheck(robot, poses[:5000], progress=False)
    assert report.agreement == 1.0 and report.pair_agreement == 1.0, report.summary()
    assert "before the matrix" in robot.collision_report()
    # the matrix is an edit of the spec: a pickle rebuilds it, obstacles can still be added
    back = pickle.loads(pickle.dumps(robot))
    np.testing.assert_array_equal(profrobot.collides(back, poses[:2000]), labels.collides[:2000])
    more = robot.with_obstacles([profrobot.Sphere(pos=(0, 0.5, 0.5), radius=0.1, name="ball")])
    assert profrobot.collides(more, poses).mean() >= labels.collides.mean()


def test_srdf_for_an_mjcf_robot(gen3_like, tmp_path):
    srdf = tmp_path / "gen3.srdf"
    srdf.write_text('<robot name="gen3_like"><disable_collisions link1="base_link" link2="shoulder_link" '
                    'reason="Adjacent"/></robot>')
    with warnings.catch_warnings():
        warnings.simplefilter("error", CollisionWarning)
        robot = profrobot.Robot.from_mjcf(gen3_like, srdf=srdf)
    assert [p[:2] for p in robot.disabled_pairs] == [("base_link", "shoulder_link")]
    assert not profrobot.collides(robot, profrobot.sample_poses(robot, 2000, seed=3)).all()
    with pytest.raises(profrobot.InputError, match="collision_matrix"):
        profrobot.Robot.from_mjcf(gen3_like, collision_matrix="everything")
