"""The command line as a new user drives it on an arm: planning without a field and to a pose of a
frame, poses read from the files the commands write, negative numbers, progress lines in a log."""

from __future__ import annotations

import io

import mujoco
import numpy as np

import profrobot
from profrobot.cli.main import main
from profrobot.cli.robots import negative_values
from profrobot.exact import problems
from profrobot.executors import progress_bar


def _hand(robot, q) -> np.ndarray:
    m = robot.mj_model
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_adr] = q
    mujoco.mj_kinematics(m, d)
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = d.body("hand").xmat.reshape(3, 3), d.body("hand").xpos
    return t


def _text(q) -> str:
    return ",".join(f"{v:.9g}" for v in q)


def test_plan_without_a_field_between_poses_with_negative_numbers(tmp_path, capsys):
    robot = profrobot.scenes.load("panda_blocks")
    a, b = problems.hard_pairs(robot, 1, seed=2)
    a, b = a[0], b[0]

    out = tmp_path / "path.npz"
    code = main(["plan", "--scene", "panda_blocks", "--start", _text(a), "--goal", _text(b), "--out", str(out)])
    assert code == 0, capsys.readouterr()
    saved = np.load(out)
    assert bool(saved["certified"])
    np.testing.assert_allclose(saved["path"][0], a, atol=1e-9)
    np.testing.assert_allclose(saved["path"][-1], b, atol=1e-9)
    assert profrobot.check_path(robot, saved["path"]).certified
    # a pose whose first value is negative, typed after a space (argparse took it for an option)
    free = problems.free_poses(robot, 20, seed=8)
    neg, other = free[free[:, 0] < 0][0], free[free[:, 0] >= 0][0]
    assert _text(neg).startswith("-")
    assert main(["plan", "--start", _text(neg), "--goal", _text(other)]) == 0


def test_negative_values_are_values_not_options():
    assert negative_values(["plan", "--start", "-0.5,1.2", "--goal", "-1e-3,2"]) == \
        ["plan", "--start=-0.5,1.2", "--goal=-1e-3,2"]
    assert negative_values(["label", "-n", "-5"]) == ["label", "-n", "-5"]        # argparse's own case
    assert negative_values(["plan", "--start", "--goal", "1,2"]) == ["plan", "--start", "--goal", "1,2"]


def test_ik_then_plan_reads_the_poses_ik_wrote_and_plans_to_a_pose(tmp_path, capsys):
    robot = profrobot.scenes.load("panda_blocks")
    a, b = problems.free_poses(robot, 2, seed=11)
    targets = tmp_path / "targets.npy"
    np.save(targets, _hand(robot, b)[None])
    ik_out = tmp_path / "ik.npz"
    assert main(["ik", "--scene", "panda_blocks", "--frame", "hand", "--targets", str(targets),
                 "--start", _text(a), "--out", str(ik_out)]) == 0
    path = tmp_path / "path.npz"
    np.save(tmp_path / "start.npy", a)
    assert main(["plan", "--start", str(tmp_path / "start.npy"), "--goal", f"{ik_out}:0", "--out", str(path)]) == 0
    np.testing.assert_allclose(np.load(path)["path"][-1], np.load(ik_out)["poses"][0], atol=1e-9)
    # the same target as a pose of the frame, no IK file: x,y,z,qw,qx,qy,qz
    t = _hand(robot, b)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, t[:3, :3].ravel())
    motion = tmp_path / "motion.npz"
    code = main(["plan", "--start", _text(a), "--frame", "hand", "--target", _text(np.r_[t[:3, 3], quat]),
                 "--out", str(motion)])
    printed = capsys.readouterr().out
    assert code == 0 and "motion to hand: certified" in printed
    end = np.load(motion)["path"][-1]
    assert np.linalg.norm(_hand(robot, end)[:3, 3] - t[:3, 3]) <= 1e-4
    # a target out of reach is a result (exit 1), not a crash
    assert main(["plan", "--start", _text(a), "--frame", "hand", "--target", "5,0,0.5"]) == 1
    assert "no candidate reached" in capsys.readouterr().out


def test_bad_pose_files_name_the_option(tmp_path, capsys):
    assert main(["plan", "--start", str(tmp_path / "missing.npy"), "--goal", "0,0"]) == 2
    assert "--start" in capsys.readouterr().err
    np.savez(tmp_path / "x.npz", other=np.zeros(3))
    assert main(["plan", "--start", str(tmp_path / "x.npz"), "--goal", "0,0"]) == 2
    assert "no 'poses' or 'path'" in capsys.readouterr().err


def test_progress_goes_into_a_log_as_lines():
    log = io.StringIO()   # not a terminal
    with progress_bar(1000, desc="train panda", unit="it", stream=log) as bar:
        for _ in range(10):
            bar.update(100)
    lines = log.getvalue().splitlines()
    assert lines and all("\r" not in ln for ln in lines)
    assert "train panda" in lines[-1] and "100%" in lines[-1] and "1000/1000" in lines[-1]
    quiet = io.StringIO()
    with progress_bar(10, desc="quiet", progress=False, stream=quiet) as bar:
        bar.update(10)
    assert quiet.getvalue() == ""


def test_a_missing_mesh_says_where_mujoco_looked(tmp_path, capsys):
    xml = tmp_path / "arm.xml"
    xml.write_text('<mujoco><compiler meshdir="meshes"/><asset><mesh name="m" file="asset/Base.stl"/></asset>'
                   '<worldbody><body><joint type="hinge"/><geom type="mesh" mesh="m"/></body></worldbody></mujoco>')
    where = str(tmp_path / "meshes" / "asset" / "Base.stl")
    try:
        profrobot.Robot.from_mjcf(xml)
    except profrobot.MissingFileError as e:
        assert where in str(e) and "meshdir='meshes'" in str(e)
    else:
        raise AssertionError("a missing mesh was not refused")
    assert main(["label", "--robot", str(xml), "-n", "10"]) == 2
    assert where in capsys.readouterr().err
