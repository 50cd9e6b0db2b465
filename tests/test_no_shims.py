"""No deprecation shims: profrobot has never been released under other names, so old argument
names, aliases, argument orders and keyword dicts are not kept; the current names are the only
ones (the API reference, docs/reference/)."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]      # the checkout (the package may be installed elsewhere)
PKG = ROOT / "python" / "profrobot"

SHIMS = {
    "renamed_arguments": re.compile(r"\brenamed_arguments\b"),
    "deprecated_alias": re.compile(r"\bdeprecated_alias\b"),
    "DeprecationWarning": re.compile(r"\b(Pending)?DeprecationWarning\b"),
    "**legacy": re.compile(r"\*\*\s*legacy\b"),
    "*old_order": re.compile(r"(?<!\*)\*\s*old_order\b"),
    "deprecated": re.compile(r"deprecat", re.IGNORECASE),
}


def test_the_package_has_no_deprecation_shims():
    files = sorted(PKG.rglob("*.py"))
    assert files, f"no sources under {PKG}"
    found = []
    for path in files:
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            for name, pattern in SHIMS.items():
                if pattern.search(line):
                    found.append(f"{path.relative_to(ROOT)}:{n}: {name}: {line.strip()}")
    assert not found, "deprecation shims left in profrobot:\n" + "\n".join(found)


@pytest.mark.parametrize("module", ["profrobot.deprecation", "profrobot.optim.certify"])
def test_shim_modules_are_gone(module):
    assert not (PKG.joinpath(*module.split(".")[1:]).with_suffix(".py")).exists()
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(module)


def test_old_facade_names_are_gone():
    import profrobot

    for name in ("save_sdf", "load_sdf"):
        assert name not in profrobot.__all__
        assert not hasattr(profrobot, name)
