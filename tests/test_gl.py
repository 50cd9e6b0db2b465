"""MuJoCo's OpenGL: a backend chosen by probing in a subprocess, one clear error when none works,
rendering in worker processes, and no import order that crashes (issue 9, part 1).

Subprocess tests run a fresh interpreter: what they check (a GL library loaded, a segfault, an
abort) cannot be undone or survived inside the test process."""

import glob
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import profrobot
from profrobot import gl
from profrobot.errors import ProfrobotError, RendererUnavailableError
from profrobot.executors import LocalExecutor, close_workers
from profrobot.gl import backends

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(code: str, timeout: float = 600, **env) -> subprocess.CompletedProcess:
    e = dict(os.environ, OMP_NUM_THREADS="1")
    for k, v in env.items():
        if v is None:
            e.pop(k, None)
        else:
            e[k] = v
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=e, capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


@pytest.fixture
def no_backend(monkeypatch):
    """Every probe fails, as on a headless machine without OSMesa or an EGL driver."""
    backends.forget()
    monkeypatch.setattr(backends, "probe", lambda gl, timeout=120.0, script=None: f"no {gl or 'default'} here")
    close_workers()
    yield
    backends.forget()
    close_workers()


def test_error_type_is_in_the_family_and_a_runtime_error():
    assert issubclass(RendererUnavailableError, RuntimeError)
    assert issubclass(RendererUnavailableError, ProfrobotError)
    assert profrobot.RendererUnavailableError is RendererUnavailableError is gl.RendererUnavailableError


