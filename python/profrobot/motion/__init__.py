"""What a robot executes (torch-free, above :mod:`profrobot.exact`): timed paths within joint
velocity and acceleration limits, their blends proven (:mod:`.timing`), and straight-line moves
of a frame, certified (:mod:`.cartesian`)."""

from .cartesian import CartesianPath, plan_cartesian
from .timing import TimedPath, time_path

__all__ = ["CartesianPath", "TimedPath", "plan_cartesian", "time_path"]
