"""Robots from URDF (issue 20): ``Robot.from_urdf`` resolves ``package://`` and relative mesh
names, MuJoCo's URDF compiler builds the robot (labels agree with MuJoCo), continuous and mimic
joints map to unlimited hinges and joint equalities, what cannot be taken fails naming the file
and what to pass, and link pairs that collide in every pose are warned about or disabled
(``srdf=``, ``collision_matrix="auto"``) as MuJoCo ``<exclude>``s.

Every URDF here is written for the purpose, with its meshes (binary STL and OBJ from numpy)."""

from __future__ import annotations

import copy
import os
import pickle
import struct
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

import profrobot
from profrobot import Box, Robot
from profrobot.errors import InputError
from profrobot.robot.urdf import UrdfWarning

N_CHECK = 5000


def box_mesh(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def write_stl(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    tri = v[f].astype(np.float32)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    rec = np.zeros(len(f), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["n"], rec["v"] = n, tri
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\0" * 80 + struct.pack("<I", len(f)) + rec.tobytes())


def write_obj(path: Path, v: np.ndarray, f: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in v)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))


def arm_urdf(link_mesh="package://mypkg/meshes/link.stl", bar_mesh="meshes/bar.obj", base_extra="",
             base_joint="") -> str:
    """A 4-link arm: box base, l1 (cylinder + package:// STL), l2 (relative-path OBJ), l3 on a
    continuous joint (sphere + the same STL), two mesh fingers, the second mimicking the first."""
    return f"""<?xml version="1.0"?>
<robot name="toyarm">
  <material name="grey"><color rgba="0.5 0.5 0.5 1"/></material>
  {base_joint}
  <link name="base">
    <visual><geometry><mesh filename="package://mypkg/meshes/base_visual.dae"/></geometry></visual>
    <collision><origin xyz="0 0 0.05"/><geometry><box size="0.3 0.3 0.1"/></geometry></collision>
    {base_extra}
  </link>
  <link name="l1">
    <inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.16"/><geometry><cylinder radius="0.05" length="0.3"/></geometry></collision>
    <collision><origin xyz="0.03 0 0" rpy="0 0 0.3"/><geometry><mesh filename="{link_mesh}"/></geometry></collision>
  </link>
  <link name="l2">
    <collision><geometry><mesh filename="{bar_mesh}"/></geometry></collision>
  </link>
  <link name="l3">
    <collision><origin xyz="0.06 0 0.05"/><geometry><sphere radius="0.045"/></geometry></collision>
    <collision><origin xyz="0 0 0.02" rpy="1.5707963 0 0"/><geometry><mesh filename="{link_mesh}" scale="0.6 0.6 0.6"/></geometry></collision>
  </link>
  <link name="finger_a"><collision><geometry><mesh filename="{bar_mesh}" scale="0.3 0.3 0.27"/></geometry></collision></link>
  <link name="finger_b"><collision><origin xyz="0 0 -0.01"/><geometry><mesh filename="{link_mesh}" scale="0.35 0.35 0.36"/></geometry></collision></link>
  <link name="tool0"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-2.8" upper="2.8" effort="10" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.09 0 0.32"/>
    <axis xyz="0 1 0"/><limit lower="-2.9" upper="2.9" effort="10" velocity="1"/></joint>
  <joint name="j3" type="continuous"><parent link="l2"/><child link="l3"/><origin xyz="0 0 0.34" rpy="0 0.2 0"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="10" velocity="1"/></joint>
  <joint name="fa" type="revolute"><parent link="l3"/><child link="finger_a"/><origin xyz="0.05 0 0.09"/>
    <axis xyz="0 1 0"/><limit lower="-0.6" upper="0.6" effort="1" velocity="1"/></joint>
  <joint name="fb" type="revolute"><parent link="l3"/><child link="finger_b"/><origin xyz="-0.05 0 0.09"/>
    <axis xyz="0 1 0"/><limit lower="-0.9" upper="0.9" effort="1" velocity="1"/>
    <mimic joint="fa" multiplier="-1.0" offset="0.1"/></joint>
  <joint name="flange" type="fixed"><parent link="l3"/><child link="tool0"/><origin xyz="0 0 0.1"/></joint>
</robot>
"""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The arm on disk: robot/arm.urdf, robot/meshes/bar.obj, ws/mypkg/meshes/link.stl."""
    root = tmp_path_factory.mktemp("urdf")
    write_stl(root / "ws" / "mypkg" / "meshes" / "link.stl", *box_mesh((-0.03, -0.03, 0.03), (0.03, 0.03, 0.28)))
    write_obj(root / "robot" / "meshes" / "bar.obj", *box_mesh((-0.035, -0.03, 0.0), (0.035, 0.03, 0.3)))
    (root / "robot" / "arm.urdf").write_text(arm_urdf())
    return root


@pytest.fixture(scope="module")
def arm(files):
    with warnings.catch_warnings():
        warnings.simplefilter("error", UrdfWarning)   # the plain arm has no always-colliding pair
        return Robot.from_urdf(files / "robot" / "arm.urdf", package_dirs={"mypkg": files / "ws" / "mypkg"})


def test_loads_with_its_joints_limits_and_meshes(arm):
    assert arm.name == "toyarm"
    assert arm.joint_names == ["j1", "j2", "j3", "fa", "fb"]
    np.testing.assert_allclose(arm.joint_limits[[0, 1, 3, 4]], [[-2.8, 2.8], [-2.9, 2.9], [-0.6, 0.6], [-0.9, 0.9]])
    # continuous even though its <limit> names lower/upper (URDF ignores them for continuous joints)
    assert arm.continuous.tolist() == [False, False, True, False, False]
    np.testing.assert_allclose(arm.joint_limits[2], [-np.pi, np.pi])
    m = arm.mj_model
    assert m.nmesh == 5   # link.stl at three scales, bar.obj at two; the .dae visual was never read
    assert {"base", "l1", "tool0"} <= set(arm.body_names)   # links kept as bodies
    types = {g["type"] for g in arm.geom_table()}
    assert {"box", "cylinder", "sphere", "mesh"} <= types
    assert "collides in" in arm.collision_report() and arm.disabled_pairs == ()


def test_labels_agree_with_mujoco(arm):
    poses = profrobot.sample_poses(arm, 100_000, seed=3)   # issue 20's acceptance count (about 2 s)
    labels = profrobot.label_poses(arm, poses)
    assert 0.05 < labels.collides.mean() < 0.95, labels.summary()   # the check sees both kinds
    report = profrobot.crosscheck(arm, poses, progress=False)
    assert report.agreement == 1.0 and report.pair_agreement == 1.0, report.summary()
    # contacts of every kind the URDF has: mesh-mesh, mesh-box, mesh-cylinder, sphere-box
    kinds = profrobot.label_poses(arm, poses, pairs=True).colliding_pairs[:, 1]
    types = {g["id"]: g["type"] for g in arm.geom_table()}
    seen = {tuple(sorted((types[a], types[b]))) for a, b in arm.pair_geoms[np.unique(kinds)].tolist()}
    assert {("mesh", "mesh"), ("box", "mesh"), ("cylinder", "mesh"), ("box", "sphere")} <= seen, seen


def test_same_labels_as_mujocos_own_compile_of_the_file(files, arm):
    # MuJoCo alone can read the file once every mesh is a path it can open; its compile (default
    # URDF settings: the base link fused into the world) gives the same labels as ours
    text = arm_urdf(link_mesh="../ws/mypkg/meshes/link.stl").replace(
        '<visual><geometry><mesh filename="package://mypkg/meshes/base_visual.dae"/></geometry></visual>', "")
    path = files / "robot" / "plain.urdf"
    path.write_text(text)
    raw = Robot.from_model(mujoco.MjModel.from_xml_path(str(path)), name="raw")
    assert "base" not in raw.body_names   # MuJoCo's default compile fused it
    poses = profrobot.sample_poses(arm, N_CHECK, seed=4)
    np.testing.assert_array_equal(profrobot.collides(raw, poses), profrobot.collides(arm, poses))


def test_mimic_is_a_joint_coupling(arm):
    eq = [e for e in arm.equalities if e.kind == "joint"]
    assert len(eq) == 1 and (eq[0].obj1, eq[0].obj2) == ("fb", "fa")
    np.testing.assert_allclose(eq[0].polycoef, [0.1, -1.0, 0, 0, 0])
    poses = profrobot.sample_poses(arm, 500, seed=1)
    np.testing.assert_allclose(poses[:, 4], 0.1 - poses[:, 3], atol=1e-12)
    assert np.ptp(poses[:, 3]) > 0.5
    assert "fb = -1·fa + 0.1" in arm.collision_report()


def test_package_dirs_as_a_list_and_ros_package_path(files, arm, monkeypatch):
    path = files / "robot" / "arm.urdf"
    listed = Robot.from_urdf(path, package_dirs=[files / "nowhere", files / "ws"])
    assert listed.fingerprint == arm.fingerprint
    monkeypatch.setenv("ROS_PACKAGE_PATH", os.pathsep.join([str(files / "nowhere"), str(files / "ws")]))
    assert Robot.from_urdf(path).fingerprint == arm.fingerprint
    assert Robot.from_mjcf(path).fingerprint == arm.fingerprint   # from_mjcf hands a .urdf over


def test_pickle_deepcopy_and_obstacles_after_unpickling(files, arm):
    poses = profrobot.sample_poses(arm, 2000, seed=5)
    want = profrobot.label_poses(arm, poses, pairs=True)
    box = Box(pos=(0.25, 0.0, 0.3), half_size=(0.05, 0.05, 0.2), name="post")
    direct = arm.with_obstacles([box])
    for copied in (pickle.loads(pickle.dumps(arm, protocol=pickle.HIGHEST_PROTOCOL)), copy.deepcopy(arm)):
        assert copied.fingerprint == arm.fingerprint and copied.name == arm.name
        got = profrobot.label_poses(copied, poses, pairs=True)
        np.testing.assert_array_equal(got.collides, want.collides)
        np.testing.assert_array_equal(got.colliding_pairs, want.colliding_pairs)
    # unpickled where the URDF and meshes are gone: the pickle carries them
    blob = pickle.dumps(arm)
    moved = files.parent / (files.name + "_gone")
    files.rename(moved)
    try:
        back = pickle.loads(blob)
        scene = back.with_obstacles([box])
        assert scene.fingerprint == direct.fingerprint
        np.testing.assert_array_equal(profrobot.collides(scene, poses), profrobot.collides(direct, poses))
        assert profrobot.crosscheck(scene, poses, progress=False).agreement == 1.0
    finally:
        moved.rename(files)


def test_missing_mesh_names_the_file_the_uri_and_what_to_pass(files):
    path = files / "robot" / "missing.urdf"
    path.write_text(arm_urdf(link_mesh="package://mypkg/meshes/nope.stl"))
    with pytest.raises(InputError) as e:
        Robot.from_urdf(path, package_dirs={"mypkg": files / "ws" / "mypkg"})
    msg = str(e.value)
    assert str(path) in msg and "package://mypkg/meshes/nope.stl" in msg
    assert str(files / "ws" / "mypkg" / "meshes" / "nope.stl") in msg and "package_dirs={'mypkg'" in msg

    path.write_text(arm_urdf(bar_mesh="meshes/gone.obj"))
    with pytest.raises(InputError, match="gone.obj") as e:
        Robot.from_urdf(path, package_dirs={"mypkg": files / "ws" / "mypkg"})
    assert str(files / "robot" / "meshes" / "gone.obj") in str(e.value)


def test_unknown_package_says_where_it_looked_and_what_to_pass(files, monkeypatch):
    monkeypatch.delenv("ROS_PACKAGE_PATH", raising=False)
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    path = files / "robot" / "other.urdf"
    path.write_text(arm_urdf(link_mesh="package://otherpkg/meshes/link.stl"))
    with pytest.raises(InputError) as e:
        Robot.from_urdf(path, package_dirs=[files / "ws"])
    msg = str(e.value)
    assert str(path) in msg and "package://otherpkg/meshes/link.stl" in msg
    assert "package_dirs={'otherpkg': '/path/to/otherpkg'}" in msg and str(files / "ws" / "otherpkg") in msg


@pytest.mark.parametrize("kind", ["floating", "planar"])
def test_floating_base_is_refused_naming_the_joint(files, kind):
    path = files / "robot" / f"{kind}.urdf"
    joint = (f'<link name="world"/><joint name="base_{kind}" type="{kind}"><parent link="world"/>'
             '<child link="base"/></joint>')
    path.write_text(arm_urdf(base_joint=joint))
    with pytest.raises(InputError, match=f"'base_{kind}'.*fixed") as e:
        Robot.from_urdf(path, package_dirs={"mypkg": files / "ws" / "mypkg"})
    assert str(path) in str(e.value)


# --------------------------------------------------------------------------------------------
# A base link that overlaps link 1: MuJoCo labels every pose colliding
# --------------------------------------------------------------------------------------------

POST = ('<collision name="post"><origin xyz="0 0 0.25"/>'
        '<geometry><cylinder radius="0.07" length="0.3"/></geometry></collision>')


@pytest.fixture(scope="module")
def overlapping(files):
    path = files / "robot" / "overlap.urdf"
    path.write_text(arm_urdf(base_extra=POST))
    return path


def _pair_mask(robot, labels, a, b):
    """Per pose: whether some colliding pair is not between bodies a and b."""
    gb = robot.mj_model.geom_bodyid
    names = np.asarray(robot.body_names)
    bodies = names[gb[robot.pair_geoms]]
    is_ab = ((bodies[:, 0] == a) & (bodies[:, 1] == b)) | ((bodies[:, 0] == b) & (bodies[:, 1] == a))
    cp = labels.colliding_pairs
    other = np.zeros(len(labels), bool)
    other[cp[~is_ab[cp[:, 1]], 0]] = True
    return other


def test_base_overlapping_link1_warns_and_auto_matrix_disables_it(files, overlapping):
    dirs = {"mypkg": files / "ws" / "mypkg"}
    with pytest.warns(UrdfWarning, match="base–l1 \\(100.0 %\\)"):
        plain = Robot.from_urdf(overlapping, package_dirs=dirs)
    poses = profrobot.sample_poses(plain, N_CHECK, seed=7)
    labels = profrobot.label_poses(plain, poses, pairs=True)
    assert labels.collides.all()   # MuJoCo's semantics: every pose collides
    assert "base – l1: 100.0 %" in plain.collision_report()

    with warnings.catch_warnings():
        warnings.simplefilter("error", UrdfWarning)
        auto = Robot.from_urdf(overlapping, package_dirs=dirs, collision_matrix="auto")
    assert [p[:2] for p in auto.disabled_pairs] == [("base", "l1")]   # nothing else
    assert auto.disabled_pairs[0].reason.startswith("Adjacent")
    got = profrobot.collides(auto, poses)
    np.testing.assert_array_equal(got, _pair_mask(plain, labels, "base", "l1"))   # what the geometry implies
    assert got.mean() < 0.9
    assert profrobot.crosscheck(auto, poses, progress=False).agreement == 1.0
    report = auto.collision_report()
    assert "base – l1: Adjacent" in report and "before the matrix" in report
    back = pickle.loads(pickle.dumps(auto))
    assert back.fingerprint == auto.fingerprint and back.disabled_pairs == auto.disabled_pairs
    np.testing.assert_array_equal(profrobot.collides(back.with_obstacles([]), poses), got)


def test_srdf_disables_exactly_the_listed_pair(files, overlapping, arm):
    srdf = files / "robot" / "arm.srdf"
    srdf.write_text('<robot name="toyarm"><group name="arm"><chain base_link="base" tip_link="l3"/></group>'
                    '<disable_collisions link1="l1" link2="base" reason="Adjacent"/></robot>')
    with warnings.catch_warnings():
        warnings.simplefilter("error", UrdfWarning)
        robot = Robot.from_urdf(overlapping, package_dirs={"mypkg": files / "ws" / "mypkg"}, srdf=srdf)
    assert robot.disabled_pairs == (("l1", "base", "SRDF: Adjacent"),)
    ids = {n: i for i, n in enumerate(robot.body_names)}
    assert sorted(map(tuple, robot.core_arrays()["exclude"])) == [tuple(sorted((ids["base"], ids["l1"])))]
    with pytest.warns(UrdfWarning):
        default = Robot.from_urdf(overlapping, package_dirs={"mypkg": files / "ws" / "mypkg"})
    poses = profrobot.sample_poses(robot, 3000, seed=8)
    labels = profrobot.label_poses(default, poses, pairs=True)
    np.testing.assert_array_equal(profrobot.collides(robot, poses), _pair_mask(default, labels, "base", "l1"))
    names = np.asarray(default.body_names)[default.mj_model.geom_bodyid]
    kept = {tuple(g) for g in default.pair_geoms.tolist() if {names[g[0]], names[g[1]]} != {"base", "l1"}}
    assert {tuple(g) for g in robot.pair_geoms.tolist()} == kept   # only base–l1 pairs went
    assert len(kept) == len(default.pair_geoms) - 4                # base's 2 geoms × l1's 2


def test_revolute_without_limits_is_continuous_and_xacro_is_refused(files):
    dirs = {"mypkg": files / "ws" / "mypkg"}
    path = files / "robot" / "nolimit.urdf"
    path.write_text(arm_urdf().replace('<limit lower="-2.8" upper="2.8" effort="10" velocity="1"/>', ""))
    with pytest.warns(UrdfWarning, match="'j1'.*continuous"):
        robot = Robot.from_urdf(path, package_dirs=dirs)
    assert robot.continuous[:3].tolist() == [True, False, True]
    path.write_text(arm_urdf().replace('<robot name="toyarm">', '<robot name="toyarm" xmlns:xacro="http://www.ros.org/wiki/xacro">'
                                       '<xacro:property name="r" value="0.1"/>'))
    with pytest.raises(InputError, match="xacro"):
        Robot.from_urdf(path, package_dirs=dirs)


def test_unphysical_inertias_load_balanced_or_replaced_and_named_in_the_report(files):
    # issue 37: UFactory's xArm6 URDF has links whose principal moments break A + B >= C, which
    # MuJoCo's compiler refuses; labels do not depend on inertia, so such files load, and the
    # collision report names each link changed and how
    text = arm_urdf().replace(
        '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>',
        '<inertia ixx="0.001" iyy="0.0012" izz="0.01" ixy="0.0001" ixz="0" iyz="0"/>').replace(
        '<link name="l2">',
        '<link name="l2"><inertial><mass value="0.5"/><inertia ixx="0.01" iyy="-0.002" izz="0.01" ixy="0" ixz="0" '
        'iyz="0"/></inertial>')
    path = files / "robot" / "inertia.urdf"
    path.write_text(text)
    plain = files / "robot" / "inertia_plain.urdf"   # MuJoCo's own compile, meshes as paths: refused
    plain.write_text(text.replace("package://mypkg/meshes/link.stl", "../ws/mypkg/meshes/link.stl").replace(
        '<visual><geometry><mesh filename="package://mypkg/meshes/base_visual.dae"/></geometry></visual>', ""))
    with pytest.raises(ValueError, match="A \\+ B >= C"):
        mujoco.MjModel.from_xml_path(str(plain))

    robot = Robot.from_urdf(path, package_dirs={"mypkg": files / "ws" / "mypkg"})
    report = robot.collision_report()
    assert "l1: principal moments" in report and "balanceinertia" in report, report
    assert "l2: principal moments" in report and "not all positive; replaced by diag(" in report, report
    assert "finger_a" not in report.split("inertias")[1].split("collisions")[0]   # only the links changed
    m = robot.mj_model
    l1, l2 = robot.body_names.index("l1"), robot.body_names.index("l2")
    np.testing.assert_allclose(m.body_inertia[l1], np.full(3, m.body_inertia[l1].mean()))   # balanced
    assert (m.body_inertia[l2] > 0).all()
    poses = profrobot.sample_poses(robot, N_CHECK, seed=5)
    assert profrobot.crosscheck(robot, poses, progress=False).agreement == 1.0
    np.testing.assert_array_equal(profrobot.collides(robot, poses),
                                  profrobot.collides(pickle.loads(pickle.dumps(robot)), poses))

    # a file that asks for MuJoCo's refusal gets it, naming the link
    path.write_text(text.replace('<robot name="toyarm">',
                                 '<robot name="toyarm"><mujoco><compiler balanceinertia="false"/></mujoco>'))
    with pytest.raises(InputError, match="A \\+ B >= C.*l1"):
        Robot.from_urdf(path, package_dirs={"mypkg": files / "ws" / "mypkg"})
