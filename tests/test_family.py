"""Families of scenes (profrobot.robot.family): obstacles on scene joints δ, labelled like MuJoCo at every
layout, pinned into static scenes, and the field g(θ, δ) used at a layout with certification there."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
import torch

import profrobot
from profrobot import InputError, RobotMismatchError
from profrobot.exact.crosscheck import crosscheck, mujoco_labels
from profrobot.robot.family import Moves
from profrobot.robot import Box, Plane, Sphere

ARM_XML = """
<mujoco model="arm2">
  <compiler angle="radian"/>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.05"/>
    <body name="base" pos="0 0 0.1">
      <geom type="cylinder" size="0.06 0.05"/>
      <body name="l1" pos="0 0 0.05">
        <joint name="j1" type="hinge" axis="0 0 1" range="-3 3"/>
        <geom type="capsule" fromto="0 0 0 0.35 0 0" size="0.03"/>
        <body name="l2" pos="0.35 0 0">
          <joint name="j2" type="hinge" axis="0 0 1" range="-2.5 2.5"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03"/>
        </body>
      </body>
    </body>
    <body name="crate" pos="0.45 0.2 0.15">
      <joint name="crate_x" type="slide" axis="1 0 0" range="-0.1 0.1"/>
      <joint name="crate_yaw" type="hinge" axis="0 0 1" range="-0.6 0.6"/>
      <geom type="box" size="0.06 0.04 0.1"/>
    </body>
  </worldbody>
  {custom}
</mujoco>
"""


@pytest.fixture(scope="module")
def family():
    return profrobot.scenes.load("panda_blocks_moving")


@pytest.fixture(scope="module")
def tiny_field(family):
    data = profrobot.make_dataset(family, 20_000, seed=0, progress=False)
    return profrobot.train_sdf(data, robot=family, iterations=40, hidden=(64, 64), eikonal_batch=64,
                               batch_size=2048, progress=False, seed=0)


def layouts(family, n, seed):
    return profrobot.sample_poses(family, n, seed=seed)[:, family.scene_index]


# ---- the family API and its labels --------------------------------------------------------------

def test_family_joints_and_ranges(family):
    assert family.is_family and family.njoint == 18
    assert family.scene_joints == tuple(f"block_{b}_{c}" for b in ("front", "left", "right") for c in ("x", "y", "yaw"))
    lim = family.joint_limits[family.scene_index]
    np.testing.assert_allclose(lim[[0, 1]], [[-0.15, 0.15]] * 2)
    np.testing.assert_allclose(lim[2], [-math.pi / 4, math.pi / 4])
    assert list(family.robot_index) == list(range(9))


def test_family_labels_agree_with_mujoco_on_theta_delta_pairs(family):
    report = crosscheck(family, profrobot.sample_poses(family, 3000, seed=11), progress=False)
    assert report.agreement == 1.0 and report.pair_agreement == 1.0
    assert 0.05 < report.confusion[1].sum() / 3000 < 0.6  # both classes present


def test_layout_zero_is_the_static_scene(family):
    """δ = 0 pins every block where panda_blocks has it: identical labels on 20 000 poses."""
    ref = profrobot.scenes.load("panda_blocks")
    q = profrobot.sample_poses(ref, 20_000, seed=3)
    at0 = family.at(np.zeros(9))
    assert at0.joint_names == ref.joint_names and not at0.is_family
    np.testing.assert_array_equal(profrobot.label_poses(at0, q).collides, profrobot.label_poses(ref, q).collides)


def test_pinned_layouts_label_like_the_family_and_like_mujoco(family):
    for delta in layouts(family, 3, seed=21):
        static = family.at(delta)
        np.testing.assert_array_equal(static.layout, delta)
        assert static.family_fingerprint == family.fingerprint
        q = profrobot.sample_poses(static, 3000, seed=4)
        ours = profrobot.label_poses(static, q).collides
        np.testing.assert_array_equal(ours, profrobot.label_poses(family, family.compose(q, delta)).collides)
        np.testing.assert_array_equal(ours, mujoco_labels(static, q, progress=False).collides)


def test_moving_a_block_changes_the_labels(family):
    """A layout is not a no-op: moving the front block 15 cm changes some poses' labels."""
    q = profrobot.sample_poses(family.at(np.zeros(9)), 5000, seed=8)
    moved = np.zeros(9)
    moved[0] = 0.15
    a = profrobot.label_poses(family.at(np.zeros(9)), q).collides
    b = profrobot.label_poses(family.at(moved), q).collides
    assert 0 < np.sum(a != b) < len(q) // 4


