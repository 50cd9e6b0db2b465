"""The documentation is tested like code: every Python block of every page in ``docs/`` runs, a
page as one script in a fresh folder and a fresh process, in order; every public name has a
docstring; and the built site (``mkdocs build --strict``) has every public name in its API
reference.

A page says what it needs in a comment near its top, ``<!-- docs-test: FLAGS -->``:
``slow`` (runs with ``--slow``, as ``.ci/run`` does), ``gl`` (draws with MuJoCo: skipped with the
reason where nothing renders), ``viewer`` / ``ray`` / ``clip`` (the extra of that name; skipped
with what to install where it is missing).
"""

from __future__ import annotations

import importlib
import inspect
import os
import pkgutil
import re
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

import profrobot

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
FLAGS = {"slow", "gl", "viewer", "ray", "clip"}
#: the module each extra flag needs, and what installs it
EXTRAS = {"viewer": ("viser", 'pip install ".[viewer]"'), "ray": ("ray", 'pip install ".[ray]"'),
          "clip": ("transformers", 'pip install ".[clip]"')}


def page_blocks(text: str) -> list[str]:
    """The page's Python blocks (```python fences), in order."""
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def page_flags(text: str) -> set[str]:
    found = set()
    for flags in re.findall(r"<!--\s*docs-test:\s*(.*?)\s*-->", text):
        found |= set(flags.split())
    if found - FLAGS:
        raise ValueError(f"unknown docs-test flags {sorted(found - FLAGS)}; known: {sorted(FLAGS)}")
    return found


def run_page(page: Path, cwd: Path, timeout: float = 1500) -> subprocess.CompletedProcess:
    """The page's blocks as one script, run in ``cwd`` by a fresh interpreter. Warnings that
    profrobot's own code raises at the page (DeprecationWarning) are errors."""
    script = "\n\n".join(page_blocks(page.read_text()))
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-W", "error::DeprecationWarning:__main__", "-c", script], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=timeout)


def _pages():
    params = []
    for page in sorted(DOCS.rglob("*.md")):
        text = page.read_text()
        if not page_blocks(text):
            continue
        flags = page_flags(text)
        marks = [getattr(pytest.mark, f) for f in ("slow", "gl") if f in flags]
        params.append(pytest.param(page, marks=marks, id=str(page.relative_to(DOCS))))
    return params


PAGES = _pages()


def test_the_task_pages_have_examples():
    """Every guide page but the ones that are prose about the shell has code that runs."""
    with_code = {p.values[0].relative_to(DOCS).as_posix() for p in PAGES}
    for page in sorted((DOCS / "guide").glob("*.md")):
        assert page.relative_to(DOCS).as_posix() in with_code, f"{page.name} has no Python block"


@pytest.mark.parametrize("page", PAGES)
def test_page_runs(page: Path, tmp_path):
    flags = page_flags(page.read_text())
    if "gl" in flags:
        from profrobot import gl

        backend, why = gl.status()
        if backend is None:
            pytest.skip(f"the page draws with MuJoCo: {why}")
    for flag, (module, install) in EXTRAS.items():
        if flag in flags:
            try:
                importlib.import_module(module)
            except ImportError:
                pytest.skip(f"the page needs the {flag} extra: {install}")
    done = run_page(page, tmp_path)
    assert done.returncode == 0, f"{page.relative_to(ROOT)} failed:\n{done.stderr[-4000:]}"


def test_a_broken_example_fails_the_page(tmp_path):
    """The runner is not a formality: a page whose example is wrong fails (here a result
    attribute that does not exist, and an assertion that does not hold)."""
    page = tmp_path / "broken.md"
    page.write_text("# Broken\n\n```python\nimport profrobot\nrobot = profrobot.scenes.load('panda_blocks')\n"
                    "q = profrobot.sample_poses(robot, 10, seed=0)\n```\n\nText.\n\n```python\n"
                    "profrobot.label_poses(robot, q).colliding\n```\n")
    done = run_page(page, tmp_path)
    assert done.returncode != 0 and "AttributeError" in done.stderr and "colliding" in done.stderr
    page.write_text("```python\nimport profrobot\nassert profrobot.CLEARANCE > 1\n```\n")
    assert run_page(page, tmp_path).returncode != 0
    with pytest.raises(ValueError, match="unknown docs-test flags"):
        page_flags("<!-- docs-test: slwo -->")


# ---- the API reference ----------------------------------------------------------------------------

def public_names() -> dict[str, object]:
    """``{"profrobot.name": object}`` for every name in ``profrobot.__all__`` and in each layer
    package's ``__all__`` (the command line's helpers excepted: its reference is ``--help``)."""
    packages = ["profrobot"] + [m.name for m in pkgutil.iter_modules(profrobot.__path__, "profrobot.")
                                if m.ispkg and m.name != "profrobot.cli"]
    names = {}
    for package in packages:
        mod = importlib.import_module(package)
        for name in getattr(mod, "__all__", []):
            names[f"{package}.{name}"] = getattr(mod, name)
    return names


def test_every_public_function_and_class_has_a_docstring():
    def documented(obj) -> bool:
        doc = (obj.__doc__ or "").strip()
        # a dataclass with no docstring of its own gets its signature as one
        return bool(doc) and not (inspect.isclass(obj) and doc.startswith(f"{obj.__name__}("))

    missing = [name for name, obj in public_names().items()
               if (inspect.isfunction(obj) or inspect.isclass(obj)) and not documented(obj)]
    assert missing == []


def _inventory(site: Path) -> set[str]:
    """The object names of a built site's ``objects.inv`` (Sphinx's format, which mkdocstrings
    writes): four header lines, then zlib-compressed lines ``name domain:role priority uri name``."""
    raw = (site / "objects.inv").read_bytes()
    body = raw.split(b"\n", 4)[4]
    return {line.split(" ", 1)[0] for line in zlib.decompress(body).decode().splitlines() if line.strip()}


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site as ``.ci/run`` builds it (``PROFROBOT_SITE``), or built here, strictly."""
    if os.environ.get("PROFROBOT_SITE"):
        return Path(os.environ["PROFROBOT_SITE"])
    pytest.importorskip("mkdocs", reason='the documentation site needs the docs extra: pip install ".[docs]"')
    pytest.importorskip("mkdocstrings", reason='the documentation site needs the docs extra: pip install ".[docs]"')
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-4000:]
    return out


def test_the_api_reference_has_every_public_name(site):
    documented = _inventory(site)
    missing = sorted(name for name, obj in public_names().items() if not inspect.ismodule(obj) and name not in documented)
    assert missing == [], f"public names with no entry in the API reference: {missing}"


def test_the_site_has_the_pages_the_issue_names(site):
    for page in ("index.html", "install/index.html", "architecture/index.html", "errors/index.html",
                 "benchmarks/index.html", "changelog/index.html", "reference/index.html",
                 "benchmarks/labelling/index.html", "guide/viewer/index.html"):
        assert (site / page).is_file(), page
    viewer = (site / "guide/viewer/index.html").read_text()
    assert "viewer_certified.png" in viewer and (site / "benchmarks/shots/viewer_certified.png").is_file()
    assert "0.1.0" in (site / "changelog/index.html").read_text()
