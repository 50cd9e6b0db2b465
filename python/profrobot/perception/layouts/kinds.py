"""What a depth pixel was taken for (:attr:`profrobot.perception.layouts.LayoutEstimate.kind`)."""

from __future__ import annotations

__all__ = ["ROBOT", "STATIC", "OBSTACLE", "UNEXPLAINED"]

#: the robot's own pixel (removed); the modelled static scene's; a candidate obstacle point; behind
#: the model's surfaces (left out)
ROBOT, STATIC, OBSTACLE, UNEXPLAINED = 0, 1, 2, 3
