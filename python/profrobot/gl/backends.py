"""Choosing MuJoCo's OpenGL backend: each candidate probed in a throwaway subprocess (a backend
that aborts takes only the probe down), the first that renders remembered per environment; and
the mark a chunk function carries when it draws (:func:`uses_gl`)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import threading
from collections.abc import Callable
from typing import TypeVar

from ..errors import RendererUnavailableError
from .hints import GL_OFF, INSTALL_HINT, plain_reason

__all__ = ["PROBE_SCRIPT", "PROBED_ENV", "child_env", "candidates", "probe", "status", "backend", "forget", "select_backend", "explain_exit",
           "uses_gl", "needs_gl"]

# what a probe runs in a fresh interpreter: one 8x8 frame
PROBE_SCRIPT = """
import mujoco
m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><light pos="0 0 1"/><geom size=".1"/></worldbody></mujoco>')
d = mujoco.MjData(m)
mujoco.mj_forward(m, d)
r = mujoco.Renderer(m, 8, 8)
r.update_scene(d)
img = r.render()
r.close()
assert img.shape == (8, 8, 3), img.shape
print("profrobot-gl-ok", flush=True)
"""

# set by profrobot in a worker's environment: the ``MUJOCO_GL`` it was started with was probed by
# its parent, so the worker need not probe again (a probe is a fresh interpreter: about a second)
PROBED_ENV = "PROFROBOT_GL_PROBED"

_CHOICE: dict[tuple, tuple[str | None, str]] = {}
_CHOICE_LOCK = threading.Lock()
_SELECTED: str | None = None


def candidates() -> tuple[list[str], str]:
    """The ``MUJOCO_GL`` values to try, in order, and why those (for messages)."""
    user = os.environ.get("MUJOCO_GL", "").strip().lower()
    if user:
        return [user], f"MUJOCO_GL={user!r} (set in the environment)"
    if platform.system() != "Linux":
        return [""], "MuJoCo's default backend"
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return ["glfw", "egl", "osmesa"], "MUJOCO_GL unset, a display: glfw, egl, osmesa"
    return ["egl", "osmesa"], "MUJOCO_GL unset, no display: egl, then osmesa"


def explain_exit(done: subprocess.CompletedProcess | None, timeout: float) -> str:
    """Why a child process failed, in one line: its signal or exit status and the first sentence
    of its last stderr line (``done=None``: it timed out)."""
    if done is None:
        return f"timed out after {timeout:.0f} s"
    lines = [ln.strip() for ln in (done.stderr or "").splitlines() if ln.strip()]
    tail = lines[-1] if lines else ""
    if ". " in tail:  # the first sentence says it
        tail = tail[:tail.index(". ") + 1]
    if done.returncode < 0:
        import signal

        try:
            sig = signal.Signals(-done.returncode).name
        except ValueError:
            sig = f"signal {-done.returncode}"
        return f"the process died ({sig})" + (f": {tail}" if tail else "")
    return tail[:300] or f"exit status {done.returncode}"


def child_env(gl: str | None) -> dict:
    """The environment of a child process that renders with ``MUJOCO_GL=gl``: this one's, with
    ``PYOPENGL_PLATFORM`` matching ``gl`` (MuJoCo's EGL/OSMesa modules refuse another value, and
    a parent that rendered with the other backend has its own in ``os.environ``)."""
    env = dict(os.environ)
    if gl:
        env["MUJOCO_GL"] = gl
    if gl in ("egl", "osmesa"):
        env["PYOPENGL_PLATFORM"] = gl
    elif gl:
        env.pop("PYOPENGL_PLATFORM", None)
    return env


def probe(gl: str, timeout: float = 120.0, script: str = PROBE_SCRIPT) -> str:
    """'' when ``MUJOCO_GL=gl`` renders a frame in a fresh interpreter, else why not."""
    if gl in GL_OFF:
        return "MuJoCo rendering is turned off"
    env = child_env(gl)
    try:
        done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                              timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        done = None
    if done is not None and done.returncode == 0 and "profrobot-gl-ok" in done.stdout:
        return ""
    return plain_reason(gl, explain_exit(done, timeout))


def status() -> tuple[str | None, str]:
    """``(MUJOCO_GL value that renders, '')`` or ``(None, the reason and what to install)``;
    probed once per environment (``MUJOCO_GL``, ``DISPLAY``) and remembered."""
    cands, where = candidates()
    key = _key()
    with _CHOICE_LOCK:
        probed = os.environ.get(PROBED_ENV, "").strip().lower()
        if key not in _CHOICE and probed and cands == [probed]:
            _CHOICE[key] = (probed, "")
        if key not in _CHOICE:
            tried = []
            for gl in cands:
                why = probe(gl)
                if not why:
                    _CHOICE[key] = (gl, "")
                    break
                tried.append(f"{gl or 'default'}: {why}")
            else:
                _CHOICE[key] = (None, f"MuJoCo cannot render here ({where}; tried {'; '.join(tried)}). "
                                      f"To render, {INSTALL_HINT}.")
        return _CHOICE[key]


def _key() -> tuple:
    return (os.environ.get("MUJOCO_GL"), os.environ.get("DISPLAY"), os.environ.get("WAYLAND_DISPLAY"))


def forget() -> None:
    """Forget the remembered choices: the next :func:`status` probes again."""
    with _CHOICE_LOCK:
        _CHOICE.clear()


def backend() -> str:
    """The ``MUJOCO_GL`` value drawing processes use; :class:`RendererUnavailableError` if none."""
    gl, why = status()
    if gl is None:
        raise RendererUnavailableError(why)
    return gl


def select_backend() -> str:
    """For a process about to draw (a Ray actor; local render workers are started with it):
    ``MUJOCO_GL`` set to :func:`backend`'s choice, probed here, before MuJoCo's GL stack loads
    (profrobot defers it to the first renderer). Once per process; returns the value."""
    global _SELECTED
    if _SELECTED is None:
        gl = backend()
        os.environ["MUJOCO_GL"] = gl
        with _CHOICE_LOCK:        # the environment now names it: no second probe for the new key
            _CHOICE.setdefault(_key(), (gl, ""))
        _SELECTED = gl
    return _SELECTED


F = TypeVar("F", bound=Callable)
_MARK = "__profrobot_uses_gl__"


def uses_gl(fn: F) -> F:
    """Mark a chunk function that draws with MuJoCo's OpenGL: executors run it only in processes
    whose ``MUJOCO_GL`` was chosen by :func:`backend` (never in the caller's process)."""
    setattr(fn, _MARK, True)
    return fn


def needs_gl(fn: Callable) -> bool:
    """Whether ``fn`` was marked with :func:`uses_gl`."""
    return bool(getattr(fn, _MARK, False))
