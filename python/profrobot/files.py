"""One house for writing files and checking whose they are.

:func:`atomic_path` and :func:`atomic_dir` write beside the target and rename over it, so an
interrupted write leaves the old file (or directory) or the new one, never half of one; the
result keeps the user's umask (``mkstemp``/``mkdtemp`` would leave 0600 / 0700).
:func:`check_robot` is the single refusal of data made for another robot.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from .errors import CorruptFileError, MissingFileError, RobotMismatchError

__all__ = ["atomic_path", "atomic_dir", "check_robot", "current_umask"]


def current_umask() -> int:
    """The process umask, read without changing it where the OS allows (Linux), so that other
    threads never see a zero umask."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fsync_path(path: str | os.PathLike) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:  # some filesystems refuse fsync on directories
        pass
    finally:
        os.close(fd)


def _fsync_dir(path: str | os.PathLike) -> None:
    if os.name == "posix":
        _fsync_path(path)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in ``path``'s folder (created if needed) to write to; on success
    it is fsynced and renamed over ``path`` with permissions ``0o666 & ~umask``, on any error it
    is removed and ``path`` is left untouched.

    The temporary name ends with ``suffix`` (default: ``path``'s own suffix), so writers that
    pick a format from the name (matplotlib, imageio) or append one (``np.savez`` adds ``.npz``
    unless the name ends with it) keep working.
    """
    path = Path(path)
    if suffix is None:
        suffix = path.suffix
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if not tmp.is_file():
            raise MissingFileError(f"nothing was written to the temporary file {tmp} (meant for {path})")
        _fsync_path(tmp)
        os.chmod(tmp, 0o666 & ~current_umask())
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a fresh temporary directory beside ``path`` to fill; on success its files are
    fsynced and it is swapped into place (an existing ``path`` is replaced), with permissions
    ``0o777 & ~umask`` (its files ``0o666 & ~umask``); on any error it is removed and ``path`` is left untouched."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        umask = current_umask()
        for root, dirs, files in os.walk(tmp):
            for name in files:  # some writers (safetensors) leave 0600 files
                f = os.path.join(root, name)
                _fsync_path(f)
                os.chmod(f, 0o666 & ~umask)
            for name in dirs:
                os.chmod(os.path.join(root, name), 0o777 & ~umask)
        os.chmod(tmp, 0o777 & ~umask)
        _fsync_dir(tmp)
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            os.replace(path, old / "d")  # a rename; old is ours alone, so no collision
            try:
                os.replace(tmp, path)
            except BaseException:
                os.replace(old / "d", path)
                raise
            finally:
                shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
        _fsync_dir(path.parent)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def check_robot(meta: Mapping[str, Any] | str | None, robot: Any, what: str, *,
                made_for: str | None = None, missing_ok: bool = False, geometry: bool = False) -> None:
    """Raise :class:`~profrobot.errors.RobotMismatchError` unless ``meta`` was made for ``robot``.

    ``meta`` is a fingerprint or a mapping holding ``robot_fingerprint`` (and ``robot`` or
    ``robot_name``, the name shown); ``robot`` anything with ``fingerprint`` and ``name`` (or
    ``robot_name``): a :class:`~profrobot.Robot`, a PoseSDF, a GaussianRobot. ``what`` names the
    thing refused, e.g. ``"checkpoint runs/panda_sdf"``. With ``missing_ok``, data that carries
    no fingerprint is accepted. With ``geometry`` (fields, views, Gaussians: made for the robot's
    geometry, not its labels), a robot with a safety margin (:meth:`~profrobot.Robot.with_margin`)
    is accepted by its ``geometry_fingerprint`` too.
    """
    if isinstance(meta, Mapping):
        fingerprint = meta.get("robot_fingerprint")
        made_for = made_for if made_for is not None else meta.get("robot", meta.get("robot_name"))
    else:
        fingerprint = meta
    if fingerprint is None and missing_ok:
        return
    given_fp = getattr(robot, "fingerprint", None) or getattr(robot, "robot_fingerprint", None)
    if fingerprint == given_fp and fingerprint is not None:
        return
    if geometry and fingerprint is not None and fingerprint == getattr(robot, "geometry_fingerprint", None):
        return
    given = getattr(robot, "name", None) or getattr(robot, "robot_name", None)
    raise RobotMismatchError(f"{what} was made for robot {made_for!r} (fingerprint {fingerprint}), "
                             f"not for {given!r} (fingerprint {given_fp})")


def format_tag(kind: str, version: int) -> str:
    """The tag every profrobot file (and pickle state) carries: ``"profrobot.<kind>/<version>"``."""
    return f"profrobot.{kind}/{version}"


def check_format(found: Any, kind: str, version: int, where: str, *, missing: int | None = None) -> int:
    """The version of a file whose tag is ``found`` (see :func:`format_tag`), which must be a
    ``kind`` file that this release reads (version 1 … ``version``); ``missing``: the version
    assumed for files written before they carried a tag (None: a tag is required).

    A newer version raises :class:`~profrobot.errors.CorruptFileError` naming both versions and
    what to do; anything that is not a ``kind`` tag raises it saying what was found.
    """
    if found is None and missing is not None:
        return missing
    prefix = f"profrobot.{kind}/"
    if isinstance(found, str) and found.startswith(prefix) and found[len(prefix):].isdigit():
        v = int(found[len(prefix):])
        if 1 <= v <= version:
            return v
        if v > version:
            from ._core import __version__

            raise CorruptFileError(f"{where} is a {kind} file of format version {v}, written by a newer profrobot; "
                                   f"profrobot {__version__} reads versions up to {version}: upgrade profrobot "
                                   f"(pip install -U profrobot) to read it")
    raise CorruptFileError(f"{where} is not a profrobot {kind} file (format {found!r}; expected {format_tag(kind, version)!r})")