def test_scene_joints_from_mjcf_text_and_with_scene_joints(tmp_path):
    text = '<custom><text name="profrobot:scene_joints" data="crate_x crate_yaw"/></custom>'
    unexcluded = tmp_path / "unexcluded.xml"
    unexcluded.write_text(ARM_XML.replace("{custom}", text))
    # a marked model must keep its scene bodies off the world, else a pinned layout (where MuJoCo
    # filters the pair) would label unlike the family: refused, with the lines to add
    with pytest.raises(InputError, match=r'(?s)lacks 1 <exclude>.*<exclude body1="world" body2="crate"/>'):
        profrobot.Robot.from_mjcf(unexcluded)
    marked = tmp_path / "marked.xml"
    marked.write_text(ARM_XML.replace("{custom}", text + '<contact><exclude body1="world" body2="crate"/></contact>'))
    plain = tmp_path / "plain.xml"
    plain.write_text(ARM_XML.replace("{custom}", ""))
    a = profrobot.Robot.from_mjcf(marked)
    assert a.scene_joints == ("crate_x", "crate_yaw") and list(a.robot_index) == [0, 1]
    q = profrobot.sample_poses(a, 2000, seed=5)
    static = a.at([0.1, -0.6])
    np.testing.assert_array_equal(profrobot.label_poses(static, q[:, :2]).collides,
                                  profrobot.label_poses(a, a.compose(q[:, :2], [0.1, -0.6])).collides)
    b = profrobot.Robot.from_mjcf(plain)
    assert not b.is_family
    fam = b.with_scene_joints(["crate_x", "crate_yaw"])
    assert fam.scene_joints == ("crate_x", "crate_yaw")
    # with_scene_joints excludes crate–floor contacts (the crate rests on nothing, but a moved crate
    # would touch the world's geoms); MuJoCo compiles the same excludes: labels agree
    report = crosscheck(fam, profrobot.sample_poses(fam, 2000, seed=1), progress=False)
    assert report.agreement == 1.0
    static = fam.at([0.05, 0.3])
    assert static.joint_names == ["j1", "j2"]
    q = profrobot.sample_poses(static, 2000, seed=2)
    np.testing.assert_array_equal(profrobot.label_poses(static, q).collides,
                                  mujoco_labels(static, q, progress=False).collides)
    with pytest.raises(InputError, match="no joint named 'nope'"):
        b.with_scene_joints(["nope"])


def test_family_pickles_and_its_layouts_rebuild(family):
    delta = layouts(family, 1, seed=5)[0]
    copy = pickle.loads(pickle.dumps(family))
    assert copy.fingerprint == family.fingerprint and copy.scene_joints == family.scene_joints
    assert copy.at(delta).fingerprint == family.at(delta).fingerprint
    static = pickle.loads(pickle.dumps(family.at(delta)))
    np.testing.assert_array_equal(static.layout, delta)
    assert static.spec is not None  # rebuilt from the family's files and the pinning edit


# ---- bad input ------------------------------------------------------------------------------------

def test_bad_layouts_are_refused_by_name(family):
    d = np.zeros(9)
    with pytest.raises(InputError, match=r"shape \(9,\)"):
        family.at(d[:3])
    bad = d.copy()
    bad[4] = np.nan
    with pytest.raises(InputError, match=r"layout\[4\] \(block_left_y\) is nan"):
        family.at(bad)
    bad[4] = 0.4
    with pytest.raises(InputError, match=r"layout\[4\] \(block_left_y\) = 0.4 is outside the family's range"):
        family.at(bad)
    with pytest.raises(InputError, match="missing"):
        family.at({"block_front_x": 0.0})
    with pytest.raises(InputError, match="not a family"):
        profrobot.scenes.load("panda_blocks").at(d)


