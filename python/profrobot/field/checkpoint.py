"""Checkpoints: a directory with ``model.safetensors`` (weights and buffers), ``config.json``
(architecture, robot fingerprint, metrics) and ``robot.pkl``, the robot it was trained for, in its
cell (``Robot.save``: read back by a restricted unpickler that builds
profrobot's classes and numpy arrays only), so that ``PoseSDF.load(path)`` and every command
given ``--field`` need nothing else. Export for deployment with ``torch.export``."""

from __future__ import annotations

import json
import os
from pathlib import Path
from collections.abc import Mapping
from typing import Any, Protocol, TypeVar

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from ..files import atomic_dir, atomic_path, check_format, check_robot, format_tag
from ..errors import CorruptFileError, InputError, InputTypeError, MissingFileError
from ..robot.robot import Robot
from ..robot.file import ROBOT_FILE, stored as stored_robot


class _Checkpointable(Protocol):
    """What :func:`read_checkpoint` needs of the field class it builds (a PoseSDF)."""

    metrics: dict

    def __init__(self, robot: Robot, **model: Any) -> None: ...

    def load_state_dict(self, state_dict: Mapping[str, Any], strict: bool = ..., assign: bool = ...) -> Any: ...

    def eval(self) -> Any: ...


#: the field class read_checkpoint builds (``PoseSDF.load`` passes itself: model.py imports this
#: module, so this module names no class of model.py; ``sdf`` arguments are PoseSDFs)
Field = TypeVar("Field", bound=_Checkpointable)

FORMAT_VERSION = 1
FORMAT = format_tag("PoseSDF", FORMAT_VERSION)


def write_checkpoint(sdf: Any, path: str | os.PathLike) -> Path:
    """Save ``sdf`` to the directory ``path`` (created or replaced atomically): :meth:`PoseSDF.save`."""
    path = Path(path)
    tensors = {k: v.detach().cpu().contiguous() for k, v in sdf.state_dict().items()}
    config = dict(format=FORMAT, robot=sdf.robot_name, robot_fingerprint=sdf.fingerprint,
                  joint_names=sdf.joint_names, model=sdf.config, family=family_description(sdf),
                  metrics={k: v for k, v in sdf.metrics.items() if isinstance(v, (int, float, str))})

    with atomic_dir(path) as d:
        save_file(tensors, str(d / "model.safetensors"), metadata={"format": FORMAT})
        (d / "config.json").write_text(json.dumps(config, indent=2))
        sdf.robot.save(d / ROBOT_FILE)
    return path


