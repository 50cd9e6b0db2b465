"""The learned pose collision field (paper §3): :class:`PoseSDF`, :func:`train_sdf`, metrics,
checkpoints and export."""

from .checkpoint import export_sdf
from .identity import check_field
from .metrics import evaluate, format_metrics
from .model import PoseSDF
from .train import PRESETS, TrainConfig, train_sdf

__all__ = ["PoseSDF", "train_sdf", "TrainConfig", "PRESETS", "evaluate", "format_metrics", "export_sdf",
           "check_field"]
