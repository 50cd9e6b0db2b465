"""Same seed, same result, whatever the thread count (acceptance 4)."""

import numpy as np

import profrobot


def test_sampling_and_labels_do_not_depend_on_threads(panda):
    a = profrobot.sample_poses(panda, 5000, seed=42, threads=1)
    b = profrobot.sample_poses(panda, 5000, seed=42, threads=2)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, profrobot.sample_poses(panda, 5000, seed=43))
    la = profrobot.label_poses(panda, a, pairs=True, distance=True, threads=1)
    lb = profrobot.label_poses(panda, a, pairs=True, distance=True, threads=2)
    for key in ("collides", "self_collides", "scene_collides", "n_pairs", "min_distance", "colliding_pairs"):
        np.testing.assert_array_equal(getattr(la, key), getattr(lb, key))


def test_samples_stay_within_limits_and_fill_them(panda):
    q = profrobot.sample_poses(panda, 20000, seed=1)
    lim = panda.joint_limits
    assert (q >= lim[:, 0]).all() and (q <= lim[:, 1]).all()
    # Uniform: each joint's mean sits mid-range.
    np.testing.assert_allclose(q.mean(0), lim.mean(1), atol=0.02 * (lim[:, 1] - lim[:, 0]).max())


def test_dataset_does_not_depend_on_threads(panda):
    a = profrobot.make_dataset(panda, 600, seed=3, batch=2000, threads=1, progress=False)
    b = profrobot.make_dataset(panda, 600, seed=3, batch=2000, threads=2, progress=False)
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.collides, b.collides)
