"""The local executor: chunk functions in this process, or in worker processes.

A chunk function marked with :func:`profrobot.gl.uses_gl` (it draws with MuJoCo) always runs in
worker processes started with the ``MUJOCO_GL`` that :func:`profrobot.gl.backend` chose (probed
in a subprocess first), so this process never creates a GL context and a backend that aborts
takes only a worker down: the call then raises :class:`~profrobot.errors.RendererUnavailableError`
with the worker's reason. Other chunk functions run here, in order, with ``processes=1`` (the
default), and in ``processes`` worker processes otherwise.

Worker processes (measured: about a second to start) are borrowed from an idle set or started,
one chunk in flight each, chunks dealt round-robin; each is sent the robot once (pickled) and
each :meth:`LocalExecutor.put` value once per call. When a call ends cleanly they free the chunk
modules' caches (:func:`~profrobot.executors.base.on_release`) and wait idle for the next call;
after an error they are killed. Idle workers are closed at exit (or with :func:`close_workers`).
"""

from __future__ import annotations

import atexit
import contextlib
import itertools
import os
import pickle
import struct
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Generator, Sequence
from pathlib import Path
from typing import Any


from ..errors import RendererUnavailableError, WorkerError
from ..gl import backends
from .base import ChunkFn, release_caches, robot_payload
from ..robot.robot import Robot
from .progress import progress_bar
from ..robot.gate import count, threads as validate_threads

__all__ = ["LocalExecutor", "close_workers", "serve"]

_HEADER = struct.Struct("<Q")
_ROBOT, _VALUE, _RELEASE, _CALL = b"r", b"v", b"x", b"c"


def _write(f, kind: bytes, data: bytes) -> None:
    f.write(_HEADER.pack(len(data) + 1))
    f.write(kind)
    f.write(data)
    f.flush()


def _read(f) -> tuple[bytes, bytes] | None:
    head = f.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    (n,) = _HEADER.unpack(head)
    data = f.read(n)
    if len(data) < n:
        return None
    return data[:1], data[1:]


class _Stored:
    """A :meth:`LocalExecutor.put` value."""

    __slots__ = ("key", "value")
    _keys = itertools.count()

    def __init__(self, value):
        self.key = next(self._keys)
        self.value = value


class _Token:
    """A stored value's key, as a worker receives it in a chunk's arguments."""

    __slots__ = ("key",)

    def __init__(self, key: int):
        self.key = key

    def __reduce__(self):
        return (_Token, (self.key,))


# --------------------------------------------------------------------------------------------
# The worker process
# --------------------------------------------------------------------------------------------

def serve() -> None:
    """A worker process's main loop: messages on stdin (the robot, stored values, calls, a
    release), one ``(ok, value)`` reply per call on the original stdout; anything the chunk
    functions print goes to stderr."""
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    inp = sys.stdin.buffer
    robot: Any = None
    robot_error: BaseException | None = None
    values: dict[int, Any] = {}
    while True:
        msg = _read(inp)
        if msg is None:
            return
        kind, data = msg
        if kind == _ROBOT:
            robot, robot_error = None, None
            try:
                robot = pickle.loads(data)
            except Exception as e:  # raised at the next call
                robot_error = e
        elif kind == _VALUE:
            key, value = pickle.loads(data)
            values[key] = value
        elif kind == _RELEASE:
            values.clear()
            with contextlib.suppress(Exception):
                release_caches()
        elif kind == _CALL:
            what = "a chunk"
            try:
                fn, args = pickle.loads(data)
                what = f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', fn)}"
                if robot_error is not None:
                    raise robot_error
                args = tuple(values[a.key] if isinstance(a, _Token) else a for a in args)
                reply = (True, fn(robot, *args))
            except Exception as e:  # sent back and re-raised by the caller
                reply = (False, e)
            try:
                _write(out, _CALL, pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL))
            except Exception as e:  # an unpicklable value or exception
                err = RuntimeError(f"{type(e).__name__}: {e} (in {what})")
                _write(out, _CALL, pickle.dumps((False, err), protocol=pickle.HIGHEST_PROTOCOL))


