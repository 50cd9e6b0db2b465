"""``import mujoco`` without its OpenGL stack; the stack loads on first use of a renderer."""

from __future__ import annotations

import importlib
import os
import sys
import threading
import types
from typing import Any

from ..errors import RendererUnavailableError
from .hints import GL_OFF, INSTALL_HINT, plain_reason

__all__ = ["import_mujoco"]


def import_mujoco() -> types.ModuleType:
    """``import mujoco`` with MuJoCo's GL disabled, unless it is imported already; the GL stack
    loads (for the user's ``MUJOCO_GL``) on first use of ``mujoco.Renderer``/``GLContext``."""
    if "mujoco" in sys.modules:
        return sys.modules["mujoco"]
    user = os.environ.get("MUJOCO_GL")
    os.environ["MUJOCO_GL"] = "disable"
    try:
        import mujoco
    finally:
        if user is None:
            os.environ.pop("MUJOCO_GL", None)
        else:
            os.environ["MUJOCO_GL"] = user
    if (user or "").strip().lower() not in GL_OFF:
        _defer_gl(mujoco)
    return mujoco


def _defer_gl(mujoco) -> None:
    try:
        from mujoco.rendering.classic import gl_context as glc
    except ImportError:  # another mujoco layout: nothing to defer
        return
    if hasattr(glc, "GLContext"):
        return
    lock = threading.Lock()

    def load():
        with lock:
            if "GLContext" not in vars(glc):
                try:
                    importlib.reload(glc)  # reads MUJOCO_GL now, as ``import mujoco`` would have
                except Exception as e:
                    gl = os.environ.get("MUJOCO_GL", "")
                    why = plain_reason(gl.strip().lower(), f"{type(e).__name__}: {e}")
                    raise RendererUnavailableError(
                        f"MuJoCo's OpenGL backend (MUJOCO_GL={gl!r}) failed to load: {why}; {INSTALL_HINT}") from e
            ctx = vars(glc).get("GLContext")
            mods: tuple[Any, ...] = (mujoco, sys.modules.get("mujoco.gl_context"))   # modules: attributes set at run time
            for mod in mods:
                if mod is not None and ctx is not None:
                    mod.GLContext = ctx
            return ctx

    def glc_getattr(name: str):
        if name == "GLContext":
            ctx = load()
            if ctx is not None:
                return ctx
        raise AttributeError(f"module {glc.__name__!r} has no attribute {name!r}")

    glc.__getattr__ = glc_getattr
    if "__getattr__" not in vars(mujoco):
        def mujoco_getattr(name: str):
            if name == "GLContext":
                return glc_getattr(name)
            raise AttributeError(f"module 'mujoco' has no attribute {name!r}")

        mujoco.__getattr__ = mujoco_getattr
