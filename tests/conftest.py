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

import profrobot  # noqa: E402

_CACHE: dict = {}


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
    from profrobot import gl as profrobot_gl

    gl, why = profrobot_gl.status()
    if gl is None:
        pytest.skip(why)
    return gl