class _Process:
    """One worker process; ``gl``: the ``MUJOCO_GL`` it was started with (None: the environment
    as it is, for chunk functions that do not draw)."""

    def __init__(self, gl: str | None):
        self.gl = gl
        env = backends.child_env(gl) if gl else dict(os.environ)
        if gl:
            env[backends.PROBED_ENV] = gl     # probed here: the worker need not probe again
        root = str(Path(__file__).resolve().parents[2])  # where this profrobot is
        path = [p for p in sys.path if isinstance(p, str)] + [root]  # the caller's, as multiprocessing's spawn
        main = f"import sys; sys.path[:0] = {path!r}; from profrobot.executors.local import serve; serve()"
        self.pending = 0          # calls sent, replies not yet read
        self.robot_key: str | None = None
        self.values: set[int] = set()
        self.err = tempfile.TemporaryFile()
        self.p = subprocess.Popen([sys.executable, "-c", main], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=self.err, env=env)

    def alive(self) -> bool:
        return self.p.poll() is None

    def _send(self, kind: bytes, data: bytes) -> None:
        try:
            _write(self.p.stdin, kind, data)
        except (BrokenPipeError, OSError):
            pass  # it died: recv says why

    def call(self, fn: ChunkFn, robot_key: str, robot_bytes: bytes, args: tuple) -> None:
        if self.robot_key != robot_key:
            self._send(_ROBOT, robot_bytes)
            self.robot_key = robot_key
        sent = []
        for a in args:
            if isinstance(a, _Stored):
                if a.key not in self.values:
                    self._send(_VALUE, pickle.dumps((a.key, a.value), protocol=pickle.HIGHEST_PROTOCOL))
                    self.values.add(a.key)
                a = _Token(a.key)
            sent.append(a)
        self.pending += 1
        self._send(_CALL, pickle.dumps((fn, tuple(sent)), protocol=pickle.HIGHEST_PROTOCOL))

    def recv(self):
        msg = _read(self.p.stdout)
        if msg is None:
            why = self._died()
            if self.gl:
                raise RendererUnavailableError(f"a MuJoCo render worker (MUJOCO_GL={self.gl!r}) died: {why}")
            raise WorkerError(f"a profrobot worker process died: {why}")
        self.pending -= 1
        ok, value = pickle.loads(msg[1])
        if not ok:
            raise value
        return value

    def release(self) -> None:
        """Free the chunk modules' caches and this call's stored values (no reply)."""
        self.values.clear()
        self._send(_RELEASE, b"")

    def _died(self) -> str:
        try:
            rc = self.p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.kill()
            rc = self.p.returncode
        self.err.seek(0)
        text = self.err.read()[-4000:].decode(errors="replace")
        return backends.explain_exit(subprocess.CompletedProcess([], rc, "", text), 0)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            if self.p.stdin is not None:   # a pipe (stdin=PIPE)
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
        for f in (self.p.stdin, self.p.stdout, self.err):
            with contextlib.suppress(OSError, ValueError):
                if f is not None:      # pipes (stdin=PIPE, stdout=PIPE)
                    f.close()


_IDLE: list[_Process] = []
_IDLE_LOCK = threading.Lock()


def _borrow(n: int, gl: str | None) -> list[_Process]:
    out: list[_Process] = []
    with _IDLE_LOCK:
        keep = []
        while _IDLE and len(out) < n:
            w = _IDLE.pop()
            if w.gl == gl and w.alive():
                out.append(w)
            elif w.alive():
                keep.append(w)  # another backend's worker: left for its next call
            else:
                w.close()
        _IDLE.extend(keep)
    while len(out) < n:
        out.append(_Process(gl))
    return out


def _give_back(workers: list[_Process], clean: bool) -> None:
    """Idle again (their caches freed) after a clean call with nothing left in their pipes;
    killed otherwise."""
    for w in workers:
        if clean and w.pending == 0 and w.alive():
            w.release()
            with _IDLE_LOCK:
                _IDLE.append(w)
        else:
            w.kill()


def close_workers() -> None:
    """Close the idle worker processes (also done at exit)."""
    with _IDLE_LOCK:
        idle, _IDLE[:] = list(_IDLE), []
    for w in idle:
        w.close()


atexit.register(close_workers)


