"""The learned pose collision field (paper §3): :class:`PoseSDF`, :func:`train_sdf`, metrics,
checkpoints and export."""

import os
import warnings
from pathlib import Path

from .checkpoint import export_sdf
from .identity import check_field, field_robot
from .metrics import evaluate, format_metrics
from .model import PoseSDF
from .train import PRESETS, TrainConfig, train_sdf

__all__ = ["PoseSDF", "train_sdf", "TrainConfig", "PRESETS", "evaluate", "format_metrics", "export_sdf",
           "save_sdf", "load_sdf", "check_field", "field_robot"]


def save_sdf(sdf: PoseSDF, path: str | os.PathLike) -> Path:
    """Deprecated: ``sdf.save(path)``."""
    warnings.warn("save_sdf(sdf, path) is deprecated; use sdf.save(path)", DeprecationWarning, stacklevel=2)
    return sdf.save(path)


def load_sdf(path: str | os.PathLike, robot) -> PoseSDF:
    """Deprecated: ``PoseSDF.load(path, robot)``."""
    warnings.warn("load_sdf(path, robot) is deprecated; use profrobot.PoseSDF.load(path, robot)", DeprecationWarning,
                  stacklevel=2)
    return PoseSDF.load(path, robot)
