"""profrobot: collision-aware robot pose optimisation.

The facade. Where a pose becomes a label: :func:`label_poses` → ``Robot.core.label`` (Rust,
``rust/collision/collide.rs``); booleans only, faster: :func:`collides` → ``Robot.core.collides``
(``rust/collision/fastpath.rs``).

```pycon
>>> import profrobot
>>> robot = profrobot.scenes.load("panda_blocks")
>>> poses = profrobot.sample_poses(robot, 1000, seed=0)          # (1000, 9), radians / metres
>>> labels = profrobot.label_poses(robot, poses)                 # exact, parallel
>>> hit = profrobot.collides(robot, poses)                       # == labels.collides, faster
>>> near = profrobot.nearest_free(robot, poses[hit][:10])        # the Δθ oracle: smallest move found
>>> report = profrobot.crosscheck(robot, poses)                  # MuJoCo on the same poses
>>> sdf = profrobot.train_sdf(robot)                             # the learned collision field
>>> g = sdf(torch.as_tensor(poses, dtype=torch.float32))         # (1000,), g > 0: colliding
```

``import profrobot`` loads neither torch, MuJoCo's OpenGL stack nor matplotlib: labelling,
datasets and the cross-check need none of them. The torch side (``PoseSDF``, ``train_sdf``,
``resolve``, ..., and the subpackages ``field``, ``optim``, ``render``, ``viz``) loads on first
attribute access (PEP 562).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

# Before anything imports mujoco or torch: mujoco without its GL stack (a MUJOCO_GL whose library
# is missing cannot break the import; rendering happens in worker processes), and triton's LLVM
# kept apart from Mesa's (a libLLVM mapped before triton loads crashed torch._dynamo's import).
from . import gl

gl.install_triton_guard()
gl.import_mujoco()

from . import scenes  # noqa: E402
from ._core import __version__  # noqa: E402
from .errors import RendererUnavailableError  # noqa: E402
from .exact.certification import (CLEARANCE, FirstContact, MotionCertificate, PathCheck, certify_motions,  # noqa: E402
                                  certify_poses, check_path, first_contact)
from .exact.crosscheck import CrosscheckReport, crosscheck, mujoco_labels  # noqa: E402
from .exact.dataset import Dataset, make_dataset  # noqa: E402
from .exact.labels import Labels, collides, interpolate, label_poses, sample_poses  # noqa: E402
from .exact.oracle import NearestFree, nearest_free  # noqa: E402
from .exact.planning import PathResult, plan_path  # noqa: E402
from .exact.ik import IKResult, PoseMotion, ik, plan_to_pose  # noqa: E402
from .exact.timing import TimedPath, time_path  # noqa: E402
from .exact.cartesian import CartesianPath, plan_cartesian  # noqa: E402
from .robot import Box, Capsule, Cylinder, Mesh, Obstacle, Plane, Robot, Sphere  # noqa: E402
from .robot.pointcloud import PointCloud  # noqa: E402
from .robot.family import Moves  # noqa: E402

if TYPE_CHECKING:  # what the lazy names are, for type checkers and the API reference (not loaded here)
    from .errors import (BackendUnavailableError, ClusterError, CorruptFileError, ImmutableError, InputError,
                         InputTypeError, MissingFileError, ModelError, ProfrobotError, RobotMismatchError, WorkerError)
    from .field import PoseSDF, export_sdf, train_sdf
    from .inverse import (InverseResult, TextResult, actions_from_video, pose_from_images, pose_from_text,
                          trajectory_from_images)
    from .kinematics import Kinematics
    from .optim import ResolveResult, TrajectoryResult, collision_penalty, plan_trajectories, plan_trajectory, resolve
    from .perception import CloudBuild, LayoutEstimate, cloud_from_depth, estimate_layout

# name → the module that defines it; loaded on first access
_LAZY = {
    "PoseSDF": ".field", "train_sdf": ".field",
    "export_sdf": ".field",
    "Kinematics": ".kinematics",
    "collision_penalty": ".optim", "resolve": ".optim", "ResolveResult": ".optim",
    "plan_trajectory": ".optim", "plan_trajectories": ".optim", "TrajectoryResult": ".optim",
    "ProfrobotError": ".errors", "ModelError": ".errors", "RobotMismatchError": ".errors",
    "CorruptFileError": ".errors", "InputError": ".errors", "InputTypeError": ".errors",
    "BackendUnavailableError": ".errors", "ClusterError": ".errors", "MissingFileError": ".errors",
    "WorkerError": ".errors", "ImmutableError": ".errors",
    "pose_from_images": ".inverse", "InverseResult": ".inverse", "trajectory_from_images": ".inverse",
    "pose_from_text": ".inverse", "TextResult": ".inverse", "actions_from_video": ".inverse",
    "estimate_layout": ".perception", "LayoutEstimate": ".perception",
    "cloud_from_depth": ".perception", "CloudBuild": ".perception",
}
#: the layers (the package's folders), each loaded on first attribute access
_SUBPACKAGES = ("robot", "exact", "executors", "gl", "kinematics", "field", "render", "optim", "inverse",
                "perception", "viz", "cli", "errors", "files")

__all__ = [
    "__version__", "scenes", "robot", "exact", "executors", "kinematics", "field", "render", "optim", "inverse",
    "perception", "viz", "errors",
    "Robot", "Obstacle", "Box", "Sphere", "Capsule", "Cylinder", "Plane", "Mesh", "Moves",
    "PointCloud", "cloud_from_depth", "CloudBuild",
    "label_poses", "collides", "sample_poses", "interpolate", "Labels", "make_dataset", "Dataset",
    "crosscheck", "mujoco_labels", "CrosscheckReport", "RendererUnavailableError",
    "Kinematics", "PoseSDF", "train_sdf", "export_sdf",
    "collision_penalty", "resolve", "ResolveResult", "plan_trajectory", "plan_trajectories", "TrajectoryResult",
    "plan_path", "PathResult", "nearest_free", "NearestFree", "ik", "IKResult", "plan_to_pose", "PoseMotion",
    "time_path", "TimedPath", "plan_cartesian", "CartesianPath",
    "pose_from_images", "InverseResult", "trajectory_from_images", "pose_from_text", "TextResult",
    "actions_from_video", "estimate_layout", "LayoutEstimate",
    "certify_poses", "certify_motions", "MotionCertificate", "first_contact", "FirstContact", "check_path", "PathCheck",
    "CLEARANCE",
    "ProfrobotError", "InputError", "InputTypeError", "ModelError", "RobotMismatchError", "CorruptFileError",
    "MissingFileError", "BackendUnavailableError", "ClusterError", "WorkerError", "ImmutableError",
]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    elif name in _SUBPACKAGES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
