"""Our labels against MuJoCo's mj_collision, scene by scene (acceptance 1 on a smaller sample)."""

import numpy as np
import pytest

import profrobot
from conftest import scene

GRAZING = 1e-4  # metres


def check_layout(name: str, n: int, seed: int):
    robot = scene(name)
    poses = profrobot.sample_poses(robot, n, seed)
    report = profrobot.crosscheck(robot, poses)
    for d in report.disagreements:
        assert abs(d.signed_distance) < GRAZING, f"{name}: non-grazing disagreement {d}"
    assert report.agreement >= 0.9999 or len(report.disagreements) <= 1, report.summary()
    # Not only labels: the sets of colliding geom pairs agree too.
    assert report.pair_agreement >= 0.999, report.summary()
    # Both classes are exercised, so agreement is not trivially all-free or all-colliding.
    assert 0 < report.confusion[1, 1] < n and 0 < report.confusion[0, 0] < n
    return report


@pytest.mark.parametrize("name", profrobot.scenes.names())
def test_labels_agree_with_mujoco(name):
    check_layout(name, 3000, seed=11)


@pytest.mark.slow
@pytest.mark.parametrize("name", profrobot.scenes.names())
def test_labels_agree_with_mujoco_large_sample(name):
    check_layout(name, 100_000, seed=12)


def test_self_and_scene_split_matches_mujoco_pairs(panda):
    poses = profrobot.sample_poses(panda, 2000, 5)
    ours = profrobot.label_poses(panda, poses)
    ref = profrobot.mujoco_labels(panda, poses)
    m = panda.mj_model
    # The scene's obstacles are world-body geoms; every other geom is the robot's.
    static_geoms = {g for g in range(m.ngeom) if m.geom_bodyid[g] == 0}
    mj_scene = np.array([any(a in static_geoms or b in static_geoms for a, b in p) for p in ref.pairs])
    mj_self = np.array([any(a not in static_geoms and b not in static_geoms for a, b in p) for p in ref.pairs])
    assert (ours.scene_collides == mj_scene).all()
    assert (ours.self_collides == mj_self).all()
    assert (ours.n_pairs == np.array([len(p) for p in ref.pairs])).all()