# --------------------------------------------------------------------------------------------
# The executor
# --------------------------------------------------------------------------------------------

class LocalExecutor:
    """Runs chunk functions on this machine (see the module's docstring).

    Args:
        processes: worker processes (at most one per chunk). With 1 (the default), chunk
            functions that do not draw run in this process; drawing ones always run in workers.
        threads: labeller threads a chunk should use (``None``: as the caller asked; worth
            setting with ``processes > 1``, whose workers would otherwise each take every core).

    ``executor=None`` in profrobot's functions means ``LocalExecutor()`` (``make_views``: its
    ``processes``).
    """

    def __init__(self, processes: int = 1, *, threads: int | None = None):
        self.processes = count("processes", processes)
        self.threads = validate_threads(threads)

    def __repr__(self) -> str:
        return f"LocalExecutor(processes={self.processes}, threads={self.threads})"

    def put(self, value: Any) -> Any:
        """A handle to ``value``: sent once to each worker of a call; chunk functions receive
        ``value`` itself."""
        return _Stored(value)

    def in_process(self, fn: ChunkFn) -> bool:
        """Whether ``fn`` runs in this process (it does not draw, and ``processes == 1``)."""
        return self.processes == 1 and not backends.needs_gl(fn)

    def map(self, fn: ChunkFn, chunks: Sequence[tuple], *, robot: Robot, sizes: Sequence[int] | None = None,
            desc: str = "chunks", unit: str = "chunk", progress: bool = True) -> list:
        """``[fn(robot, *args) for args in chunks]`` (a non-tuple item is one argument), in order."""
        chunks = [tuple(c) if isinstance(c, tuple) else (c,) for c in chunks]
        sizes = list(sizes) if sizes is not None else [1] * len(chunks)
        out: list = [None] * len(chunks)
        stream = self._stream(fn, robot, chunks.__getitem__, len(chunks), lambda: len(chunks), self._backend(fn))
        with progress_bar(sum(sizes), desc=desc, unit=unit, progress=progress) as bar:
            for i, value in stream:
                out[i] = value
                bar.update(sizes[i])
        return out

    def ordered(self, fn: ChunkFn, args_of: Callable[[int], tuple], limit: int, demand: Callable[[], int], *,
                robot: Robot) -> Generator[tuple[int, Any], None, None]:
        """``(i, fn(robot, *args_of(i)))`` for ``i < limit``, in order; in this process each is
        computed when asked for, in workers at most ``min(demand(), processes)`` ahead."""
        return self._stream(fn, robot, args_of, limit, demand, self._backend(fn))

    def _backend(self, fn: ChunkFn) -> str | None:
        """The ``MUJOCO_GL`` of the workers that run ``fn`` (None: it draws nothing); raises
        :class:`RendererUnavailableError` (what to install) before any work when none renders."""
        return backends.backend() if backends.needs_gl(fn) else None

    def _stream(self, fn: ChunkFn, robot, args_of: Callable[[int], tuple], limit: int, demand: Callable[[], int],
                gl: str | None) -> Generator[tuple[int, Any], None, None]:
        if self.in_process(fn):
            for i in range(limit):
                yield i, fn(robot, *(a.value if isinstance(a, _Stored) else a for a in args_of(i)))
            return
        if limit <= 0:
            return
        key, data = robot_payload(robot)
        n = max(1, min(self.processes, limit))
        workers = _borrow(n, gl)
        clean = False
        nxt = sub = 0
        try:
            while nxt < limit:
                want = min(n, max(1, int(demand())))
                while sub < limit and sub - nxt < want:
                    workers[sub % n].call(fn, key, data, tuple(args_of(sub)))
                    sub += 1
                value = workers[nxt % n].recv()
                yield nxt, value
                nxt += 1
            clean = True
        except GeneratorExit:  # the caller needs no more: finish what is in flight, keep the workers
            try:
                for w in workers:
                    while w.pending and w.alive():
                        try:
                            w.recv()
                        except Exception:  # a chunk's error (nobody wants it now) or a death
                            pass
                clean = all(w.pending == 0 for w in workers)
            finally:
                _give_back(workers, clean)
                workers = []
            raise
        finally:
            if workers:
                _give_back(workers, clean)
