"""A field directory stores its robot (issue 37): ``PoseSDF.load(path)`` with no robot, for a
URDF cell with obstacles and a point cloud that no bundled name can rebuild; the fingerprint
check kept when a robot is passed; old directories without the robot say what to pass; and
:meth:`profrobot.Robot.load` runs none of a tampered file's code."""

from __future__ import annotations

import json
import os
import pickle

import numpy as np
import pytest
import torch

import profrobot
from profrobot import PointCloud, PoseSDF, Robot, Sphere
from profrobot.errors import CorruptFileError, MissingFileError, RobotMismatchError

from test_cli_robots import ARM_URDF


@pytest.fixture(scope="module")
def cell(tmp_path_factory) -> Robot:
    """The mimic arm from URDF (a post fixed to its base), a sphere added in Python and a cloud."""
    path = tmp_path_factory.mktemp("cell") / "arm.urdf"
    path.write_text(ARM_URDF)
    cloud = PointCloud(np.random.default_rng(0).uniform([-0.5, 0.3, 0.0], [0.5, 0.6, 0.8], (200, 3)), radius=0.01)
    robot = Robot.from_urdf(path).with_obstacles([Sphere(pos=(-0.3, -0.2, 0.4), radius=0.08), cloud])
    os.remove(path)   # the robot travels without its files
    return robot


def test_a_field_loads_from_its_directory_alone(cell, tmp_path):
    torch.manual_seed(0)
    sdf = PoseSDF(cell, hidden=(16,))
    sdf.save(tmp_path / "field")
    assert sorted(p.name for p in (tmp_path / "field").iterdir()) == ["config.json", "model.safetensors", "robot.pkl"]
    back = PoseSDF.load(tmp_path / "field")
    assert back.robot.fingerprint == cell.fingerprint and back.robot.cloud is not None
    poses = profrobot.sample_poses(cell, 3000, seed=1)
    np.testing.assert_array_equal(profrobot.collides(back.robot, poses), profrobot.collides(cell, poses))
    q = torch.as_tensor(poses[:50], dtype=torch.float32)
    with torch.no_grad():
        assert torch.equal(back(q), sdf(q))
    # a robot passed is still checked against the checkpoint
    assert PoseSDF.load(tmp_path / "field", cell).robot is cell
    with pytest.raises(RobotMismatchError, match="made for robot"):
        PoseSDF.load(tmp_path / "field", profrobot.scenes.load("panda_blocks"))
    # and the stored robot must be the one the weights were made for
    other = tmp_path / "other"
    PoseSDF(profrobot.scenes.load("ur5e_wall_box"), hidden=(8,)).save(other)
    os.replace(other / "robot.pkl", tmp_path / "field" / "robot.pkl")
    with pytest.raises(RobotMismatchError, match="stored robot"):
        PoseSDF.load(tmp_path / "field")


def test_a_family_field_stores_its_family(tmp_path):
    family = profrobot.scenes.load("panda_blocks_moving")
    PoseSDF(family, hidden=(8,)).save(tmp_path / "f")
    back = PoseSDF.load(tmp_path / "f")
    assert back.robot.is_family and back.robot.scene_joints == family.scene_joints
    assert back.robot.fingerprint == family.fingerprint


def test_a_directory_written_before_fields_stored_their_robot(cell, tmp_path):
    PoseSDF(cell, hidden=(8,)).save(tmp_path / "old")
    os.remove(tmp_path / "old" / "robot.pkl")
    with pytest.raises(MissingFileError, match="stores no robot.*PoseSDF.load\\(path, robot\\)"):
        PoseSDF.load(tmp_path / "old")
    assert PoseSDF.load(tmp_path / "old", cell).robot is cell


def test_save_and_load_robot_round_trip_and_refuse_what_is_not_a_robot(cell, tmp_path):
    path = cell.save(tmp_path / "cell.pkl")
    back = Robot.load(path)
    assert back.fingerprint == cell.fingerprint and back.joint_names == cell.joint_names
    assert oct(path.stat().st_mode & 0o777) == oct(0o666 & ~_umask())
    with pytest.raises(MissingFileError, match="no robot file"):
        Robot.load(tmp_path / "none.pkl")
    (tmp_path / "cut.pkl").write_bytes(path.read_bytes()[:1000])
    with pytest.raises(CorruptFileError, match="not a robot file"):
        Robot.load(tmp_path / "cut.pkl")
    (tmp_path / "list.pkl").write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(CorruptFileError, match="holds a list"):
        Robot.load(tmp_path / "list.pkl")
    with pytest.raises(profrobot.errors.InputTypeError, match="path must be a file path"):
        Robot.load(123)


class _Payload:
    """A pickle that would create a file when loaded: ``open(path, "w")`` via ``__reduce__``."""

    def __init__(self, path: str):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


class _ViaGetattr:
    """A pickle that reaches ``os.system`` through ``getattr`` on a profrobot class."""

    def __reduce__(self):
        return (getattr, (Robot, "__init__"))


def test_a_tampered_robot_file_runs_none_of_its_code(tmp_path):
    marker = tmp_path / "pwned"
    (tmp_path / "evil.pkl").write_bytes(pickle.dumps(_Payload(str(marker))))
    with pytest.raises(CorruptFileError, match="io.open"):
        Robot.load(tmp_path / "evil.pkl")
    assert not marker.exists()
    (tmp_path / "evil2.pkl").write_bytes(pickle.dumps(_ViaGetattr()))
    with pytest.raises(CorruptFileError, match="RobotModel._from_state only"):
        Robot.load(tmp_path / "evil2.pkl")
    # a name reached through a profrobot module is not a profrobot class
    (tmp_path / "evil3.pkl").write_bytes(b"\x80\x02cprofrobot.robot.robot\nnp\n.")
    with pytest.raises(CorruptFileError, match="profrobot.robot.robot.np"):
        Robot.load(tmp_path / "evil3.pkl")
    # a field directory holding such a file fails the same way, naming it
    field = tmp_path / "field"
    PoseSDF(profrobot.scenes.load("ur5e_wall_box"), hidden=(8,)).save(field)
    (field / "robot.pkl").write_bytes(pickle.dumps(_Payload(str(marker))))
    with pytest.raises(CorruptFileError, match="robot.pkl"):
        PoseSDF.load(field)
    assert not marker.exists()
    assert json.loads((field / "config.json").read_text())["robot"] == "ur5e_wall_box"


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
