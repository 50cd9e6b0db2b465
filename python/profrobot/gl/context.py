"""The one place a MuJoCo GL context is made in this process: :func:`renderer`.

Why one place: MuJoCo picks its GL backend when its GL stack first loads, from ``MUJOCO_GL`` as it
is *then*. Unset and without a display that is GLFW, which cannot make a context: MuJoCo raises
``FatalError``, and the next GL call aborts the interpreter (issue 32: a test's own
``mujoco.Renderer`` killed the README's test command on a headless machine with EGL). So before a
context is made here:

1. the backend is the probed one (:func:`.backends.select_backend`: each candidate tried in a
   throwaway subprocess, ``MUJOCO_GL`` then set for this process), so no backend that fails is
   ever tried in this process;
2. MuJoCo's GL stack, if something already loaded it for another backend (``import mujoco``
   before ``import profrobot``, with another ``MUJOCO_GL``), is reloaded for the chosen one while
   no context exists yet, or refused with :class:`RendererUnavailableError` when a context of the
   other kind does;
3. a ``mujoco.FatalError`` from making the context is raised as :class:`RendererUnavailableError`,
   and this process never touches that backend again.

``tests/test_gl_choice.py`` fails if any module of the library, the tests or the benches makes a
``mujoco.Renderer`` or a GL context anywhere but here.
"""

from __future__ import annotations

import importlib
import os
import sys
import threading
from typing import TYPE_CHECKING, Any

from ..errors import RendererUnavailableError
from .backends import select_backend
from .hints import INSTALL_HINT
from .imports import import_mujoco

if TYPE_CHECKING:   # MuJoCo's own types (no profrobot module); at run time mujoco loads through import_mujoco
    import mujoco

__all__ = ["renderer", "loaded_backend"]

_LOCK = threading.Lock()
_BROKEN: dict[str, str] = {}      # backend → why making a context failed in this process
_MADE: set[str] = set()           # backends this process has made a context with

# the backends' module names (``mujoco.egl``, ...), where each GLContext class lives
_MODULES = ("egl", "osmesa", "glfw", "cgl", "wgl")


def _gl_context_module():
    try:
        from mujoco.rendering.classic import gl_context as glc
    except ImportError:       # an older mujoco layout
        try:
            from mujoco import gl_context as glc
        except ImportError:
            return None
    return glc


def loaded_backend() -> str | None:
    """The backend whose ``GLContext`` MuJoCo's GL stack has loaded in this process (``'egl'``,
    ``'osmesa'``, ``'glfw'``, ...), or None while it has loaded none (profrobot defers it)."""
    glc = _gl_context_module()
    ctx = vars(glc).get("GLContext") if glc is not None else None
    if ctx is None:
        return None
    mod = getattr(ctx, "__module__", "") or ""
    return next((part for part in reversed(mod.split(".")) if part in _MODULES), mod or None)


def _load_for(gl: str) -> None:
    """Make MuJoCo's GL stack the one for ``gl`` (``MUJOCO_GL`` is ``gl`` already)."""
    mujoco = import_mujoco()
    have = loaded_backend()
    if have is None:
        getattr(mujoco, "GLContext", None)   # the deferred load (gl.imports), for MUJOCO_GL=gl
        have = loaded_backend()
    if have == gl or have is None:
        return
    if have in _MADE:
        raise RendererUnavailableError(
            f"MuJoCo's OpenGL in this process is {have!r} (a context was made with it), but {gl!r} is the backend "
            f"that renders here; set MUJOCO_GL={gl} before the first mujoco.Renderer")
    # loaded by an ``import mujoco`` that came first, no context made through us: load the chosen one
    glc = _gl_context_module()
    try:
        importlib.reload(glc)
    except Exception as e:  # noqa: BLE001 - a backend library that fails to load is this error
        raise RendererUnavailableError(f"MuJoCo's OpenGL backend {gl!r} failed to load: {type(e).__name__}: {e}; "
                                       f"{INSTALL_HINT}") from e
    ctx = vars(glc).get("GLContext")
    mods: tuple[Any, ...] = (mujoco, sys.modules.get("mujoco.gl_context"))   # modules: attributes set at run time
    for mod in mods:
        if mod is not None and ctx is not None:
            mod.GLContext = ctx


def renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer(model, height, width)`` (pixels) on the backend that renders here.

    Raises :class:`RendererUnavailableError` (never aborts) where no backend renders, naming what
    was tried and what to install; use it as MuJoCo's (``with gl.renderer(m, h, w) as r:``)."""
    with _LOCK:
        gl = select_backend()
        if gl in _BROKEN:
            raise RendererUnavailableError(_BROKEN[gl])
        if os.environ.get("MUJOCO_GL") != gl:   # someone changed it since: ours is the one probed
            os.environ["MUJOCO_GL"] = gl
        # MuJoCo's EGL and OSMesa modules set PYOPENGL_PLATFORM in os.environ as they load; left
        # there, every child process (a probe, a render worker, the user's subprocess) inherits
        # it, and one that needs the other backend fails to load it ("Cannot use OSMesa
        # rendering platform"). PyOpenGL has read it by then: it is taken back out.
        had_platform = "PYOPENGL_PLATFORM" in os.environ
        try:
            _load_for(gl)
            mujoco = import_mujoco()
            try:
                r = mujoco.Renderer(model, int(height), int(width))
            except mujoco.FatalError as e:
                _BROKEN[gl] = (f"MuJoCo could not make a {gl!r} OpenGL context in this process ({e}), though a probe "
                               f"rendered with it; {INSTALL_HINT}")
                raise RendererUnavailableError(_BROKEN[gl]) from e
        finally:
            if not had_platform:
                os.environ.pop("PYOPENGL_PLATFORM", None)
        _MADE.add(gl)
        return r