def test_candidates_follow_mujoco_gl_and_display(monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform.startswith("linux"):
        assert backends.candidates()[0] == ["egl", "osmesa"]
        monkeypatch.setenv("DISPLAY", ":0")
        assert backends.candidates()[0] == ["glfw", "egl", "osmesa"]
    monkeypatch.setenv("MUJOCO_GL", "OSMesa")
    assert backends.candidates()[0] == ["osmesa"]   # the user's choice, and only it


def test_no_backend_is_one_clear_error(no_backend, panda, tmp_path):
    chosen, why = gl.status()
    assert chosen is None and "apt-get install libosmesa6" in why and "EGL" in why
    with pytest.raises(RendererUnavailableError, match="libosmesa6"):
        gl.backend()
    from profrobot.optim.pictures import render_trajectory
    from profrobot.render import make_views, ring_cameras

    with pytest.raises(RendererUnavailableError, match="libosmesa6"):
        make_views(panda, np.zeros((1, panda.njoint)), ring_cameras(2, size=8), progress=False)
    with pytest.raises(RendererUnavailableError, match="libosmesa6"):
        render_trajectory(panda, np.zeros((2, panda.njoint)), tmp_path / "t.gif")
    assert not (tmp_path / "t.gif").exists()
    # labels never needed a renderer
    assert profrobot.label_poses(panda, panda.joint_limits.mean(1)[None]).collides.shape == (1,)


def test_cli_without_a_renderer_exits_2_with_the_message(no_backend, capsys, tmp_path):
    import torch

    from profrobot.cli.main import main

    code = main(["render", "-n", "1", "--cameras", "1", "--size", "8", "--iterations", "1", "--gaussians", "10",
                 "--processes", "1", "--torch-threads", str(torch.get_num_threads()),
                 "--out", str(tmp_path / "g.safetensors")])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("profrobot: error: MuJoCo cannot render here") and "libosmesa6" in err


def test_a_probe_that_crashes_is_a_reason_not_a_crash():
    assert "invalid value" in gl.probe("bogus")                          # mujoco refuses the name
    assert "SIGABRT" in gl.probe("egl", script="import os; os.abort()")  # GLFW without a display does this


# chunk functions for the worker tests (module-level: the workers import them from here)
@gl.uses_gl
def drawing_pid(robot) -> int:
    return os.getpid()


@gl.uses_gl
def drawing_abort(robot):
    os.abort()


def sqrt_pid(robot, x: float) -> tuple[float, int]:
    return math.sqrt(x), os.getpid()


def test_a_worker_that_dies_raises_and_is_not_reused(monkeypatch, panda):
    monkeypatch.setattr(backends, "backend", lambda: "egl")  # these chunk functions draw nothing
    close_workers()
    ex = LocalExecutor()
    assert not ex.in_process(drawing_pid) and ex.in_process(sqrt_pid)
    first = ex.map(drawing_pid, [()], robot=panda, progress=False)[0]
    assert first != os.getpid()                          # drawing happens in a worker, never here
    assert ex.map(drawing_pid, [()], robot=panda, progress=False) == [first]   # kept idle, reused
    with pytest.raises(RendererUnavailableError, match="SIGABRT"):
        ex.map(drawing_abort, [()], robot=panda, progress=False)               # that worker dies
    again = ex.map(drawing_pid, [()], robot=panda, progress=False)[0]
    assert again not in (first, os.getpid())             # a new one: the dead one is not reused
    # chunk functions that do not draw: here with one process, in workers with more
    assert ex.map(sqrt_pid, [4.0, 9.0], robot=panda, progress=False) == [(2.0, os.getpid()), (3.0, os.getpid())]
    two = LocalExecutor(processes=2)
    got = two.map(sqrt_pid, [(1.0,), (9.0,), (16.0,)], robot=panda, progress=False)
    assert [v for v, _ in got] == [1.0, 3.0, 4.0]
    assert len({p for _, p in got}) == 2 and os.getpid() not in {p for _, p in got}
    with pytest.raises(ValueError):                      # errors in a worker come back as they are
        two.map(sqrt_pid, [(-1.0,)], robot=panda, progress=False)
    close_workers()


def test_ordered_stops_early_and_keeps_its_workers(panda):
    close_workers()
    ex = LocalExecutor(processes=2)
    stream = ex.ordered(sqrt_pid, lambda i: (float(i * i),), 100, lambda: 2, robot=panda)
    got = [next(stream) for _ in range(5)]
    stream.close()                                       # the rest is not computed
    assert [(i, v) for i, (v, _) in got] == [(i, float(i)) for i in range(5)]
    pids = {p for _, (_, p) in got}
    again = ex.map(sqrt_pid, [(1.0,), (4.0,)], robot=panda, progress=False)
    assert {p for _, p in again} == pids                 # the same two workers, idle in between
    close_workers()


def test_a_missing_mujoco_gl_backend_does_not_break_import_or_labels():
    """MUJOCO_GL naming a backend that cannot load (here: a name mujoco rejects, which makes a bare
    ``import mujoco`` raise, as ``osmesa`` does without libOSMesa) leaves profrobot importable; the
    user's own ``mujoco.Renderer`` and our rendering raise the clear error."""
    done = run("""
        import sys, numpy as np, profrobot, mujoco
        robot = profrobot.scenes.load("panda_blocks")
        assert profrobot.label_poses(robot, profrobot.sample_poses(robot, 10, seed=0)).collides.shape == (10,)
        m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=".1"/></worldbody></mujoco>')
        for draw in (lambda: mujoco.Renderer(m, 8, 8),
                     lambda: profrobot.render.make_views(robot, np.zeros((1, robot.njoint)),
                                                         profrobot.render.ring_cameras(1, size=8), progress=False)):
            try:
                draw()
            except profrobot.RendererUnavailableError as e:
                assert "libosmesa6" in str(e), e
            else:
                raise AssertionError("rendered with a bogus MUJOCO_GL")
        print("ok")
        """, MUJOCO_GL="bogus")
    assert done.returncode == 0 and "ok" in done.stdout, done.stderr[-3000:]


def osmesa_loadable() -> bool:
    """Whether libOSMesa loads here (a file .ci/without-gl hides is there, but empty)."""
    import ctypes

    for path in glob.glob("/usr/lib/*/libOSMesa.so*") + glob.glob("/usr/lib/libOSMesa.so*"):
        try:
            ctypes.CDLL(path)
            return True
        except OSError:
            continue
    return False


def test_osmesa_named_but_missing():
    if osmesa_loadable():
        pytest.skip("OSMesa is installed here")
    done = run("import profrobot, mujoco; print(profrobot.__version__)", MUJOCO_GL="osmesa")
    assert done.returncode == 0, done.stderr[-3000:]


def test_user_renderer_works_after_import_profrobot(renderer):
    """profrobot imports mujoco without its GL; ``mujoco.Renderer`` still loads the user's."""
    done = run("""
        import profrobot, mujoco
        m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><light pos="0 0 1"/><geom size=".1"/></worldbody></mujoco>')
        d = mujoco.MjData(m); mujoco.mj_forward(m, d)
        r = mujoco.Renderer(m, 8, 8); r.update_scene(d); assert r.render().any(); r.close()
        assert mujoco.GLContext is not None
        print("ok")
        """, MUJOCO_GL=renderer)
    assert done.returncode == 0 and "ok" in done.stdout, done.stderr[-3000:]


def _libllvm() -> str:
    found = sorted(glob.glob("/usr/lib/*/libLLVM*.so*") + glob.glob("/usr/lib64/libLLVM*.so*"))
    if not found or not sys.platform.startswith("linux"):
        pytest.skip("no shared libLLVM on this machine (Mesa's llvmpipe brings one)")
    pytest.importorskip("triton")
    return found[0]


def test_triton_after_a_foreign_llvm_does_not_segfault():
    """The crash without GL: a libLLVM mapped (RTLD_GLOBAL, as Mesa's llvmpipe is) before triton
    loads. With profrobot imported first, torch._dynamo and torch.optim load safely."""
    code = f"""
        import ctypes, os, sys
        if sys.argv[1] == "guard":
            import profrobot
        ctypes.CDLL({_libllvm()!r}, mode=os.RTLD_NOW | os.RTLD_GLOBAL)
        import torch, torch._dynamo
        torch.optim.Adam([torch.zeros(2, requires_grad=True)]).step()
        print("ok")
        """
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code), "guard"], capture_output=True, text=True,
                          timeout=600, cwd=ROOT)
    assert done.returncode == 0 and "ok" in done.stdout, (done.returncode, done.stderr[-3000:])