def test_bad_moves_are_refused():
    arm = profrobot.Robot.from_menagerie("franka_emika_panda", "panda")
    with pytest.raises(InputError, match="low < high"):
        arm.with_obstacles([Box(pos=(0.5, 0, 0.1), name="b", moves=Moves(x=(0.1, -0.1)))])
    with pytest.raises(InputError, match="needs a name"):
        arm.with_obstacles([Box(pos=(0.5, 0, 0.1), moves=Moves(x=(-0.1, 0.1)))])
    with pytest.raises(InputError, match="plane cannot move"):
        arm.with_obstacles([Plane(pos=(0, 0, 0), name="f", moves=Moves(z=(-0.1, 0.1)))])
    with pytest.raises(InputError, match="moves nothing"):
        arm.with_obstacles([Box(pos=(0.5, 0, 0.1), name="b", moves=Moves())])
    with pytest.raises(InputError, match="more than a full turn"):
        arm.with_obstacles([Box(pos=(0.5, 0, 0.1), name="b", moves=Moves(yaw=(-4, 4)))])


def test_a_layout_inside_the_robots_base_is_refused():
    arm = profrobot.Robot.from_menagerie("franka_emika_panda", "panda")
    fam = arm.with_obstacles([Sphere(pos=(0.4, 0, 0.05), radius=0.05, name="ball", moves=Moves(x=(-0.4, 0.2)))])
    fam.at([0.0])  # clear of the base
    with pytest.raises(InputError, match="overlaps 'link0'.*every pose would collide"):
        fam.at([-0.4])  # the ball at the origin, inside link0


def test_regression_a_layout_within_the_clearance_of_the_base_is_refused():
    """Issue 33: a ball 0.5 µm from the base was accepted by ``at``. On the family that pair is
    checked (nothing certifies), pinned it is filtered (everything may): they disagreed."""
    import mujoco

    arm = profrobot.Robot.from_menagerie("franka_emika_panda", "panda")
    fam = arm.with_obstacles([Sphere(pos=(0.4, 0, 0.05), radius=0.05, name="ball", moves=Moves(x=(-0.4, 0.2)))])
    m, d = fam.mj_model, mujoco.MjData(fam.mj_model)
    ball = m.body("ball").geomadr[0]
    base = [g for g in range(m.ngeom) if m.geom_bodyid[g] == m.body("link0").id and m.geom_contype[g]]

    def gap(x: float) -> float:
        d.qpos[fam.qpos_adr[fam.scene_index]] = x
        mujoco.mj_kinematics(m, d)
        return min(mujoco.mj_geomDistance(m, d, ball, g, 1.0, None) for g in base)

    lo, hi = -0.4, 0.0                       # inside the base .. clear of it
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gap(mid) < 5e-7 else (lo, mid)
    assert 0 < gap(hi) <= 1e-6
    theta = profrobot.exact.problems.free_poses(fam.at([0.0]), 20, seed=0)
    assert not profrobot.certify_poses(fam, theta, layout=[hi]).any()   # the family certifies nothing here
    with pytest.raises(InputError, match="is .* m from 'link0'.*clearance"):
        fam.at([hi])


# ---- the field g(θ, δ) ---------------------------------------------------------------------------

def test_family_field_inputs_and_layout_field(family, tiny_field):
    sdf = tiny_field
    assert sdf.scene_joints == list(family.scene_joints)
    delta = layouts(family, 2, seed=9)
    q = torch.as_tensor(profrobot.sample_poses(family.at(delta[0]), 64, seed=1), dtype=torch.float32)
    full = torch.as_tensor(family.compose(q.double().numpy(), delta[0]), dtype=torch.float32)
    g = sdf(full)
    torch.testing.assert_close(sdf(q, layout=delta[0]), g)
    at = sdf.at(delta[0])
    torch.testing.assert_close(at(q), g)
    assert at.njoint == 9 and at.robot.fingerprint == family.at(delta[0]).fingerprint
    # one layout per pose
    both = sdf(q[:2], layout=delta)
    torch.testing.assert_close(both[1], sdf(q[1:2], layout=delta[1])[0])
    # the layout matters to the field
    assert not torch.allclose(sdf(q, layout=delta[0]), sdf(q, layout=delta[1]))
    # gradients reach θ only through a LayoutField
    x = q.clone().requires_grad_(True)
    at(x).sum().backward()
    assert x.grad.shape == (64, 9) and torch.isfinite(x.grad).all()
    copy = pickle.loads(pickle.dumps(at))
    torch.testing.assert_close(copy(q), at(q))


def test_eikonal_is_taken_over_the_robot_joints(tiny_field, family):
    from profrobot.field.train import eikonal_terms

    q = torch.as_tensor(profrobot.sample_poses(family, 32, seed=3), dtype=torch.float32).requires_grad_(True)
    (grad,) = torch.autograd.grad(tiny_field(q).sum(), q)
    want = ((grad[:, :9].norm(dim=1) - 1) ** 2).mean()
    eik, _ = eikonal_terms(tiny_field, q.detach())
    torch.testing.assert_close(eik, want)


