"""The pick-and-place (examples/pick_and_place.py), certified end to end and executed in MuJoCo:
every stage's path certified and timed within the limits (at 1 kHz, every sample free by
MuJoCo's own collision, the held mug included), then played with the Panda's position
actuators (mj_step, the mug welded to the hand while held): no contact but the allowed
touches, the mug within 5 mm of its place."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import profrobot

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "pick_and_place.py"


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("pick_and_place", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules["pick_and_place"] = module          # (its dataclasses look their module up)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def stages(example):
    return example.plan()


def test_every_stage_is_certified_and_timed_within_the_limits(example, stages):
    assert [s.name for s in stages] == ["pre-grasp", "approach", "close", "lift", "carry", "place", "open", "retreat"]
    for st in stages:
        assert st.certified and st.timed.certified
        v, a = example._limits(st.robot)
        t, q, qd, qdd = st.timed.at_rate(1000)
        assert (np.abs(qd) <= v * (1 + 1e-9)).all() and (np.abs(qdd) <= a * (1 + 1e-9)).all(), st.name
        assert not profrobot.mujoco_labels(st.robot, q, progress=False).collides.any(), st.name
        assert profrobot.certify_poses(st.robot, q).all(), st.name
    # the held stages were planned with the mug moving with the hand
    held = [s for s in stages if s.holding]
    assert {s.name for s in held} == {"close", "lift", "carry", "place", "open"}
    assert all("mug" in {g["name"] for g in s.robot.geom_table()} for s in stages)
    # consecutive stages join: each starts where the last ended
    for a, b in zip(stages[:-1], stages[1:]):
        np.testing.assert_allclose(b.path[0], a.path[-1], atol=1e-12)


def test_the_straight_stages_keep_the_fingertips_on_a_vertical_line(example, stages):
    for st in stages:
        if st.name not in ("approach", "lift", "place", "retreat"):
            continue
        tips = np.array([example.robot_frame(st.robot, q) for q in st.timed.at_rate(500)[1]])
        assert np.abs(tips[:, :2] - tips[0, :2]).max() < 1e-3, st.name


def test_executed_in_mujoco_with_the_arm_s_actuators(example, stages):
    ex = example.execute(stages)
    assert not ex.forbidden, ex.forbidden
    assert ex.place_error <= 0.005
    assert ex.tracking_error < 0.02
    touched = {n for key in ex.contacts for n in key}
    assert "table" in touched and any(n.startswith("left_finger") for n in touched) \
        and any(n.startswith("right_finger") for n in touched)


def test_played_in_the_viewer_with_the_mug_in_the_hand_while_held(example, stages):
    """``examples/pick_and_place.py --view``: the stages play in the browser viewer, each with
    its own robot; during the carry the mug drawn is the held one, where MuJoCo's model of the
    holding robot puts it at that frame."""
    pytest.importorskip("viser", reason="the viewer needs viser: pip install '.[viewer]'")
    import mujoco

    from profrobot.viz import Viewer

    from test_viewer import free_port

    with Viewer(stages[0].robot, stages[0].timed.sample(0.0)[0], port=free_port(), gizmo=False) as viewer:
        shown = viewer.show_stages([(st.robot, st.timed) for st in stages], name="pp", fps=30)
        assert shown["certified"]
        carry = [i for i, st in enumerate(stages) if st.name == "carry"][0]
        t = sum(st.timed.duration for st in stages[:carry]) + stages[carry].timed.duration / 2
        q = viewer.seek("pp", t)
        held = stages[carry].robot
        assert viewer.robot is held and viewer.verdict == "free, certified"
        m = held.mj_model
        d = mujoco.MjData(m)
        d.qpos[held.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        g = m.geom("mug").id
        np.testing.assert_allclose(viewer._geoms[g].position, d.geom_xpos[g], atol=1e-12)
        np.testing.assert_allclose(q, stages[carry].robot.project(
            stages[carry].timed.sample(t - sum(st.timed.duration for st in stages[:carry]))[0][None])[0], atol=0.05)
