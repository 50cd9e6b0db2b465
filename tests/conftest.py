import os
from pathlib import Path

import pytest

# Offline machines (CI included) use the Menagerie copy beside the checkout.
_LOCAL = Path(__file__).resolve().parents[1].parent / "shared" / "menagerie"
if "MENAGERIE_ROOT" not in os.environ and _LOCAL.is_dir():
    os.environ["MENAGERIE_ROOT"] = str(_LOCAL)
# The README sets it relative (../shared/menagerie); tests that run subprocesses in a temporary
# folder need it absolute.
if os.environ.get("MENAGERIE_ROOT"):
    os.environ["MENAGERIE_ROOT"] = os.path.abspath(os.environ["MENAGERIE_ROOT"])

# Under pytest-xdist (the README's command runs two workers, one per core) each worker's torch
# takes one thread, set before torch loads: two workers of two OpenMP threads each on two cores
# spin against each other. The Rust pools keep theirs (results do not depend on thread counts).
if os.environ.get("PYTEST_XDIST_WORKER") and "OMP_NUM_THREADS" not in os.environ:
    os.environ["OMP_NUM_THREADS"] = "1"

# MuJoCo's GL backend, fixed before MuJoCo's GL stack loads (issue 32). ``import profrobot`` imports
# mujoco with its GL deferred; the probe (each candidate in a throwaway subprocess: EGL, then
# OSMesa, without a display) picks the backend, and ``MUJOCO_GL`` is set to it for this process, so
# no test ever makes a context on a backend that cannot render (GLFW without a display raises
# FatalError and aborts the next call). Every context is made by ``profrobot.gl.renderer``
# (tests/test_gl_choice.py fails on any other). Where nothing renders, ``MUJOCO_GL`` stays as it
# was and the rendering tests are skipped with the reason and what to install.
import profrobot  # noqa: E402
from profrobot import gl as _gl  # noqa: E402
from profrobot.errors import RendererUnavailableError  # noqa: E402

GL_BACKEND, GL_WHY = _gl.status()
if GL_BACKEND is not None:
    _gl.select_backend()

_CACHE: dict = {}


def pytest_report_header(config):
    return f"MuJoCo GL: {GL_BACKEND}" if GL_BACKEND else f"MuJoCo GL: none ({GL_WHY})"


def pytest_addoption(parser):
    parser.addoption("--slow", action="store_true", default=False,
                     help="also run the slow end-to-end tier (tests marked slow: the docs' slow pages, the real-rig "
                          "fits, large cross-checks); .ci/run runs it")


def pytest_collection_modifyitems(config, items):
    """Tests that draw with MuJoCo (they take the ``renderer`` fixture, or live in test_gl.py /
    test_gl_choice.py) carry the ``gl`` mark: ``.ci/run`` runs them again under each GL setup.
    Tests marked ``slow`` run with ``--slow`` only (the default run stays within minutes)."""
    run_slow = config.getoption("--slow")
    skip_slow = pytest.mark.skip(reason="the slow end-to-end tier: run it with --slow")
    for item in items:
        if "renderer" in getattr(item, "fixturenames", ()) or item.path.name in ("test_gl.py", "test_gl_choice.py"):
            item.add_marker(pytest.mark.gl)
        if not run_slow and "slow" in item.keywords:
            item.add_marker(skip_slow)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Where no backend renders, a test that needed one is skipped with the reason (what was tried,
    what to install); where one does, a RendererUnavailableError stays a failure."""
    outcome = yield
    rep = outcome.get_result()
    if (GL_BACKEND is None and call.excinfo is not None and rep.failed
            and call.excinfo.errisinstance(RendererUnavailableError)):
        rep.outcome = "skipped"
        rep.longrepr = (str(item.path), item.location[1] or 0, f"Skipped: {call.excinfo.value}")


def scene(name: str) -> "profrobot.Robot":
    """Bundled scenes are built once per test session."""
    if name not in _CACHE:
        _CACHE[name] = profrobot.scenes.load(name)
    return _CACHE[name]


@pytest.fixture(scope="session")
def panda():
    return scene("panda_blocks")


@pytest.fixture(scope="session")
def ur5e():
    return scene("ur5e_wall_box")


@pytest.fixture(scope="session")
def renderer() -> str:
    """The MuJoCo GL backend render workers use (probed once, in a subprocess); tests that draw
    with MuJoCo take this fixture and skip, with what to install, where no backend works."""
    if GL_BACKEND is None:
        pytest.skip(GL_WHY)
    return GL_BACKEND
