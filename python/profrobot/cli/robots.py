"""A robot named on the command line: a bundled scene or family (``--scene NAME``), or a file
(``--robot FILE``: MJCF ``.xml``, URDF ``.urdf`` with meshes through ``--package-dir``, or a
robot file ``.pkl`` from ``robot.save``). A command given ``--field DIR`` and
neither takes the robot the field directory stores. Every command takes these (base layer: no
torch)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from .. import scenes
from ..errors import InputError
from ..robot.robot import Robot
from ..robot.file import stored as stored_robot

if TYPE_CHECKING:   # the functions below import numpy themselves
    import numpy as np

__all__ = ["robot_file", "add_robot_arguments", "robot_of", "field_robot", "numbers", "pose_arg", "layout_of",
           "negative_values", "DefaultsFormatter"]

DEFAULT_SCENE = "panda_blocks"


def robot_file(path: str, package_dirs: list[str] | None = None) -> Robot:
    """An MJCF (.xml), URDF (.urdf, or a ``<robot>`` root; meshes by ``package://`` through
    ``package_dirs``) or ``robot.save`` (.pkl) file, e.g. the robot in its cell
    that a field was trained for."""
    p = Path(path)
    if not p.is_file():
        if path in scenes.names() + scenes.family_names() and not package_dirs:  # a bundled name works too
            return scenes.load(path)
        raise InputError(f"--robot {path}: no such file (an MJCF .xml or a URDF .urdf, or a bundled scene: "
                         f"{', '.join(scenes.names() + scenes.family_names())})")
    if p.suffix.lower() == ".urdf":
        return Robot.from_urdf(p, package_dirs=package_dirs)
    if package_dirs:
        raise InputError("--package-dir is for URDF robots (--robot FILE.urdf)")
    if p.suffix.lower() == ".pkl":   # robot.save's file: the robot in its cell
        return Robot.load(p)
    return Robot.from_mjcf(p)


def add_robot_arguments(sp: argparse.ArgumentParser, *, scene_default: str | None = DEFAULT_SCENE) -> None:
    """``--scene NAME`` (bundled scenes and families), ``--robot FILE`` and ``--package-dir``."""
    every = scenes.names() + scenes.family_names()
    sp.add_argument("--scene", default=None,
                    help=f"a bundled scene or family of scenes: {', '.join(every)} "
                         f"(default: {scene_default or 'the one the field was trained for'}, unless --robot)")
    sp.add_argument("--robot", default=None, metavar="FILE",
                    help="the robot (and its cell) as a file instead: MJCF .xml, URDF .urdf, or "
                         "a robot.save .pkl")
    sp.add_argument("--package-dir", dest="package_dir", action="append", default=None, metavar="DIR",
                    help="where a URDF's package:// meshes live (a package's folder or a folder of packages; "
                         "repeatable)")
    sp.set_defaults(scene_default=scene_default)


def robot_of(args: argparse.Namespace, field: str | Path | None = None) -> Robot:
    """The robot ``args`` name (:func:`add_robot_arguments`): ``--robot FILE``, else ``--scene``,
    else, for a command given a field checkpoint directory ``field``, the robot the directory
    stores (or, for one written before fields stored their robot, the bundled scene it names),
    else the command's default scene."""
    robot = getattr(args, "robot", None)
    scene = getattr(args, "scene", None)
    if robot is not None and scene is not None:
        raise InputError("give --scene or --robot, not both")
    if robot is not None:
        return robot_file(robot, getattr(args, "package_dir", None))
    if getattr(args, "package_dir", None):
        raise InputError("--package-dir is for URDF robots (--robot FILE.urdf)")
    if scene is None and field is not None:
        return field_robot(field)
    name = scene or getattr(args, "scene_default", None) or DEFAULT_SCENE
    if name not in scenes.names() + scenes.family_names():
        raise InputError(f"--scene: unknown scene {name!r}; one of {', '.join(scenes.names() + scenes.family_names())} "
                         f"(or --robot FILE for your own)")
    return scenes.load(name)


def field_robot(field: str | Path) -> Robot:
    """The robot a field checkpoint directory was trained for: the one it stores
    (``robot.pkl``), else, for directories written before fields stored their robot, the bundled
    scene its config.json names; a clear error saying to name the robot otherwise."""
    import json

    from ..errors import CorruptFileError, MissingFileError

    field = Path(field)
    if not field.is_dir():
        raise MissingFileError(f"--field {field}: no such checkpoint directory (profrobot train --out)")
    robot = stored_robot(field, Robot)
    if robot is not None:
        return robot
    cfg = field / "config.json"
    if not cfg.is_file():
        raise CorruptFileError(f"--field {field}: not a PoseSDF checkpoint (no config.json; profrobot train --out)")
    try:
        name = json.loads(cfg.read_text()).get("robot")
    except (ValueError, AttributeError, OSError) as e:
        raise CorruptFileError(f"--field {field}: unreadable config.json ({e})") from None
    if name not in scenes.names() + scenes.family_names():
        raise InputError(f"--field {field}: it stores no robot (written before fields stored theirs) and its robot "
                         f"{name!r} is not a bundled scene; pass --robot FILE (the MJCF, URDF or robot.save file it "
                         "was trained for) or --scene NAME")
    return scenes.load(name)


