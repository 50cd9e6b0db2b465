"""The exact layer (torch-free): answers from the Rust core's labeller, never from a learned field.

- :mod:`.labels`: sampling, exact labels (:func:`label_poses`), the booleans-only :func:`collides`;
- :mod:`.certification`: poses and motions certified free (conservative advancement);
- :mod:`.planning`: global paths (RRT-Connect on the labeller, certified continuously);
- :mod:`.ik`: certified inverse kinematics and motions to a pose;
- :mod:`.timing`: timed paths within joint limits, their blends certified;
- :mod:`.cartesian`: straight-line moves of a frame, certified;
- :mod:`.oracle`: the nearest free pose (the Δθ yardstick);
- :mod:`.problems`: benchmark problems (colliding, free poses, hard pairs);
- :mod:`.dataset`: labelled datasets on disk;
- :mod:`.crosscheck`: the same poses through MuJoCo's ``mj_collision``.
"""

from __future__ import annotations

from . import cartesian, certification, crosscheck, dataset, ik, labels, oracle, planning, problems, timing

__all__ = ["labels", "certification", "planning", "ik", "timing", "cartesian", "oracle", "problems", "dataset",
           "crosscheck"]
