"""MuJoCo's OpenGL, chosen by us and kept out of the caller's process.

Three ways MuJoCo's rendering used to crash a process that only wanted labels or a field, and
what each module here does about it:

1. **No display, ``MUJOCO_GL`` unset** (:mod:`.backends`). MuJoCo's default backend (GLFW) cannot
   make a context; depending on the machine that is an exception or an abort of the whole
   interpreter. :func:`backend` probes the candidates (with a display: GLFW, EGL, OSMesa; without:
   EGL, then OSMesa; a ``MUJOCO_GL`` the user set: only that one) in a throwaway subprocess, so a
   backend that aborts takes only the probe down, and returns the first that renders; when none
   does it raises :class:`~profrobot.errors.RendererUnavailableError`, which says what to install.
2. **A ``MUJOCO_GL`` whose library is missing** (:mod:`.imports`): ``osmesa`` without libOSMesa
   makes ``import mujoco`` itself raise (PyOpenGL). :func:`import_mujoco` imports mujoco with its
   GL disabled (model compilation, kinematics and collision need none) and defers MuJoCo's GL
   stack to the first use of ``mujoco.Renderer`` / ``mujoco.GLContext``, which then loads it for
   the user's ``MUJOCO_GL`` as an ordinary ``import mujoco`` would have.
3. **Two LLVMs in one process** (:mod:`.triton_guard`). Mesa's llvmpipe (OSMesa, or EGL without
   a GPU) maps ``libLLVM-*.so``; triton's ``libtriton.so`` (imported by ``torch._dynamo``, hence by
   the first ``torch.optim`` optimiser) carries its own static LLVM, whose static constructors then
   bind to Mesa's exported LLVM symbols and crash. :func:`install_triton_guard` loads triton's
   extension modules with ``RTLD_DEEPBIND`` when a libLLVM is already mapped.

4. **A GL context made outside that choice** (:mod:`.context`). A ``mujoco.Renderer`` made while
   ``MUJOCO_GL`` is unset loads GLFW, which without a display raises ``FatalError`` and aborts the
   process on the next call. :func:`renderer` is the one place a context is made: on the probed
   backend, with a ``FatalError`` turned into :class:`~profrobot.errors.RendererUnavailableError`.

profrobot's own drawing never happens in the caller's process: a chunk function marked with
:func:`uses_gl` runs in worker processes started with the chosen ``MUJOCO_GL``
(:class:`profrobot.executors.LocalExecutor`), or on Ray actors that choose their own
(:func:`select_backend`).
"""

from __future__ import annotations

from ..errors import RendererUnavailableError
from .context import loaded_backend, renderer
from .backends import backend, forget, needs_gl, probe, select_backend, status, uses_gl
from .hints import INSTALL_HINT
from .imports import import_mujoco
from .triton_guard import install_triton_guard, llvm_mapped

__all__ = ["RendererUnavailableError", "INSTALL_HINT", "renderer", "loaded_backend", "backend", "status", "probe", "forget", "select_backend",
           "uses_gl", "needs_gl", "import_mujoco", "install_triton_guard", "llvm_mapped"]
