"""One GL choice for every MuJoCo context (issue 32: the README's test command aborted on a fresh
headless machine with EGL, because a test made its own ``mujoco.Renderer`` while ``MUJOCO_GL``
was unset; MuJoCo fell back to GLFW, raised ``FatalError``, and the next call aborted Python).

Every context in the library, the tests and the benches is made by ``profrobot.gl.renderer``:
the probed backend, and ``FatalError`` raised as ``RendererUnavailableError``, never an abort.
Subprocess tests run a fresh interpreter: an abort cannot be survived inside the test process."""

import ast
import textwrap
from pathlib import Path

import pytest

from profrobot import gl
from profrobot.errors import RendererUnavailableError

from test_gl import osmesa_loadable, run

ROOT = Path(__file__).resolve().parents[1]
GL_PACKAGE = ROOT / "python" / "profrobot" / "gl"
# what makes a GL context, or loads a GL backend behind the one choice's back
CONTEXT_MAKERS = {"Renderer", "GLContext", "MjrContext"}
BACKEND_MODULES = ("mujoco.egl", "mujoco.osmesa", "mujoco.glfw", "mujoco.gl_context", "mujoco.rendering")


def _sources():
    for folder in ("python/profrobot", "tests", "benches", "examples"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if GL_PACKAGE not in path.parents:
                yield path


def context_makers(path: Path) -> list[str]:
    """Places in ``path`` that make a MuJoCo GL context or import a backend themselves: calls of
    ``<anything>.Renderer/GLContext/MjrContext(...)``, those names imported from mujoco and called,
    and imports of MuJoCo's backend modules. Code inside strings (subprocess scripts that stand for
    a user's own program) is not code of this module."""
    tree = ast.parse(path.read_text(), str(path))
    imported: set[str] = set()
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("mujoco"):
            mod = node.module or ""
            if mod.startswith(BACKEND_MODULES):
                found.append(f"{path.name}:{node.lineno}: from {mod} import ...")
            imported |= {a.asname or a.name for a in node.names if a.name in CONTEXT_MAKERS}
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith(BACKEND_MODULES):
                    found.append(f"{path.name}:{node.lineno}: import {a.name}")
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if (isinstance(f, ast.Attribute) and f.attr in CONTEXT_MAKERS) or (isinstance(f, ast.Name) and f.id in imported):
            found.append(f"{path.name}:{node.lineno}: {ast.unparse(f)}(...)")
    return found


def test_no_gl_context_is_made_outside_the_one_choice():
    found = [hit for path in _sources() for hit in context_makers(path)]
    assert not found, ("MuJoCo GL contexts made outside profrobot.gl.renderer (use it: it renders on the probed "
                       "backend and never aborts):\n" + "\n".join(found))


def test_the_scan_finds_what_it_must(tmp_path):
    """The scan is not vacuous: each way of making a context is found, strings are not."""
    bad = tmp_path / "bad.py"
    bad.write_text(textwrap.dedent("""
        import mujoco
        import mujoco as mj
        from mujoco import Renderer as R
        from mujoco.egl import GLContext
        a = mujoco.Renderer(m, 8, 8)
        b = mj.GLContext(8, 8)
        c = R(m, 8, 8)
        d = mujoco.MjrContext(m, 0)
        e = "mujoco.Renderer(m, 8, 8)"      # a script for a subprocess: not this module's code
        """))
    found = context_makers(bad)
    assert len(found) == 5, found
    assert not context_makers(ROOT / "tests" / "test_gl.py")   # its own renderers are in subprocess scripts


BALL = "<mujoco><worldbody><light pos='0 0 1'/><geom size='.1'/></worldbody></mujoco>"


def test_fatal_error_from_a_context_is_an_error_not_an_abort():
    """GLFW without a display: MuJoCo raises FatalError, and its next call would abort. Here the
    probe is made to pick GLFW anyway (as a probe that lied would): ``gl.renderer`` raises the
    clear error, twice, and the process goes on to label and exit 0."""
    done = run(f"""
        import numpy as np, profrobot, mujoco
        from profrobot.gl import backends
        backends._SELECTED = "glfw"           # a backend that cannot make a context here
        m = mujoco.MjModel.from_xml_string("{BALL}")
        for attempt in range(2):
            try:
                profrobot.gl.renderer(m, 8, 8)
            except profrobot.RendererUnavailableError as e:
                assert "glfw" in str(e) and "libosmesa6" in str(e), e
            else:
                raise AssertionError("made a GLFW context without a display")
        robot = profrobot.scenes.load("panda_blocks")
        print("labels", profrobot.label_poses(robot, robot.joint_limits.mean(1)[None]).collides.shape)
        """, MUJOCO_GL=None, DISPLAY=None, WAYLAND_DISPLAY=None)
    assert done.returncode == 0 and "labels (1,)" in done.stdout, (done.returncode, done.stderr[-3000:])


def test_renderer_picks_the_probed_backend_with_mujoco_gl_unset(renderer):
    """The bug as the README's test command met it: ``MUJOCO_GL`` unset, no display, mujoco
    imported by the user's code. ``gl.renderer`` draws on the backend the probe picked."""
    done = run(f"""
        import os, profrobot, mujoco
        m = mujoco.MjModel.from_xml_string("{BALL}")
        d = mujoco.MjData(m); mujoco.mj_forward(m, d)
        with profrobot.gl.renderer(m, 8, 8) as r:
            r.update_scene(d); assert r.render().any()
        print("drew", os.environ["MUJOCO_GL"], profrobot.gl.loaded_backend())
        """, MUJOCO_GL=None, DISPLAY=None, WAYLAND_DISPLAY=None)
    assert done.returncode == 0, (done.returncode, done.stderr[-3000:])
    _, chosen, loaded = done.stdout.split()
    assert chosen == loaded and chosen in ("egl", "osmesa"), done.stdout


def test_renderer_after_mujoco_loaded_its_gl_for_another_backend(renderer):
    """``import mujoco`` first, with ``MUJOCO_GL`` unset (MuJoCo loads GLFW's module), then
    profrobot: ``gl.renderer`` loads the probed backend instead and draws."""
    done = run(f"""
        import mujoco                      # before profrobot: GL stack for MUJOCO_GL unset (GLFW)
        import os, profrobot
        before = profrobot.gl.loaded_backend()
        m = mujoco.MjModel.from_xml_string("{BALL}")
        d = mujoco.MjData(m); mujoco.mj_forward(m, d)
        with profrobot.gl.renderer(m, 8, 8) as r:
            r.update_scene(d); assert r.render().any()
        print("drew", before, profrobot.gl.loaded_backend(), os.environ["MUJOCO_GL"])
        """, MUJOCO_GL=None, DISPLAY=None, WAYLAND_DISPLAY=None)
    assert done.returncode == 0, (done.returncode, done.stderr[-3000:])
    _, before, loaded, chosen = done.stdout.split()
    assert loaded == chosen, done.stdout


def test_no_backend_raises_the_clear_error_in_process(monkeypatch):
    """Where the probe finds nothing, ``gl.renderer`` raises (what was tried, what to install)."""
    from profrobot.gl import backends

    monkeypatch.setattr(backends, "_SELECTED", None)
    monkeypatch.setattr(backends, "probe", lambda gl, timeout=120.0, script=None: f"no {gl} here")
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    backends.forget()
    try:
        import mujoco

        with pytest.raises(RendererUnavailableError, match="libosmesa6"):
            gl.renderer(mujoco.MjModel.from_xml_string(BALL), 8, 8)
    finally:
        backends.forget()


def test_regression_an_in_process_render_leaves_no_pyopengl_platform_to_children(renderer):
    """MuJoCo's EGL module set PYOPENGL_PLATFORM=egl in os.environ; every child then inherited it,
    and one asked to render with OSMesa failed ("Cannot use OSMesa rendering platform"): with
    OSMesa installed, the OSMesa tests were skipped as if it were missing."""
    done = run(f"""
        import os, profrobot, mujoco
        from profrobot.gl import backends
        m = mujoco.MjModel.from_xml_string("{BALL}")
        with profrobot.gl.renderer(m, 8, 8):
            pass
        assert "PYOPENGL_PLATFORM" not in os.environ, os.environ["PYOPENGL_PLATFORM"]
        other = "osmesa" if os.environ["MUJOCO_GL"] == "egl" else "egl"
        assert backends.child_env(other)["PYOPENGL_PLATFORM"] == other
        print("ok", os.environ["MUJOCO_GL"], repr(backends.probe(other)))
        """, MUJOCO_GL=None, DISPLAY=None, WAYLAND_DISPLAY=None, PYOPENGL_PLATFORM=None)
    assert done.returncode == 0 and "ok" in done.stdout, (done.returncode, done.stderr[-3000:])
    if osmesa_loadable() and " egl " in done.stdout:
        assert done.stdout.rstrip().endswith("''"), done.stdout     # OSMesa installed: its probe renders
