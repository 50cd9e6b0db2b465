"""What a wheel must carry (issue 41): one version everywhere, the typing files, every subpackage;
and, where .ci/run installs the built wheel (PROFROBOT_WHEEL=1), that these tests import it and
not the source tree."""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest

import profrobot

ROOT = Path(__file__).resolve().parents[1]


def cargo_version() -> str:
    text = (ROOT / "Cargo.toml").read_text()
    package = text.split("[package]", 1)[1].split("\n[", 1)[0]
    return re.search(r'^version\s*=\s*"([^"]+)"', package, flags=re.M).group(1)


def test_one_version_everywhere():
    """Cargo.toml is the one source: the wheel's metadata, profrobot.__version__ (from the
    native module) and ``profrobot --version`` all say it."""
    want = cargo_version()
    assert profrobot.__version__ == want
    assert importlib.metadata.version("profrobot") == want
    out = subprocess.run([sys.executable, "-m", "profrobot.cli.main", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"profrobot {want}"
    assert 'dynamic = ["version"]' in (ROOT / "pyproject.toml").read_text()


def test_the_typing_files_and_every_module_are_installed():
    here = Path(profrobot.__file__).parent
    assert (here / "py.typed").is_file() and (here / "_core.pyi").is_file()
    assert "class RobotModel" in (here / "_core.pyi").read_text()
    source = ROOT / "python" / "profrobot"
    want = {p.relative_to(source).with_suffix("").as_posix() for p in source.rglob("*.py")}
    have = {p.relative_to(here).with_suffix("").as_posix() for p in here.rglob("*.py")}
    assert want <= have, f"modules missing from the installed package: {sorted(want - have)}"
    for mod in pkgutil.walk_packages(profrobot.__path__, "profrobot."):
        if mod.name.endswith((".ray_cluster", ".scorers")):   # extras (ray, transformers) may be absent
            continue
        importlib.import_module(mod.name)


@pytest.mark.skipif(os.environ.get("PROFROBOT_WHEEL") != "1", reason="only where .ci/run tests the built wheel")
def test_the_tests_import_the_installed_wheel():
    here = Path(profrobot.__file__).resolve()
    assert "site-packages" in here.parts and ROOT not in here.parents
    assert Path(profrobot._core.__file__).name == "_core.abi3.so"
