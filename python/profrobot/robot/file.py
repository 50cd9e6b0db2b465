"""A robot in a file: ``robot.save(path)`` and ``Robot.load(path)`` call :func:`write` and
:func:`read` (base layer: no torch; the class is passed in, so this module imports no ``Robot``).

A :class:`~profrobot.Robot`'s pickle already carries everything that built it (the MJCF or URDF
text, every mesh's bytes, the obstacles, clouds, margins and collision matrix added since:
:meth:`Robot.__getstate__`), so a robot in its cell, with its obstacles, travels as one file,
and a field directory (``PoseSDF.save``) stores the robot it was trained for beside its weights.

Reading is restricted, as ``torch.load(weights_only=True)`` is: :class:`_RobotUnpickler` builds
only classes defined in profrobot, numpy arrays and dtypes, and the one attribute look-up a
``RobotModel`` pickle makes (``RobotModel._from_state``). Anything else a file names (``os.system``,
``builtins.eval``, a class of another package) raises :class:`~profrobot.errors.CorruptFileError`
naming it, before it is called: loading a robot file runs none of its author's code.
"""

from __future__ import annotations

import io
import os
import pickle
from pathlib import Path

from typing import Any

from ..errors import CorruptFileError, InputTypeError, MissingFileError
from ..files import atomic_path

__all__ = ["write", "read", "stored", "ROBOT_FILE"]

ROBOT_FILE = "robot.pkl"   # the name a field directory stores its robot under

# numpy's own pickles of arrays, dtypes and scalars (numpy 1.x and 2.x module names)
_NUMPY = {("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.multiarray", "_reconstruct"),
          ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "scalar"),
          ("numpy._core.multiarray", "scalar"), ("numpy.core.numeric", "_frombuffer"),
          ("numpy._core.numeric", "_frombuffer")}
_BUILTINS = {"set", "frozenset", "slice", "complex", "bytearray", "range"}


def _state_getattr(obj, name: str):
    """The ``getattr`` a ``RobotModel`` pickle calls (``RobotModel._from_state``), and no other."""
    from .._core import RobotModel

    if obj is RobotModel and name == "_from_state":
        return RobotModel._from_state
    raise CorruptFileError(f"a robot file may look up RobotModel._from_state only; this one asks for "
                           f"{getattr(obj, '__name__', type(obj).__name__)}.{name}")


class _RobotUnpickler(pickle.Unpickler):
    """An unpickler that builds profrobot's own classes, numpy arrays and a few builtin
    containers, and refuses every other global a file names (module docs)."""

    def __init__(self, file, where: str):
        super().__init__(file)
        self.where = where

    def find_class(self, module: str, name: str):
        if (module, name) in _NUMPY:
            return super().find_class(module, name)
        if module == "builtins" and name in _BUILTINS:
            return super().find_class(module, name)
        if module == "builtins" and name == "getattr":
            return _state_getattr
        if module == "profrobot" or module.startswith("profrobot."):
            try:
                obj = super().find_class(module, name)
            except (ImportError, AttributeError):
                from .._core import __version__

                raise CorruptFileError(f"{self.where}: it names {module}.{name}, which profrobot {__version__} does "
                                       "not have: written by another profrobot (one before 0.1.0, whose modules "
                                       "were laid out otherwise, or a newer one); build the robot again and save "
                                       "it") from None
            if isinstance(obj, type) and getattr(obj, "__module__", "").startswith("profrobot"):
                return obj
        raise CorruptFileError(f"{self.where}: it names {module}.{name}, which a robot file may not (only "
                               "profrobot's classes and numpy arrays): not a file save_robot wrote, or tampered with")


def write(robot: Any, path: str | os.PathLike) -> Path:
    """``robot.save(path)``: its pickle (protocol 5: the MJCF or URDF text, the meshes' bytes,
    obstacles, cloud, margin, collision matrix; a Panda cell is about 6 MB), written atomically."""
    path = Path(path)
    data = pickle.dumps(robot, protocol=5)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def read(path: str | os.PathLike, cls: type) -> Any:
    """``Robot.load(path)``: the ``cls`` a robot file at ``path`` holds (or a field directory's
    ``robot.pkl``).

    Raises :class:`~profrobot.errors.MissingFileError` for no file and
    :class:`~profrobot.errors.CorruptFileError` for one that is not a robot, is truncated, was
    written by another format, or names anything but profrobot's classes and numpy arrays (it is
    refused before anything it names is called: module docs)."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputTypeError(f"path must be a file path; got {type(path).__name__}")
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"no robot file at {str(path)!r}")
    data = path.read_bytes()
    try:
        robot = _RobotUnpickler(io.BytesIO(data), str(path)).load()
    except CorruptFileError:
        raise
    except Exception as e:   # truncated, not a pickle, a state the classes refuse
        raise CorruptFileError(f"{path}: not a robot file robot.save wrote ({type(e).__name__}: {e})") from None
    if not isinstance(robot, cls):
        raise CorruptFileError(f"{path}: holds a {type(robot).__name__}, not a profrobot.Robot")
    return robot


def stored(folder: str | os.PathLike, cls: type) -> Any:
    """The ``cls`` a field checkpoint directory stores (``folder/robot.pkl``, read as :func:`read`
    does), or None where it stores none (directories written before fields stored their robot)."""
    file = Path(folder) / ROBOT_FILE
    return read(file, cls) if file.is_file() else None
