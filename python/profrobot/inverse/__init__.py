"""Image-space inverse problems whose answers do not collide (the paper's point, Tables 7–9):
the Gaussian robot's image loss, the pose collision field's penalty, the exact labeller's
certificate.

- :func:`pose_from_images` (Table 7): joint angles from multi-view images;
- :func:`trajectory_from_images` (Table 8): a trajectory towards the pose seen in images, every
  frame and dense segment certified;
- :func:`actions_from_video` (supplement): a joint trajectory from multi-view video;
- :func:`pose_from_text` (Table 9): a pose whose render matches a prompt under a scorer
  (:mod:`profrobot.inverse.scorers`).
"""

from .images import InverseResult, pose_from_images
from .text import TextResult, pose_from_text
from .trajectory import trajectory_from_images
from .video import actions_from_video

__all__ = ["InverseResult", "pose_from_images", "trajectory_from_images", "TextResult", "pose_from_text",
           "actions_from_video"]