def test_family_field_save_load_and_mismatch(tmp_path, family, tiny_field):
    path = tiny_field.save(tmp_path / "fam")
    import json

    cfg = json.loads((path / "config.json").read_text())
    assert cfg["family"]["scene_joints"] == list(family.scene_joints)
    np.testing.assert_allclose(cfg["family"]["ranges"][0], [-0.15, 0.15])
    back = profrobot.PoseSDF.load(path, family)
    q = torch.as_tensor(profrobot.sample_poses(family, 16, seed=2), dtype=torch.float32)
    torch.testing.assert_close(back(q), tiny_field(q))
    # another family (wider ranges): another fingerprint
    arm = profrobot.Robot.from_menagerie("franka_emika_panda", "panda")
    wider = Moves(x=(-0.2, 0.2), y=(-0.15, 0.15), yaw=(-math.pi / 4, math.pi / 4))
    other = arm.with_obstacles([Plane(pos=(0, 0, 0), name="floor"),
                                Box(pos=(0.55, 0.0, 0.10), half_size=(0.1, 0.1, 0.1), name="block_front", moves=wider)])
    with pytest.raises(RobotMismatchError):
        profrobot.PoseSDF.load(path, other)
    with pytest.raises(RobotMismatchError):
        profrobot.resolve(tiny_field, np.zeros((1, 9)), robot=other.at(np.zeros(3)))


def test_scene_argument_errors(family, tiny_field):
    delta = np.zeros(9)
    q = profrobot.exact.problems.colliding_poses(family.at(delta), 3, seed=0)
    with pytest.raises(InputError, match="pass layout="):
        profrobot.resolve(tiny_field, q)
    with pytest.raises(InputError, match="outside the family's range"):
        profrobot.resolve(tiny_field, q, layout=np.full(9, 0.5))
    plain = profrobot.scenes.load("panda_blocks")
    field = profrobot.PoseSDF(plain, hidden=(8,))
    with pytest.raises(InputError, match="not a family field"):
        profrobot.resolve(field, q, layout=delta)
    with pytest.raises(InputError, match=r"theta must be a \(B, 9\)"):
        tiny_field(torch.zeros(2, 5), layout=delta)


def test_resolve_at_a_layout_is_certified_there(family, tiny_field):
    """Whatever the field's quality, nothing certified collides at that layout (MuJoCo), and
    layout=δ and robot=family.at(δ) are the same call."""
    delta = layouts(family, 1, seed=13)[0]
    static = family.at(delta)
    q = profrobot.exact.problems.colliding_poses(static, 20, seed=1)
    r = profrobot.resolve(tiny_field, q, layout=delta, iterations=100, refine_rounds=1)
    r2 = profrobot.resolve(tiny_field, q, robot=static, iterations=100, refine_rounds=1)
    np.testing.assert_array_equal(r.poses, r2.poses)
    assert r.certified.any()
    assert not mujoco_labels(static, r.poses[r.certified], progress=False).collides.any()
    np.testing.assert_array_equal(r.certified, ~profrobot.label_poses(static, r.poses).collides)


def test_family_training_is_deterministic(family):
    data = profrobot.make_dataset(family, 4000, seed=1, progress=False)
    kw = dict(robot=family, iterations=5, hidden=(16,), eikonal_batch=16, batch_size=512, progress=False, seed=3)
    a, b = profrobot.train_sdf(data, **kw), profrobot.train_sdf(data, **kw)
    for (ka, va), (_, vb) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(va, vb), ka


def test_export_carries_the_family(tmp_path, tiny_field, family):
    import json

    path = tmp_path / "fam.pt2"
    profrobot.export_sdf(tiny_field, path, batch=8)
    extra = {"profrobot.json": ""}
    program = torch.export.load(str(path), extra_files=extra)
    meta = json.loads(extra["profrobot.json"])
    assert meta["family"]["scene_joints"] == list(family.scene_joints) and meta["joint_names"] == family.joint_names
    q = torch.as_tensor(profrobot.sample_poses(family, 8, seed=1), dtype=torch.float32)
    torch.testing.assert_close(program.module()(q), tiny_field(q))


