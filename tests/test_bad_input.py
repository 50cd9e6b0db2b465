"""Every bad input gets a Python exception that names the problem (acceptance 4)."""

import numpy as np
import pytest

import profrobot
from profrobot import Robot


@pytest.mark.parametrize("poses, exc, match", [
    (np.zeros((4, 5)), ValueError, r"shape \(B, 9\)"),
    (np.zeros((2, 3, 9)), ValueError, r"shape \(B, 9\)"),
    (np.zeros((0, 9)), ValueError, "empty"),
    (np.array([["a"] * 9]), TypeError, "floating-point"),
    (np.zeros((3, 9), dtype=complex), TypeError, "floating-point"),
    (np.full((2, 9), np.nan), ValueError, r"poses\[0, 0\].*finite"),
    (np.r_[np.zeros((1, 9)), [[0, 0, np.inf, 0, 0, 0, 0, 0, 0]]], ValueError, r"poses\[1, 2\] \(joint3\)"),
])
def test_bad_poses(panda, poses, exc, match):
    with pytest.raises(exc, match=match):
        profrobot.label_poses(panda, poses)


def test_regression_out_of_limits_poses_are_refused_by_labels_too(panda):
    """Issue 33: a pose in degrees got labels (and, before, a certificate) silently."""
    pose = panda.joint_limits.mean(1)[None].copy()
    pose[0, 3] = 1.0  # joint4's range is about [-3.07, -0.07]
    for fn in (profrobot.label_poses, profrobot.collides):
        with pytest.raises(profrobot.InputError, match=r"poses\[0, 3\] = 1 is outside the limits of joint 'joint4'"):
            fn(panda, pose)
    assert profrobot.label_poses(panda, pose, check_limits=False).collides.shape == (1,)  # asked for: allowed
    assert not profrobot.certify_poses(panda, pose)[0]
    with pytest.raises(ValueError, match="outside the limits"):
        profrobot.interpolate(panda, pose[0], panda.joint_limits.mean(1), 10)


def test_poses_checked_in_one_pass_name_the_entry_numpy_would(panda):
    """as_poses checks finiteness and limits in one Rust pass (`first_bad_entries`); the entry
    named is numpy's row-major first, a non-finite one before any outside the limits, within
    `atol` of a limit allowed, and a continuous joint never out of limits."""
    from profrobot.robot.gate import as_poses
    rng = np.random.default_rng(0)
    lim, k = panda.joint_limits, panda.njoint
    for _ in range(200):
        poses = rng.uniform(lim[:, 0], lim[:, 1], size=(int(rng.integers(1, 6)), k))
        for _ in range(int(rng.integers(0, 3))):
            i, j = rng.integers(len(poses)), rng.integers(k)
            poses[i, j] = rng.choice([np.nan, np.inf, -np.inf, lim[j, 1] + 1e-10, lim[j, 1] + 1e-3, lim[j, 0] - 2])
        nonfinite = ~np.isfinite(poses)
        outside = ((poses < lim[:, 0] - 1e-9) | (poses > lim[:, 1] + 1e-9)) & ~panda.continuous
        if nonfinite.any():
            i, j = np.argwhere(nonfinite)[0]
            match = rf"poses\[{i}, {j}\] \({panda.joint_names[j]}\) is .*finite"
        elif outside.any():
            i, j = np.argwhere(outside)[0]
            match = rf"poses\[{i}, {j}\] = .* is outside the limits of joint '{panda.joint_names[j]}'"
        else:
            assert as_poses(panda, poses, check_limits=True) is not None
            continue
        with pytest.raises(profrobot.InputError, match=match):
            as_poses(panda, poses, check_limits=True)
        if not nonfinite.any():
            assert as_poses(panda, poses, check_limits=False).shape == poses.shape


def test_whole_numbers_are_poses_too(panda):
    """Issue 33: an int array (or a list of ints) was a plain TypeError."""
    lim = panda.joint_limits
    ints = np.clip(np.round(lim.mean(1)), np.ceil(lim[:, 0]), np.floor(lim[:, 1])).astype(np.int64)
    ints[7:] = 0   # the fingers
    assert profrobot.label_poses(panda, ints[None]).collides.shape == (1,)
    assert profrobot.collides(panda, [ints.tolist()]).shape == (1,)


def test_bad_counts_seeds_and_threads(panda):
    for n in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match="n must be a positive integer"):
            profrobot.sample_poses(panda, n)
    with pytest.raises(ValueError, match="seed"):
        profrobot.sample_poses(panda, 10, seed=-1)
    with pytest.raises(ValueError, match="threads"):
        profrobot.label_poses(panda, panda.joint_limits.mean(1)[None], threads=0)
    mid = panda.joint_limits.mean(1)
    with pytest.raises(ValueError, match="steps"):
        profrobot.interpolate(panda, mid, mid, 1)


