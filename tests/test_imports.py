"""The lazy facade (issue 9, part 2): ``import profrobot`` loads neither torch, MuJoCo's OpenGL
stack nor matplotlib; labelling, datasets, the cross-check and their commands never load torch;
the torch side loads on first attribute access. Each check runs in a fresh interpreter."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

import profrobot

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HEAVY = ("torch", "matplotlib", "OpenGL", "mujoco.egl", "mujoco.osmesa", "mujoco.glfw", "triton", "scipy")


def loaded_after(code: str, **env) -> list[str]:
    """The HEAVY modules in sys.modules after running ``code`` in a fresh interpreter."""
    probe = textwrap.dedent(code) + (f"\nimport json, sys\nprint('LOADED=' + json.dumps([m for m in {HEAVY!r} "
                                     "if m in sys.modules]))\n")
    e = dict(os.environ, OMP_NUM_THREADS="1", **env)
    done = subprocess.run([sys.executable, "-c", probe], env=e, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    line = [ln for ln in done.stdout.splitlines() if ln.startswith("LOADED=")][-1]
    return json.loads(line[len("LOADED="):])


@pytest.mark.parametrize("gl", [None, "osmesa", "egl"])
def test_import_loads_no_torch_no_gl_no_matplotlib(gl):
    env = {} if gl is None else dict(MUJOCO_GL=gl)
    assert loaded_after("import profrobot", **env) == []


def test_labels_datasets_crosscheck_never_load_torch(tmp_path):
    assert loaded_after(f"""
        import profrobot
        robot = profrobot.scenes.load("panda_blocks")
        poses = profrobot.sample_poses(robot, 200, seed=0)
        labels = profrobot.label_poses(robot, poses)
        report = profrobot.crosscheck(robot, poses[:50], progress=False)
        ds = profrobot.make_dataset(robot, 200, 0.5, 0)
        ds.save({str(tmp_path / "d.npz")!r})
        profrobot.Dataset.load({str(tmp_path / "d.npz")!r}, robot)
        profrobot.interpolate(robot, poses[0], poses[1], 5)
        """) == []


@pytest.mark.parametrize("argv", [["scenes"], ["label", "-n", "500"], ["crosscheck", "-n", "50"],
                                  ["dataset", "-n", "200", "--out", "{tmp}/d.npz"]])
def test_cli_commands_without_torch(argv, tmp_path):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert loaded_after(f"""
        import sys
        from profrobot.cli.main import main
        assert main({argv!r}) == 0
        """) == []


def test_torch_side_loads_on_first_access():
    # the attribute loads it (the module's __getattr__; `from profrobot import PoseSDF` goes
    # through the same hook, and gets the same object)
    assert "torch" in loaded_after("""
        import sys, profrobot
        assert "torch" not in sys.modules
        profrobot.train_sdf
        assert "torch" in sys.modules
        from profrobot import PoseSDF
        assert PoseSDF is profrobot.field.PoseSDF
        """)
    assert "torch" in loaded_after("import profrobot.field")


def test_every_public_name_resolves_and_dir_is_complete():
    for name in profrobot.__all__:
        assert getattr(profrobot, name) is not None, name
    assert set(profrobot.__all__) <= set(dir(profrobot))
    import profrobot.field.checkpoint as checkpoint
    import profrobot.optim as optim
    assert profrobot.train_sdf is profrobot.field.train_sdf and profrobot.export_sdf is checkpoint.export_sdf
    assert profrobot.resolve is optim.resolve and profrobot.plan_trajectory is optim.plan_trajectory
    assert set(profrobot.render.__all__) <= set(dir(profrobot.render))
    for name in profrobot.render.__all__:
        assert getattr(profrobot.render, name) is not None, name
    with pytest.raises(AttributeError):
        profrobot.no_such_name  # noqa: B018
    with pytest.raises(AttributeError):
        profrobot.render.no_such_name  # noqa: B018


def test_render_rasterize_is_the_function_whatever_was_imported_first():
    """The function ``render.rasterize`` lives in the module ``render.rasterizer``: no submodule
    shares a name its package exports."""
    assert loaded_after("""
        import profrobot.render.rasterizer
        from profrobot.render import rasterize
        import profrobot.render
        assert callable(rasterize) and rasterize is profrobot.render.rasterize, rasterize
        from profrobot.render.rasterizer import RenderOut
        assert profrobot.render.RenderOut is RenderOut
        """)  # torch, of course: the rasteriser is torch


def test_render_views_need_no_torch():
    assert loaded_after("""
        from profrobot.render import Cameras, Views, make_views, ring_cameras, sphere_cameras
        ring_cameras(4).K
        """) == []
