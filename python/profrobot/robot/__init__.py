"""The robot and what it is built from (torch-free; the layer every other one stands on).

- :mod:`.robot`: :class:`Robot`, a compiled MuJoCo scene: its joints, obstacles and point cloud,
  assembled from the modules below (no mixins: each module knows nothing of ``Robot``);
- :mod:`.loading`: the constructors (Menagerie, MJCF, URDF, SRDF, collision matrix);
- :mod:`.sources`, :mod:`.urdf`: where a robot came from, and URDF → MJCF;
- :mod:`.arrays`: a compiled ``MjModel`` → the Rust core's flat arrays, and the label fingerprint;
- :mod:`.obstacles`, :mod:`.pointcloud`: obstacles added in Python (shapes, a point cloud);
- :mod:`.margin`: the safety margin (metres) every obstacle keeps;
- :mod:`.family`: families of scenes: scene joints, layouts δ (``robot.at(layout)``);
- :mod:`.equalities`, :mod:`.angles`: joint couplings, the one angle wrap;
- :mod:`.state`: pickling and copies; :mod:`.file`: robot files (``robot.save`` / ``Robot.load``);
- :mod:`.gate`: the one gate every public entry point passes its robot and poses through.
"""

from __future__ import annotations

from .family import Moves
from .loading import ExcludedPairs
from .obstacles import Box, Capsule, Cylinder, Mesh, Obstacle, Plane, Sphere
from .pointcloud import PointCloud
from .robot import Robot

__all__ = ["Robot", "ExcludedPairs", "Moves", "PointCloud", "Obstacle", "Box", "Sphere", "Capsule", "Cylinder",
           "Plane", "Mesh"]