def test_wrong_argument_types(panda):
    with pytest.raises(TypeError, match="profrobot.Robot"):
        profrobot.label_poses("panda", np.zeros((1, 9)))
    with pytest.raises(TypeError, match="mujoco.MjModel"):
        Robot("not a model")


def test_unknown_robot_scene_and_entry():
    with pytest.raises(ValueError, match="unknown scene 'nope'.*panda_blocks"):
        profrobot.scenes.load("nope")
    with pytest.raises(ValueError, match="unknown Menagerie robot 'nope'"):
        Robot.from_menagerie("nope")
    with pytest.raises(ValueError, match="no entry point 'nope'"):
        Robot.from_menagerie("franka_emika_panda", "nope")


def test_unreadable_and_malformed_mjcf(tmp_path):
    with pytest.raises(FileNotFoundError, match="no MJCF file"):
        Robot.from_mjcf(tmp_path / "missing.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body><geom size='0.1'></body></worldbody>")
    with pytest.raises(ValueError, match="could not read MJCF"):
        Robot.from_mjcf(bad)
    bad.write_text("<mujoco><worldbody><geom type='box' size='-1 1 1'/></worldbody></mujoco>")
    with pytest.raises(ValueError):
        Robot.from_mjcf(bad)


@pytest.mark.parametrize("joint, kind", [('type="free"', "free"), ('type="ball"', "ball")])
def test_free_and_ball_joints_are_rejected(tmp_path, joint, kind):
    path = tmp_path / "robot.xml"
    path.write_text(f"""<mujoco><worldbody><body pos="0 0 1"><joint name="j" {joint}/><geom size="0.1"/>
        <body pos="0 0 0.3"><joint name="h" axis="1 0 0"/><geom size="0.1"/></body></body></worldbody></mujoco>""")
    with pytest.raises(ValueError, match=f"'j' \\({kind}\\)"):
        Robot.from_mjcf(path)


def test_robot_without_joints_and_unsupported_geoms(tmp_path):
    path = tmp_path / "static.xml"
    path.write_text("<mujoco><worldbody><geom size='0.1'/></worldbody></mujoco>")
    with pytest.raises(ValueError, match="no joints"):
        Robot.from_mjcf(path)
    path.write_text("""<mujoco><worldbody><geom type="plane" size="1 1 1"/><body><joint axis="1 0 0"/>
        <geom type="ellipsoid" size="0.1 0.2 0.3"/></body></worldbody></mujoco>""")
    with pytest.raises(ValueError, match="ellipsoid"):
        Robot.from_mjcf(path)


def test_bad_obstacles(panda):
    with pytest.raises(ValueError, match="positive length"):
        panda.with_obstacles([profrobot.Box(pos=(0, 0, 0), half_size=(0.1, -1, 0.1))])
    with pytest.raises(ValueError, match="vertices"):
        panda.with_obstacles([profrobot.Mesh(pos=(0, 0, 0), vertices=np.zeros((2, 3)))])
    with pytest.raises(TypeError, match="Obstacle"):
        panda.with_obstacles(["box"])
    with pytest.raises(ValueError, match="MjSpec"):
        Robot.from_model(panda.mj_model).with_obstacles([])


def test_core_rejects_inconsistent_arrays_without_panicking(panda):
    arrays = panda.core_arrays()
    arrays["body_parent"] = arrays["body_parent"][::-1].copy()
    with pytest.raises(ValueError, match="parents must precede children"):
        profrobot._core.RobotModel(arrays)
    arrays = panda.core_arrays()
    arrays["geom_pos"] = arrays["geom_pos"][:3].copy()
    with pytest.raises(ValueError, match="geom_pos has 3 entries"):
        profrobot._core.RobotModel(arrays)
    arrays = panda.core_arrays()
    arrays["jnt_axis"] = arrays["jnt_axis"].astype(np.float32)
    with pytest.raises(TypeError, match="jnt_axis"):
        profrobot._core.RobotModel(arrays)
    arrays = panda.core_arrays()
    del arrays["exclude"]
    with pytest.raises(ValueError, match="lack 'exclude'"):
        profrobot._core.RobotModel(arrays)
    # a strided view is read through its strides (tests/test_native_edges.py), not refused
    np.testing.assert_array_equal(panda.core.label(np.zeros((4, 18))[:, ::2])["collides"],
                                  panda.core.label(np.zeros((4, 9)))["collides"])
    with pytest.raises(profrobot._core.ModelError):
        profrobot._core.RobotModel({**panda.core_arrays(), "geom_type": np.full(len(arrays["geom_type"]), 4, np.int32)})