def read_checkpoint(cls: type[Field], path: str | os.PathLike, robot: Robot | None = None) -> Field:
    """Load a checkpoint saved by :func:`write_checkpoint` for ``robot`` as a ``cls``:
    :meth:`PoseSDF.load`. ``robot=None``: the robot stored beside the weights (``robot.pkl``;
    checkpoints written before it was stored need ``robot``).

    Raises :class:`~profrobot.errors.RobotMismatchError` if the checkpoint is for another robot
    (its fingerprint differs), :class:`~profrobot.errors.CorruptFileError` if its files are
    missing or corrupt (both are ``ValueError``), :class:`~profrobot.errors.MissingFileError` if
    the directory does not exist.
    """
    path = Path(path)
    cfg_path, w_path = path / "config.json", path / "model.safetensors"
    if not path.exists():   # missing, as a missing dataset or model file is
        raise MissingFileError(f"no PoseSDF checkpoint directory at {str(path)!r}")
    if not cfg_path.is_file() or not w_path.is_file():
        raise CorruptFileError(f"{path} is not a PoseSDF checkpoint (needs config.json and model.safetensors)")
    try:
        config = json.loads(cfg_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise CorruptFileError(f"corrupt checkpoint config {cfg_path}: {e}") from e
    if not isinstance(config, dict):
        raise CorruptFileError(f"{cfg_path} is not a {FORMAT} config")
    check_format(config.get("format"), "PoseSDF", FORMAT_VERSION, str(cfg_path))
    if not isinstance(config.get("model"), dict):
        raise CorruptFileError(f"{cfg_path} is not a {FORMAT} config: it has no model section")
    stored = robot is None
    if stored:
        robot = stored_robot(path, Robot)
        if robot is None:
            raise MissingFileError(f"checkpoint {path} stores no robot (written before fields stored theirs): pass the "
                                   f"profrobot.Robot it was trained for, {config.get('robot')!r}: PoseSDF.load(path, robot)")
    elif not isinstance(robot, Robot):
        raise InputTypeError(f"PoseSDF.load needs the profrobot.Robot the field was trained for; got {type(robot).__name__}")
    # the stored robot is the one the weights were saved with (the pair must be whole: its exact
    # fingerprint); a robot passed may also be that robot with a safety margin (geometry)
    check_robot(config, robot, f"checkpoint {path}'s stored robot {ROBOT_FILE}" if stored else f"checkpoint {path}",
                geometry=not stored)
    family = config.get("family")
    if (family or {}).get("scene_joints", []) != list(getattr(robot, "scene_joints", ())):
        raise CorruptFileError(f"{cfg_path}: its family's scene joints {(family or {}).get('scene_joints', [])} are not "
                               f"the robot's {list(getattr(robot, 'scene_joints', ()))}")
    try:
        tensors = load_file(str(w_path))
    except (SafetensorError, OSError, ValueError) as e:
        raise CorruptFileError(f"corrupt checkpoint weights {w_path}: {e}") from e
    try:
        sdf = cls(robot, **config["model"])
    except (TypeError, ValueError) as e:
        raise CorruptFileError(f"{cfg_path} describes no valid PoseSDF: {e}") from e
    try:
        sdf.load_state_dict(tensors, strict=True)
    except RuntimeError as e:
        raise CorruptFileError(f"checkpoint weights {w_path} do not fit the architecture in its config: {e}") from e
    sdf.metrics = dict(config.get("metrics", {}))
    sdf.eval()
    return sdf


def family_description(sdf: Any) -> dict | None:
    """For a field of a family of scenes: its scene joints and their ranges (radians / metres),
    written beside the weights so that a reader knows what δ means; None otherwise."""
    if not getattr(sdf, "scene_joints", None):
        return None
    limits = sdf.robot.joint_limits[sdf.scene_index.cpu().numpy()]   # float64, as the family says
    return dict(scene_joints=list(sdf.scene_joints), ranges=limits.tolist(),
                robot_joints=[sdf.joint_names[i] for i in sdf.robot_index.tolist()])


class _Deployable(torch.nn.Module):
    """θ (B, K) → g (B,), without the Python-side checks (export traces tensors only)."""

    def __init__(self, sdf: Any):
        super().__init__()
        self.sdf = sdf

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        return self.sdf.head_g(self.sdf.encoder(theta))


def export_sdf(sdf: Any, path: str | os.PathLike, *, batch: int = 1024) -> int:
    """Export ``sdf`` with ``torch.export`` to a ``.pt2`` file (dynamic batch size); returns its
    size in bytes. Load it with ``torch.export.load(path).module()``: θ (B, K) → g (B,). The file
    carries ``profrobot.json`` (``torch.export.load(path, extra_files={"profrobot.json": ""})``):
    robot, fingerprint, joint names and, for a family field, its scene joints and ranges (the
    exported program takes the full vectors (θ, δ) in that joint order)."""
    path = Path(path)
    if not hasattr(sdf, "head_g"):
        raise InputError(f"export_sdf needs a PoseSDF; got {type(sdf).__name__} (for a LayoutField, export its family "
                         "field .field: it takes the full vectors (θ, δ))")
    sdf = sdf.eval()
    example = torch.zeros(batch, sdf.njoint)
    dim = torch.export.Dim("batch", min=1)
    program = torch.export.export(_Deployable(sdf), (example,), dynamic_shapes={"theta": {0: dim}})
    with atomic_path(path, suffix=".pt2") as tmp:
        meta = dict(format=FORMAT, robot=sdf.robot_name, robot_fingerprint=sdf.fingerprint,
                    joint_names=list(sdf.joint_names), family=family_description(sdf))
        torch.export.save(program, tmp, extra_files={"profrobot.json": json.dumps(meta)})
    return path.stat().st_size
