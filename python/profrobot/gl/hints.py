"""What to install, in words: the messages :mod:`.imports` and :mod:`.backends` both give."""

from __future__ import annotations

__all__ = ["INSTALL_HINT", "GL_OFF", "plain_reason"]

INSTALL_HINT = ("install OSMesa for CPU rendering (Debian/Ubuntu: `apt-get install libosmesa6`) or an EGL "
                "driver (Mesa: `apt-get install libegl1 libgl1-mesa-dri`, or the NVIDIA driver), or set "
                "MUJOCO_GL to a backend that works here (egl, osmesa, glfw with a display)")
"""What to install (or set) where no MuJoCo GL backend works: the end of every such message."""

# MUJOCO_GL values that turn MuJoCo's rendering off
GL_OFF = ("disable", "disabled", "off", "false", "0")


def plain_reason(gl: str, why: str) -> str:
    """PyOpenGL's way of saying libOSMesa or libEGL is missing, in words."""
    if gl == "osmesa" and "glGetError" in why:
        return f"libOSMesa not found ({why})"
    if gl == "egl" and "'NoneType' object has no attribute 'egl" in why:   # PyOpenGL without libEGL
        return f"libEGL not found ({why})"
    return why
