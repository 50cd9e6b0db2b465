"""The progress every long job shows: a tqdm bar on a terminal, and plain lines where the output is
a log (a file, a pipe, a CI job), where tqdm's own rule (``disable=None``: no bar without a
terminal) left a 6-minute ``profrobot train`` silent until it ended.

In a log a line is written at most every ``LOG_INTERVAL`` seconds (and at the end), each ending in
a newline: ``train panda_blocks:  41%| 1230/3000 [02:31<03:37, 8.1it/s]``.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any, TextIO

__all__ = ["progress_bar", "LOG_INTERVAL"]

#: seconds between two progress lines in a log
LOG_INTERVAL = 30.0


class _Lines:
    """A stream that turns tqdm's carriage-return redraws into one line each."""

    def __init__(self, stream: TextIO):
        self.stream = stream

    def write(self, text: str) -> int:
        line = text.replace("\r", "").strip()
        if line:
            self.stream.write(line + "\n")
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


def progress_bar(total: int | None = None, *, desc: str, unit: str = "it", progress: bool = True,
                 leave: bool = True, stream: TextIO | None = None, iterable: Iterable[Any] | None = None) -> Any:
    """A tqdm progress bar of ``total`` steps (or over ``iterable``): drawn on a terminal, lines in
    a log, nothing when ``progress`` is false. ``stream``: where it writes (default ``sys.stderr``)."""
    from tqdm import tqdm as plain
    from tqdm.auto import tqdm

    out = sys.stderr if stream is None else stream
    if not progress:
        return plain(iterable, total=total, desc=desc, unit=unit, disable=True)
    if stream is None and "ipykernel" in sys.modules:   # a notebook: tqdm's own widget
        return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave)
    if getattr(out, "isatty", lambda: False)():
        return plain(iterable, total=total, desc=desc, unit=unit, leave=leave, file=out)
    # a log: a line at most every LOG_INTERVAL seconds (the monitor thread too), and the last one
    return plain(iterable, total=total, desc=desc, unit=unit, file=_Lines(out), mininterval=LOG_INTERVAL,
                 maxinterval=LOG_INTERVAL, ascii=True, dynamic_ncols=False, ncols=100)
