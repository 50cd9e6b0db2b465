"""MuJoCo's OpenGL, chosen by us and kept out of the caller's process.

Three ways MuJoCo's rendering used to crash a process that only wanted labels or a field, and
what this module does about each:

1. **No display, ``MUJOCO_GL`` unset.** MuJoCo's default backend (GLFW) cannot make a context;
   depending on the machine that is an exception or an abort of the whole interpreter.
   :func:`backend` probes the candidates (with a display: GLFW, EGL, OSMesa; without: EGL, then
   OSMesa; a ``MUJOCO_GL`` the user set: only that one) in a throwaway subprocess, so a backend
   that aborts takes only the probe down, and returns the first that renders; when none does it
   raises :class:`RendererUnavailableError`, which says what to install.
2. **A ``MUJOCO_GL`` whose library is missing** (``osmesa`` without libOSMesa) makes
   ``import mujoco`` itself raise (PyOpenGL). :func:`import_mujoco` imports mujoco with its GL
   disabled (model compilation, kinematics and collision need none) and defers MuJoCo's GL stack
   to the first use of ``mujoco.Renderer`` / ``mujoco.GLContext``, which then loads it for the
   user's ``MUJOCO_GL`` as an ordinary ``import mujoco`` would have.
3. **Two LLVMs in one process.** Mesa's llvmpipe (OSMesa, or EGL without a GPU) maps
   ``libLLVM-*.so``; triton's ``libtriton.so`` (imported by ``torch._dynamo``, hence by the first
   ``torch.optim`` optimiser) carries its own static LLVM, whose static constructors then bind to
   Mesa's exported LLVM symbols and crash (SIGSEGV in ``llvm::cl::Option::addArgument``).
   :func:`install_triton_guard` loads triton's extension modules with ``RTLD_DEEPBIND`` when a
   libLLVM is already mapped, so they bind to their own copy, whatever the import order.

Rendering itself (:func:`profrobot.render.make_views`, GIFs) runs in :class:`RenderWorkers`:
subprocesses started with the chosen ``MUJOCO_GL`` in their environment, so the caller's process
never creates a GL context (measured: a worker costs about a second to start, against about
0.7 s per pose for 8 views and 70-90 ms per 320x240 GIF frame on a CPU). Idle workers are kept
for the next call and closed at exit (or with :func:`close_workers`).
"""

from __future__ import annotations

import atexit
import contextlib
import importlib
import importlib.abc
import importlib.machinery
import os
import pickle
import platform
import struct
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from .errors import RendererUnavailableError

__all__ = ["RendererUnavailableError", "backend", "status", "import_mujoco", "install_triton_guard",
           "RenderWorkers", "close_workers"]

INSTALL_HINT = ("install OSMesa for CPU rendering (Debian/Ubuntu: `apt-get install libosmesa6`) or an EGL "
                "driver (Mesa: `apt-get install libegl1 libgl1-mesa-dri`, or the NVIDIA driver), or set "
                "MUJOCO_GL to a backend that works here (egl, osmesa, glfw with a display)")
_GL_OFF = ("disable", "disabled", "off", "false", "0")


def import_mujoco():
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
    if (user or "").strip().lower() not in _GL_OFF:
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
                    why = _plain(gl.strip().lower(), f"{type(e).__name__}: {e}")
                    raise RendererUnavailableError(
                        f"MuJoCo's OpenGL backend (MUJOCO_GL={gl!r}) failed to load: {why}; {INSTALL_HINT}") from e
            ctx = vars(glc).get("GLContext")
            for mod in (mujoco, sys.modules.get("mujoco.gl_context")):
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


# --------------------------------------------------------------------------------------------
# 3. triton's LLVM beside Mesa's
# --------------------------------------------------------------------------------------------

