"""profrobot's exceptions: one family, told apart by type, never by message text.

::

    ProfrobotError                      every error profrobot raises on purpose (root)
    ├── InputError (ValueError)         bad input: a shape, a NaN, an option out of range
    │   ├── ModelError                  a model the Rust core cannot label exactly (also a geom pair
    │   │                               its narrow phase cannot decide: never read as "free")
    │   ├── RobotMismatchError          a file or object made for another robot
    │   ├── CorruptFileError            a file that cannot be read back as what it claims to be
    │   └── MissingFileError            a file or directory that does not exist (also FileNotFoundError)
    ├── InputTypeError (TypeError)      an argument of the wrong type or dtype (from the Rust core)
    ├── ClusterError (RuntimeError)     a Ray cluster that cannot be reached or lost work
    ├── WorkerError (RuntimeError)      a local worker process that died
    ├── ImmutableError (AttributeError) an attribute of an immutable object set, or one it lacks
    ├── RendererUnavailableError        no OpenGL backend can draw (RuntimeError)
    └── BackendUnavailableError         a backend asked for by name cannot run (RuntimeError)

The root is not a ``ValueError``: a missing renderer or a dead cluster is not a bad value. Every
bad-input error still is one (``except ValueError`` keeps catching them), and the Rust core raises
``InputError``, ``ModelError`` and ``InputTypeError`` itself: every deliberate error from Rust is a
``ProfrobotError``.
"""

from __future__ import annotations

from ._core import InputError, InputTypeError, ModelError, ProfrobotError

__all__ = ["ProfrobotError", "InputError", "InputTypeError", "ModelError", "RobotMismatchError",
           "CorruptFileError", "MissingFileError", "ClusterError", "WorkerError", "ImmutableError", "RendererUnavailableError", "BackendUnavailableError"]


class RobotMismatchError(InputError):
    """A dataset, checkpoint, view set or fitted model was made for another robot."""


class CorruptFileError(InputError):
    """A file is missing parts, truncated, or not in the format it should be (or written by a
    newer profrobot: the message names both versions)."""


class MissingFileError(InputError, FileNotFoundError):
    """A file or directory profrobot was asked to read does not exist (a dataset, a field's
    checkpoint directory, a model, a robot file). Also a ``FileNotFoundError``."""


class ClusterError(ProfrobotError, RuntimeError):
    """The Ray cluster cannot be reached, cannot start workers, or lost a chunk more times than
    ``max_retries`` allows. The message names the address and the time-out that ran out."""


class WorkerError(ProfrobotError, RuntimeError):
    """A local worker process (``LocalExecutor``) died; the message says how (its exit status or
    signal, and the last lines it wrote)."""


class ImmutableError(ProfrobotError, AttributeError):
    """An attribute of an immutable object (``PointCloud``, ``Cameras``) was set, or read where
    that kind of object has none. Also an ``AttributeError`` (``hasattr`` is False)."""


class RendererUnavailableError(ProfrobotError, RuntimeError):
    """No OpenGL backend could render here; the message says what to install."""


class BackendUnavailableError(ProfrobotError, RuntimeError):
    """A compute backend asked for by name (``backend="gsplat"``) cannot run here; the message
    says why. ``backend="auto"`` never raises it: it picks one that runs."""
