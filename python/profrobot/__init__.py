from ._core import __version__
from .robot import Robot, Box, Sphere, Capsule, Cylinder, Plane, Mesh
