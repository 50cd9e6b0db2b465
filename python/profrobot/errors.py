"""profrobot's exceptions: one family, told apart by type, never by message text.

``ProfrobotError`` (a ``ValueError``, so ``except ValueError`` keeps working) is the root;
``ModelError`` is raised by the Rust core (invalid model or input), ``RobotMismatchError`` when a
file or object was made for another robot (fingerprints differ), ``CorruptFileError`` when a
file cannot be read as what it claims to be.
"""

from __future__ import annotations

from ._core import ModelError, ProfrobotError

__all__ = ["ProfrobotError", "ModelError", "RobotMismatchError", "CorruptFileError"]


class RobotMismatchError(ProfrobotError):
    """A dataset, checkpoint, view set or fitted model was made for another robot."""


class CorruptFileError(ProfrobotError):
    """A file is missing parts, truncated, or not in the format it should be."""
