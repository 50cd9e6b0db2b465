"""Pictures and views: :func:`sdf_slice` (a field slice over two joints with the exact labels
drawn over it; torch), :func:`save_figure`, and :class:`Viewer`, a live 3-D view in the browser
(viser; ``pip install ".[viewer]"``). Each is imported when first used: the viewer needs no torch
unless a field slice is shown, and ``import profrobot.viz`` loads neither."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # for type checkers and the API reference (loaded on first use)
    from .slices import save_figure, sdf_slice
    from .viewer import VERDICT_COLOURS, Viewer

__all__ = ["sdf_slice", "save_figure", "Viewer", "VERDICT_COLOURS"]

_LAZY = {"sdf_slice": ".slices", "save_figure": ".slices", "Viewer": ".viewer", "VERDICT_COLOURS": ".viewer"}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