def test_slice_picture_over_a_scene_joint(tmp_path, tiny_field, family):
    from profrobot.viz import sdf_slice

    fig = sdf_slice(tiny_field, family, joints=(0, 9), resolution=24, path=tmp_path / "slice.png")
    assert (tmp_path / "slice.png").stat().st_size > 1000 and "block_front_x (m)" in fig.axes[0].get_ylabel()


def test_scene_bodies_must_hang_from_the_world_and_carry_scene_joints_only(tmp_path):
    plain = tmp_path / "plain.xml"
    plain.write_text(ARM_XML.replace("{custom}", ""))
    arm = profrobot.Robot.from_mjcf(plain)
    with pytest.raises(InputError, match="'l1' also moves with robot joints"):
        arm.with_scene_joints(["j1"])            # l2 (a robot joint) hangs below l1
    with pytest.raises(InputError, match="'l2' hangs from 'l1', which moves"):
        arm.with_scene_joints(["j2"])


def test_robot_obstacle_contacts_count_as_scene_contacts(family):
    """The blocks ride on scene joints, yet they are obstacles: a hand in a block is a scene
    collision in the family exactly as at the pinned layout."""
    delta = layouts(family, 1, seed=17)[0]
    static = family.at(delta)
    q = profrobot.sample_poses(static, 4000, seed=6)
    a = profrobot.label_poses(static, q)
    b = profrobot.label_poses(family, family.compose(q, delta))
    assert a.scene_collides.any()
    np.testing.assert_array_equal(a.self_collides, b.self_collides)
    np.testing.assert_array_equal(a.scene_collides, b.scene_collides)
    assert not family.pair_is_self[[i for i, (g1, g2) in enumerate(family.pair_geoms)
                                    if "block" in " ".join(family.pair_names(i))]].any()


def test_families_are_never_planned_as_if_obstacles_were_joints(family, tiny_field):
    start, goal = profrobot.exact.problems.free_poses(family.at(np.zeros(9)), 2, seed=3)
    with pytest.raises(InputError, match="family of scenes"):
        profrobot.plan_path(family, family.compose(start, np.zeros(9)), family.compose(goal, np.zeros(9)))
    with pytest.raises(InputError, match="family of scenes"):
        profrobot.nearest_free(family, family.compose(start, np.zeros(9))[None])
    with pytest.raises(InputError, match="pass layout="):
        profrobot.plan_trajectory(None, start, goal, robot=family)
    with pytest.raises(InputError, match="pass layout="):
        profrobot.collision_penalty(tiny_field, torch.zeros(2, 18))
    pen = profrobot.collision_penalty(tiny_field, torch.as_tensor(start[None], dtype=torch.float32), layout=np.zeros(9))
    assert pen.shape == (1,)
    # the family itself with layout=δ is accepted where a labeller robot is asked for
    q = profrobot.exact.problems.colliding_poses(family.at(np.zeros(9)), 2, seed=4)
    r = profrobot.resolve(tiny_field, q, robot=family, layout=np.zeros(9), iterations=5, refine_rounds=0)
    np.testing.assert_array_equal(r.certified, ~profrobot.label_poses(family.at(np.zeros(9)), r.poses).collides)
    with pytest.raises(InputError, match="save the family field"):
        tiny_field.at(np.zeros(9)).save("x")


def test_compose_takes_dicts_tensors_and_one_layout_per_pose(family):
    d = {n: 0.01 * i for i, n in enumerate(family.scene_joints)}
    theta = np.zeros((3, 9))
    full = family.compose(theta, d)
    np.testing.assert_allclose(full[:, family.scene_index], np.tile(list(d.values()), (3, 1)))
    np.testing.assert_array_equal(family.compose(theta, torch.tensor(list(d.values()), dtype=torch.float64)), full)
    with pytest.raises(InputError, match=r"one layout per pose \(3, D\)"):
        family.compose(theta, np.zeros((2, 9)))
    bad = np.zeros((3, 9))
    bad[2, 1] = 1.0
    with pytest.raises(InputError, match=r"layout\[2\]\[1\] \(block_front_y\)"):
        family.compose(theta, bad)
    box = profrobot.Box((0, 0, 0), (1, 0, 0, 0), "b", (1, 1, 1, 1), (0.1, 0.2, 0.3))   # positional, as before
    assert box.half_size == (0.1, 0.2, 0.3) and box.moves is None
