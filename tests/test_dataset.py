"""Balanced datasets, atomic saves, and provenance checks on load."""

import os

import numpy as np
import pytest

import profrobot
from profrobot import Dataset
from profrobot.errors import CorruptFileError, RobotMismatchError


@pytest.fixture(scope="module")
def dataset(panda):
    return profrobot.make_dataset(panda, 1000, collided_fraction=0.5, seed=7, batch=4000, progress=False)


def test_dataset_is_balanced_and_labels_are_exact(panda, dataset):
    assert len(dataset) == 1000 and dataset.collided_fraction == 0.5
    check = profrobot.crosscheck(panda, dataset.poses[:300])
    assert check.agreement == 1.0
    np.testing.assert_array_equal(check.ours.collides, dataset.collides[:300])
    assert dataset.metadata["robot_fingerprint"] == panda.fingerprint
    assert dataset.metadata["joint_names"] == panda.joint_names
    assert 0 < dataset.metadata["uniform_collision_rate"] < 0.5


def test_other_fractions_and_impossible_quotas(panda):
    ds = profrobot.make_dataset(panda, 200, collided_fraction=0.25, seed=1, batch=2000, progress=False)
    assert ds.collides.sum() == 50
    with pytest.raises(profrobot.ProfrobotError, match="collision rate"):
        profrobot.make_dataset(panda, 500, collided_fraction=1.0, seed=1, batch=100, max_samples=300, progress=False)


def test_save_load_round_trip(tmp_path, panda, dataset):
    path = tmp_path / "panda.npz"
    dataset.save(path)
    back = Dataset.load(path, robot=panda)
    np.testing.assert_array_equal(back.poses, dataset.poses)
    for k in ("collides", "self_collides", "scene_collides", "n_pairs"):
        np.testing.assert_array_equal(getattr(back, k), getattr(dataset, k))
    assert back.metadata == dataset.metadata
    assert os.listdir(tmp_path) == ["panda.npz"]  # no temporary file left behind


def test_interrupted_save_keeps_the_old_file(tmp_path, dataset, monkeypatch):
    path = tmp_path / "d.npz"
    dataset.save(path)
    before = path.read_bytes()

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez", boom)
    with pytest.raises(KeyboardInterrupt):
        dataset.save(path)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["d.npz"]


def test_load_refuses_other_robots_and_corrupt_files(tmp_path, ur5e, dataset):
    path = tmp_path / "d.npz"
    dataset.save(path)
    with pytest.raises(RobotMismatchError, match="was made for robot 'panda_blocks'"):
        Dataset.load(path, robot=ur5e)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(path.read_bytes()[:200])
    with pytest.raises(CorruptFileError, match="corrupt"):
        Dataset.load(bad)
    np.savez(tmp_path / "other.npz", poses=np.zeros((2, 9)))
    with pytest.raises(CorruptFileError, match="not a profrobot dataset"):
        Dataset.load(tmp_path / "other.npz")
    with pytest.raises(ValueError, match=".npz"):
        dataset.save(tmp_path / "d.pkl")


def test_split_is_seeded(dataset):
    tr, te = dataset.split(0.1, seed=0)
    assert len(te) == 100 and len(tr) == 900
    np.testing.assert_array_equal(te.poses, dataset.split(0.1, seed=0)[1].poses)


def test_boundary_poses_sit_at_contact_with_exact_labels(panda):
    """boundary_dataset: labels are the labeller's, about half collide, the poses are within the
    limits, and they are far closer to contact than uniform poses (the point of drawing them)."""
    from profrobot.exact.dataset import boundary_dataset

    near = boundary_dataset(panda, 4000, seed=3)
    assert len(near) == 4000 and 0.3 < near.collides.mean() < 0.7
    assert np.array_equal(near.collides, profrobot.collides(panda, near.poses))
    lim = panda.joint_limits
    assert ((near.poses >= lim[:, 0]) & (near.poses <= lim[:, 1])).all()
    uniform = profrobot.sample_poses(panda, 4000, seed=3)
    # distances are reported only near contact; penetration depths are exact: the boundary
    # poses' colliding ones are far shallower than uniform colliding poses
    d_near = profrobot.label_poses(panda, near.poses, distance=True).min_distance
    d_uni = profrobot.label_poses(panda, uniform, distance=True).min_distance
    assert np.median(-d_near[d_near < 0]) < 0.5 * np.median(-d_uni[d_uni < 0])   # 24 against 58 mm when written
    again = boundary_dataset(panda, 4000, seed=3, threads=1)
    assert np.array_equal(again.poses, near.poses)


def test_boundary_dataset_bad_input_is_named(panda):
    from profrobot.exact.dataset import boundary_dataset
    from profrobot.errors import InputError

    with pytest.raises(InputError, match="spread"):
        boundary_dataset(panda, 10, spread=0.0)
