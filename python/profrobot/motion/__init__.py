"""What a robot executes (torch-free, above :mod:`profrobot.exact`): timed paths within joint
velocity and acceleration limits, their geometry certified (:mod:`.timing`)."""

from .timing import TimedPath, time_path

__all__ = ["TimedPath", "time_path"]
