"""Writing a bench's results file (torch-free, imported by the benches that write one): the
generated part replaced, the notes a person wrote below the `NOTES` line kept, atomically."""

from __future__ import annotations

from pathlib import Path

from profrobot.files import atomic_path

#: The line after which a results file's hand-written notes start: a bench that writes the file
#: again keeps everything from it on.
NOTES = "<!-- notes: kept when the bench writes this file again -->"


def write_results(path: Path, text: str) -> None:
    """``text`` (the bench's tables) into ``path``, followed by the notes of the file there now
    (from its `NOTES` line on, if it has one), written atomically."""
    old = path.read_text() if path.exists() else ""
    notes = old[old.index(NOTES):] if NOTES in old else ""
    with atomic_path(path) as tmp:
        tmp.write_text(text.rstrip("\n") + "\n" + ("\n" + notes if notes else ""))