FLOW = """
import mujoco  # the user's import, first; their own render maps Mesa's libLLVM (OSMesa, or EGL on a CPU)
m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=".1"/></worldbody></mujoco>')
d = mujoco.MjData(m); mujoco.mj_forward(m, d)
r = mujoco.Renderer(m, 16, 16); r.update_scene(d); r.render(); r.close()
import sys
import numpy as np
import profrobot
robot = profrobot.scenes.load("panda_blocks")
sdf = profrobot.train_sdf(robot, hidden=(16,), n_poses=2000, iterations=3, batch_size=256, eikonal_batch=32,
                          progress=False, seed=0)
q = profrobot.sample_poses(robot, 200, seed=1)
res = profrobot.resolve(sdf, q[profrobot.label_poses(robot, q).collides][:5], iterations=5, refine=False)
from profrobot.render import GaussianRobot, fit_pose, make_views, ring_cameras
ARM = '''<mujoco><compiler angle="radian"/><statistic extent="1" center="0 0 0.3"/>
  <asset><mesh name="bar" vertex="-.04 -.04 0 .04 -.04 0 .04 .04 0 -.04 .04 0 -.04 -.04 .3 .04 -.04 .3 .04 .04 .3 -.04 .04 .3"/>
  </asset><worldbody>
    <body name="l1"><joint name="j1" type="hinge" axis="0 0 1" range="-3 3"/><geom type="mesh" mesh="bar" rgba=".8 .2 .2 1"/>
      <body name="l2" pos="0 0 0.3"><joint name="j2" type="hinge" axis="0 1 0" range="-2 2"/>
        <geom type="mesh" mesh="bar" rgba=".2 .6 .9 1"/></body></body>
  </worldbody></mujoco>'''
arm = profrobot.Robot.from_spec(mujoco.MjSpec.from_string(ARM), name="arm")
cams = ring_cameras(2, size=16, distance=1.4, elevation=-20, lookat=(0, 0, 0.3))
v = make_views(arm, np.array([[0.3, 0.8]]), cams, progress=False)
g = GaussianRobot.from_robot(arm, 100, seed=0)
fit = fit_pose(g, dict(rgb=v.rgb, depth=v.depth, mask=v.mask), cams, np.array([[0.2, 0.7]]), iterations=3)
from profrobot.optim.pictures import render_trajectory
gif = render_trajectory(robot, profrobot.interpolate(robot, q[0], q[1], 5), sys.argv[1], size=(64, 48))
r = mujoco.Renderer(m, 16, 16); r.update_scene(d); r.render(); r.close()  # the user's renderer still works
print("flow-ok", "triton" in sys.modules)
"""


#: bytes of thread-local storage the core may take (its ELF TLS segment): the core is linked with
#: static TLS (``STATIC_TLS``: parts of its dependencies use the initial-exec model), so its block is
#: carved from the few spare bytes glibc keeps for libraries loaded later, which torch's
#: ``libgomp`` needs too. At 1 488 bytes, ``import torch`` after ``mujoco``'s EGL and the core failed
#: ("cannot allocate memory in static TLS block", the full flow below); 1 376 is the largest size
#: the full flow has passed with. 1 104 of them are ``matrixmultiply``'s (through nalgebra).
CORE_TLS_BUDGET = 1376


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="an ELF shared library")
def test_core_thread_locals_leave_room_for_libraries_loaded_later():
    import struct

    from profrobot import _core
    data = Path(_core.__file__).read_bytes()
    assert data[:4] == b"\x7fELF" and data[4] == 2, "a 64-bit ELF file"
    phoff, = struct.unpack_from("<Q", data, 0x20)
    phentsize, phnum = struct.unpack_from("<HH", data, 0x36)
    tls = [struct.unpack_from("<Q", data, phoff + i * phentsize + 0x28)[0]
           for i in range(phnum) if struct.unpack_from("<I", data, phoff + i * phentsize)[0] == 7]
    assert len(tls) == 1 and tls[0] <= CORE_TLS_BUDGET, (tls, CORE_TLS_BUDGET)


@pytest.mark.slow
@pytest.mark.parametrize("gl", ["osmesa", "egl"])
def test_import_order_full_flow(gl, tmp_path):
    """``import mujoco`` (and a render of the user's own) before ``import profrobot``, then train a
    field, resolve poses, fit a pose and write a GIF, in one process: exit status 0."""
    why = backends.probe(gl)
    if why:
        pytest.skip(f"MUJOCO_GL={gl} cannot render here: {why}")
    env = dict(backends.child_env(gl), OMP_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", FLOW, str(tmp_path / "t.gif")], env=env, capture_output=True,
                          text=True, timeout=900, cwd=ROOT)
    assert done.returncode == 0 and "flow-ok" in done.stdout, (done.returncode, done.stderr[-3000:])
    assert (tmp_path / "t.gif").stat().st_size > 0
