"""profrobot: collision-aware robot pose optimisation.

The facade. Where a pose becomes a label: :func:`label_poses` → ``Robot.core.label`` (Rust,
``rust/collide.rs``).

>>> import profrobot
>>> robot = profrobot.scenes.load("panda_blocks")
>>> poses = profrobot.sample_poses(robot, 1000, seed=0)          # (1000, 9), radians / metres
>>> labels = profrobot.label_poses(robot, poses)                 # exact, parallel
>>> report = profrobot.crosscheck(robot, poses)                  # MuJoCo on the same poses
>>> sdf = profrobot.train_sdf(robot)                             # the learned collision field
>>> g = sdf(torch.as_tensor(poses, dtype=torch.float32))         # (1000,), g > 0: colliding
"""

# torch.optim imports torch._dynamo (and with it triton's LLVM) on first use; once MuJoCo has
# loaded OSMesa (llvmpipe, another LLVM) that import segfaults. Importing it first is safe.
import torch._dynamo  # noqa: E402,F401  (isort: skip)

from . import render, scenes
from ._core import __version__
from .crosscheck import CrosscheckReport, crosscheck, mujoco_labels
from .dataset import Dataset, make_dataset
from .labels import Labels, interpolate, label_poses, sample_poses
from .robot import Box, Capsule, Cylinder, Mesh, Obstacle, Plane, Robot, Sphere
from .field import PoseSDF, train_sdf
from .field.checkpoint import export_sdf, load_sdf, save_sdf
from .kinematics import Kinematics
from .optim import ResolveResult, TrajectoryResult, collision_penalty, plan_trajectory, resolve

__all__ = [
    "__version__", "scenes", "render", "Robot", "Obstacle", "Box", "Sphere", "Capsule", "Cylinder", "Plane", "Mesh",
    "label_poses", "sample_poses", "interpolate", "Labels", "make_dataset", "Dataset",
    "crosscheck", "mujoco_labels", "CrosscheckReport",
    "Kinematics", "PoseSDF", "train_sdf", "save_sdf", "load_sdf", "export_sdf",
    "collision_penalty", "resolve", "ResolveResult", "plan_trajectory", "TrajectoryResult",
]