def llvm_mapped() -> bool:
    """Whether a shared libLLVM (Mesa's llvmpipe brings one) is mapped into this process."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return b"libLLVM" in f.read()
    except OSError:
        return False


class _DeepbindLoader(importlib.abc.Loader):
    def __init__(self, inner):
        self.inner = inner

    def create_module(self, spec):
        flags = sys.getdlopenflags()
        sys.setdlopenflags(flags | os.RTLD_DEEPBIND)
        try:
            return self.inner.create_module(spec)
        finally:
            sys.setdlopenflags(flags)

    def exec_module(self, module):
        return self.inner.exec_module(module)


class _TritonDeepbind(importlib.abc.MetaPathFinder):
    """Loads ``triton._C.*`` extension modules with ``RTLD_DEEPBIND`` while a libLLVM is mapped."""

    def find_spec(self, fullname, path, target=None):
        if not fullname.startswith("triton._C."):
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path, target)
        if spec is None or not isinstance(spec.loader, importlib.machinery.ExtensionFileLoader) or not llvm_mapped():
            return None
        spec.loader = _DeepbindLoader(spec.loader)
        return spec


def install_triton_guard() -> None:
    """Put :class:`_TritonDeepbind` first on ``sys.meta_path`` (once; Linux only). Without a
    libLLVM in the process, or once triton is imported, it changes nothing."""
    if not hasattr(os, "RTLD_DEEPBIND") or not sys.platform.startswith("linux"):
        return
    if not any(isinstance(f, _TritonDeepbind) for f in sys.meta_path):
        sys.meta_path.insert(0, _TritonDeepbind())


# --------------------------------------------------------------------------------------------
# 1. choosing a backend
# --------------------------------------------------------------------------------------------

_PROBE = """
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
_CHOICE: dict[tuple, tuple[str | None, str]] = {}
_CHOICE_LOCK = threading.Lock()


def _candidates() -> tuple[list[str], str]:
    user = os.environ.get("MUJOCO_GL", "").strip().lower()
    if user:
        return [user], f"MUJOCO_GL={user!r} (set in the environment)"
    if platform.system() != "Linux":
        return [""], "MuJoCo's default backend"
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return ["glfw", "egl", "osmesa"], "MUJOCO_GL unset, a display: glfw, egl, osmesa"
    return ["egl", "osmesa"], "MUJOCO_GL unset, no display: egl, then osmesa"


def _why(done: subprocess.CompletedProcess | None, timeout: float) -> str:
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


def _probe(gl: str, timeout: float = 120.0) -> str:
    """'' when ``MUJOCO_GL=gl`` renders a frame in a fresh interpreter, else why not."""
    if gl in _GL_OFF:
        return "MuJoCo rendering is turned off"
    env = dict(os.environ, MUJOCO_GL=gl) if gl else dict(os.environ)
    try:
        done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True,
                              timeout=timeout, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        done = None
    if done is not None and done.returncode == 0 and "profrobot-gl-ok" in done.stdout:
        return ""
    return _plain(gl, _why(done, timeout))


def _plain(gl: str, why: str) -> str:
    """PyOpenGL's way of saying libOSMesa is missing, in words."""
    if gl == "osmesa" and "glGetError" in why:
        return f"libOSMesa not found ({why})"
    return why


def status() -> tuple[str | None, str]:
    """``(MUJOCO_GL value that renders, '')`` or ``(None, the reason and what to install)``;
    probed once per environment (``MUJOCO_GL``, ``DISPLAY``) and remembered."""
    cands, where = _candidates()
    key = (os.environ.get("MUJOCO_GL"), os.environ.get("DISPLAY"), os.environ.get("WAYLAND_DISPLAY"))
    with _CHOICE_LOCK:
        if key not in _CHOICE:
            tried = []
            for gl in cands:
                why = _probe(gl)
                if not why:
                    _CHOICE[key] = (gl, "")
                    break
                tried.append(f"{gl or 'default'}: {why}")
            else:
                _CHOICE[key] = (None, f"MuJoCo cannot render here ({where}; tried {'; '.join(tried)}). "
                                      f"To render, {INSTALL_HINT}.")
        return _CHOICE[key]


def backend() -> str:
    """The ``MUJOCO_GL`` value render workers use; :class:`RendererUnavailableError` if none."""
    gl, why = status()
    if gl is None:
        raise RendererUnavailableError(why)
    return gl


# --------------------------------------------------------------------------------------------
# Render workers: MuJoCo's GL in subprocesses
# --------------------------------------------------------------------------------------------

_HEADER = struct.Struct("<Q")


