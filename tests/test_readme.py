"""The README is the front page: its first bash block is the two set-up commands, its first
example runs as written, and it stays short (the guide is the documentation site, docs/)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path


README = Path(__file__).resolve().parents[1] / "README.md"


def blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_readme_has_the_two_setup_commands_first():
    text = README.read_text()
    first = re.search(r"```bash\n(.*?)```", text, flags=re.S)
    assert first and text.index(first.group(0)) < text.index("```python")
    lines = first.group(1).strip().splitlines()
    assert len(lines) == 2 and lines[0].startswith("pip install .") and "pytest" in lines[1]


def test_readme_is_a_front_page():
    """At most 150 lines; every relative link and picture points at a file that is there."""
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
        if not target.startswith(("http://", "https://")):
            assert (README.parent / target).exists(), target


def test_readme_python_blocks_run(tmp_path):
    """The first example, as written, in a fresh process and folder."""
    code = blocks()
    assert code, "the README has a first example"
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-W", "error::DeprecationWarning:__main__", "-c", "\n\n".join(code)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]
    assert "certified: True" in done.stdout
