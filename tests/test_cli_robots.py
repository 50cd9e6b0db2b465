"""Every command of the command line with ``--robot FILE`` (MJCF and URDF) and with a family's
``--scene`` (issue 33): only ``pose`` took ``--robot``, ``plan --out`` crashed, ``train -n`` and
``plan -n`` were listed and ignored, the help showed no defaults and ``--scene``'s help left out
the families; and with ``--field DIR`` alone, the robot the field directory stores (issue 37).
(``pose --robot FILE.urdf``: tests/test_cli_pose.py.)"""

from __future__ import annotations

import numpy as np
import pytest

from profrobot.cli.main import main

from test_feasible_answers import MIMIC_URDF

ARM_XML = """<mujoco model="cli_arm">
  <compiler angle="radian"/>
  <worldbody>
    <light pos="0 0 2"/>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <geom name="post" type="box" pos="0.35 0.1 0.3" size="0.05 0.05 0.3"/>
    <body name="l1" pos="0 0 0.1">
      <joint name="j1" type="hinge" axis="0 0 1" range="-2.8 2.8"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.3" size="0.045"/>
      <body name="l2" pos="0 0 0.3">
        <joint name="j2" type="hinge" axis="0 1 0" range="-2.0 2.0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
        <body name="l3" pos="0.3 0 0">
          <joint name="j3" type="hinge" axis="0 1 0" range="-2.0 2.0"/>
          <geom type="box" pos="0.08 0 0" size="0.08 0.03 0.03"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

# the mimic arm of test_feasible_answers, with a post fixed to its base: an obstacle a URDF carries
ARM_URDF = MIMIC_URDF.replace(
    '  <joint name="j1"',
    '  <link name="post"><collision><origin xyz="0 0 0.3"/><geometry><box size="0.1 0.1 0.6"/></geometry></collision></link>\n'
    '  <joint name="post_fixed" type="fixed"><parent link="base"/><child link="post"/><origin xyz="0.35 0.1 0"/></joint>\n'
    '  <joint name="j1"', 1)


# the URDF cell in the default run (its robot is the one only a stored robot.pkl can name); the
# MJCF cell and the family in the slow tier (each is every command end to end: 6-20 s)
@pytest.fixture(scope="module", params=[pytest.param("mjcf", marks=pytest.mark.slow), "urdf",
                                        pytest.param("family", marks=pytest.mark.slow)])
def robot_args(request, tmp_path_factory) -> list[str]:
    folder = tmp_path_factory.mktemp(f"cli_{request.param}")
    if request.param == "family":
        return ["--scene", "panda_blocks_moving"]
    path = folder / ("arm.xml" if request.param == "mjcf" else "arm.urdf")
    path.write_text(ARM_XML if request.param == "mjcf" else ARM_URDF)
    return ["--robot", str(path)]


def run(capsys, *argv) -> str:
    code = main(list(argv))
    out = capsys.readouterr()
    assert code == 0, (argv, out.err[-3000:])
    return out.out


def test_every_command_takes_the_robot(robot_args, tmp_path, capsys):
    assert "agreement" in run(capsys, "demo", *robot_args, "-n", "600", "--check", "200")
    run(capsys, "label", *robot_args, "-n", "2000", "--out", str(tmp_path / "l.npz"))
    with np.load(tmp_path / "l.npz") as z:
        assert len(z["poses"]) == 2000
    assert "agreement" in run(capsys, "crosscheck", *robot_args, "-n", "300")
    run(capsys, "dataset", *robot_args, "-n", "300", "--out", str(tmp_path / "d.npz"))
    field = tmp_path / "field"
    run(capsys, "train", *robot_args, "--n-poses", "3000", "--iterations", "20", "--out", str(field))
    # resolve and plan with the field and the robot named the same way, then with the field
    # alone (issue 37: the directory stores its robot; a URDF or MJCF cell could not be named
    # before): the same answers (exit 1 only when an answer is not certified: a 20-step field
    # may leave one, which is reported, not crashed)
    for named in (robot_args, []):
        tag = "named" if named else "alone"
        for cmd in (["resolve", *named, "--field", str(field), "-n", "4", "--out", str(tmp_path / f"r_{tag}.npz")],
                    ["plan", *named, "--field", str(field), "--steps", "12", "--iterations", "10",
                     "--out", str(tmp_path / f"p_{tag}.npz")]):
            code = main(cmd)
            out = capsys.readouterr()
            assert code in (0, 1), (cmd, out.err[-3000:])
            assert "saved" in out.out, out.out
    for kind in ("r", "p"):
        with np.load(tmp_path / f"{kind}_named.npz") as a, np.load(tmp_path / f"{kind}_alone.npz") as b:
            assert sorted(a.files) == sorted(b.files)
            for key in a.files:
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"{kind}: {key}")
    with np.load(tmp_path / "p_alone.npz") as z:
        assert z["path"].shape[0] == 12
    with np.load(tmp_path / "r_alone.npz") as z:
        assert z["poses"].shape[0] == 4


def test_render_takes_the_robot(robot_args, tmp_path, capsys, renderer):
    run(capsys, "render", *robot_args, "-n", "2", "--cameras", "1", "--size", "16", "--gaussians", "60",
        "--iterations", "2", "--processes", "1", "--out", str(tmp_path / "g.safetensors"))
    assert (tmp_path / "g.safetensors").stat().st_size > 0


def test_help_shows_defaults_and_the_families(capsys):
    for cmd, expect in (("demo", ["(default: 100000)", "(default: 5000)", "panda_blocks_moving", "--robot FILE"]),
                        ("plan", ["(default: 100)", "(default: penalty)", "--robot FILE"]),
                        ("train", ["(default: cpu)", "--robot FILE"])):
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        text = capsys.readouterr().out
        for e in expect:
            assert e in " ".join(text.split()), (cmd, e, text)
    # -n is not offered where it means nothing
    for cmd in ("train", "plan"):
        with pytest.raises(SystemExit):
            main([cmd, "--help"])
        assert "\n  -n N" not in capsys.readouterr().out


def test_scene_and_robot_together_are_refused(capsys, tmp_path):
    (tmp_path / "arm.xml").write_text(ARM_XML)
    assert main(["label", "-n", "10", "--scene", "panda_blocks", "--robot", str(tmp_path / "arm.xml")]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["label", "-n", "10", "--robot", str(tmp_path / "nope.xml")]) == 2
    assert "nope.xml" in capsys.readouterr().err