def numbers(text: str, option: str) -> np.ndarray:
    """``--option``'s comma-separated numbers (radians / metres) as a float64 array (K,)."""
    import numpy as np

    try:
        return np.array([float(v) for v in text.replace(" ", "").split(",") if v != ""])
    except ValueError:
        raise InputError(f"--{option} must be comma-separated numbers (radians / metres); got {text!r}") from None


def pose_arg(text: str, option: str, robot: Robot) -> np.ndarray:
    """``--option``'s one joint pose (radians / metres) as a float64 array: comma-separated
    numbers, or a file the commands write: a ``.npy`` array, or an ``.npz`` with ``poses`` (``ik``,
    ``resolve``) or ``path`` (``plan``); ``FILE:i`` picks row ``i`` (default: 0; for a path,
    ``:-1`` is its end)."""
    import re
    import zipfile

    import numpy as np

    from ..errors import CorruptFileError, MissingFileError

    picked = re.fullmatch(r"(.*\.np[yz]):(-?\d+)", text, flags=re.IGNORECASE)
    name, row = (picked.group(1), int(picked.group(2))) if picked else (text, None)
    if not name.lower().endswith((".npy", ".npz")):
        return numbers(text, option)
    if not Path(name).is_file():
        raise MissingFileError(f"--{option} {name}: no such file")
    try:
        data = np.load(name, allow_pickle=False)
        if name.lower().endswith(".npz"):
            key = next((k for k in ("poses", "path") if k in data.files), None)
            if key is None:
                raise CorruptFileError(f"--{option} {name}: holds {sorted(data.files)}, no 'poses' or 'path'")
            data = data[key]
        arr = np.asarray(data, dtype=np.float64)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as e:
        raise CorruptFileError(f"--{option} {name}: not a readable .npy / .npz array of numbers ({e})") from None
    if arr.ndim == 2:
        i = 0 if row is None else row
        if not -len(arr) <= i < len(arr):
            raise InputError(f"--{option} {text}: row {i} of {len(arr)}")
        arr = arr[i]
    elif row is not None:
        raise InputError(f"--{option} {text}: :{row} picks a row, but {name} holds one pose, shape {arr.shape}")
    if arr.ndim != 1:
        raise InputError(f"--{option} {text}: a pose is (K,) or a row of (N, K); got shape {arr.shape}")
    return arr


def layout_of(args: argparse.Namespace, robot: Robot) -> np.ndarray | None:
    """``--layout`` for a family of scenes (its scene joints at 0 by default), None for a robot
    with no scene joints (which refuses ``--layout``)."""
    import numpy as np

    text = getattr(args, "layout", None)
    if not robot.is_family:
        if text is not None:
            raise InputError(f"--layout is for a family of scenes; {robot.name} has no scene joints")
        return None
    if text is None:
        return np.zeros(len(robot.scene_index))
    delta = numbers(text, "layout")
    if len(delta) != len(robot.scene_index):
        raise InputError(f"--layout needs {len(robot.scene_index)} values, one per scene joint "
                         f"({', '.join(robot.scene_joints)}); got {len(delta)}")
    return delta


def negative_values(argv: list[str]) -> list[str]:
    """``--start -0.5,1.2`` as ``--start=-0.5,1.2``: argparse reads a value that starts with ``-``
    and is not one plain number as an option, so a pose or layout with a negative first value
    failed with "expected one argument"."""
    import re

    number_list = re.compile(r"^-\d*\.?\d+(?:[eE][-+]?\d+)?(?:,\s*-?\d*\.?\d+(?:[eE][-+]?\d+)?)*,?$")
    out: list[str] = []
    for a in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and number_list.match(a):
            out[-1] = f"{out[-1]}={a}"
        else:
            out.append(a)
    return out


class DefaultsFormatter(argparse.HelpFormatter):
    """``--help`` with each option's default, where it has one worth showing (not None, not a
    flag's False) and its help does not already name it."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("default" in text or default is None or default is argparse.SUPPRESS or action.nargs == 0
                or action.option_strings == []):   # (nargs 0: a flag, --help, --version)
            return text
        return f"{text} (default: {default})" if text else f"(default: {default})"