def _send(f, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    f.write(_HEADER.pack(len(data)))
    f.write(data)
    f.flush()


def _recv(f):
    head = f.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    (n,) = _HEADER.unpack(head)
    data = f.read(n)
    if len(data) < n:
        return None
    return pickle.loads(data)


def _serve() -> None:
    """A worker's main loop: requests ``(module, function, args)`` on stdin, ``(ok, value)``
    replies on the original stdout; anything else printed goes to stderr."""
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    inp = sys.stdin.buffer
    while True:
        req = _recv(inp)
        if req is None:
            return
        mod, fn, args = req
        try:
            reply = (True, getattr(importlib.import_module(mod), fn)(*args))
        except Exception as e:  # sent back and re-raised by the caller
            reply = (False, e)
        try:
            _send(out, reply)
        except Exception as e:  # an unpicklable value or exception
            _send(out, (False, RuntimeError(f"{type(e).__name__}: {e} (in {mod}.{fn})")))


class _Worker:
    def __init__(self, gl: str):
        self.gl = gl
        env = dict(os.environ)
        if gl:
            env["MUJOCO_GL"] = gl
        root = str(Path(__file__).resolve().parents[1])  # where this profrobot is, last on the path
        main = f"import sys; sys.path.append({root!r}); from profrobot._gl import _serve; _serve()"
        self.pending = 0  # requests sent, replies not yet read
        self.err = tempfile.TemporaryFile()
        self.p = subprocess.Popen([sys.executable, "-c", main], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=self.err, env=env)

    def alive(self) -> bool:
        return self.p.poll() is None

    def send(self, mod: str, fn: str, *args) -> None:
        self.pending += 1
        try:
            _send(self.p.stdin, (mod, fn, args))
        except (BrokenPipeError, OSError):
            pass  # it died: recv says why

    def recv(self):
        reply = _recv(self.p.stdout)
        if reply is None:
            raise RendererUnavailableError(f"a MuJoCo render worker (MUJOCO_GL={self.gl!r}) died: {self._died()}")
        self.pending -= 1
        ok, value = reply
        if not ok:
            raise value
        return value

    def _died(self) -> str:
        try:
            rc = self.p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.kill()
            rc = self.p.returncode
        self.err.seek(0)
        text = self.err.read()[-4000:].decode(errors="replace")
        return _why(subprocess.CompletedProcess([], rc, "", text), 0)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.p.stdin.close()
        try:
            self.p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.kill()
        self._cleanup()

    def kill(self) -> None:
        self.p.kill()
        self.p.wait()
        self._cleanup()

    def _cleanup(self) -> None:
        for f in (self.p.stdout, self.err):
            with contextlib.suppress(OSError, ValueError):
                f.close()


_IDLE: list[_Worker] = []
_IDLE_LOCK = threading.Lock()


class RenderWorkers:
    """``n`` render worker processes (the chosen backend in their environment), borrowed from
    the idle set or started; returned to it on a clean exit, killed after an error.

    ``call(mod, fn, *args)`` runs ``mod.fn(*args)`` in every worker; ``map(mod, fn, items)``
    yields ``mod.fn(item)`` in order, the items dealt round-robin, one in flight per worker.
    """

    def __init__(self, n: int = 1):
        self.n = max(1, int(n))
        self.gl = backend()
        self.workers: list[_Worker] = []

    def __enter__(self) -> "RenderWorkers":
        with _IDLE_LOCK:
            while _IDLE and len(self.workers) < self.n:
                w = _IDLE.pop()
                if w.gl == self.gl and w.alive():
                    self.workers.append(w)
                else:
                    w.close()
        while len(self.workers) < self.n:
            self.workers.append(_Worker(self.gl))
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        for w in self.workers:  # a worker is reused only with nothing left in its pipes
            if exc_type is None and w.pending == 0 and w.alive():
                with _IDLE_LOCK:
                    _IDLE.append(w)
            else:
                w.kill()
        self.workers = []

    def call(self, mod: str, fn: str, *args) -> list:
        for w in self.workers:
            w.send(mod, fn, *args)
        out, error = [], None
        for w in self.workers:
            try:
                out.append(w.recv())
            except Exception as e:  # read every reply before raising the first error
                error = error or e
        if error is not None:
            raise error
        return out

    def map(self, mod: str, fn: str, items):
        items = list(items)
        ws = self.workers
        for k in range(min(len(ws), len(items))):
            ws[k].send(mod, fn, items[k])
        for k in range(len(items)):
            w = ws[k % len(ws)]
            out = w.recv()
            if k + len(ws) < len(items):
                w.send(mod, fn, items[k + len(ws)])
            yield out


def close_workers() -> None:
    """Close the idle render workers (also done at exit)."""
    with _IDLE_LOCK:
        idle, _IDLE[:] = list(_IDLE), []
    for w in idle:
        w.close()


atexit.register(close_workers)
