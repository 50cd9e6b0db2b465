"""Beyond one machine: the same chunk functions, cut into the same chunks, on a Ray cluster.

``executor=RayExecutor(...)`` runs the chunks of :func:`profrobot.make_dataset` (its seeded
sampling rounds), :func:`profrobot.render.make_views` (its pose chunks), :func:`profrobot.crosscheck`
(MuJoCo's labels, per chunk of poses) and the batch benches on Ray actors.

Why the output is identical to the local run, whatever the number of workers: every client cuts
its work with :func:`~profrobot.executors.base.chunk_bounds` (or seeded rounds), a chunk function
is a pure function of the robot and its arguments (never of the worker that runs it or of when it
runs), and the results are placed by chunk index; what is computed from them afterwards
(make_dataset's quota filling, the concatenations) runs in the caller, in chunk order, exactly as
locally.

How it runs: one pool of long-lived actors per robot (``workers`` of them, ``threads`` CPUs
each). The robot is pickled once, put in Ray's object store once, and loaded once per actor; a
chunk function's per-process caches (MuJoCo's renderer, one GL context) live in its module, in
the actor, beside the robot. An actor asked to run a chunk function marked with
:func:`profrobot.gl.uses_gl` first sets ``MUJOCO_GL`` the way profrobot's local render workers
get it (:func:`profrobot.gl.select_backend`, probed on the actor's node). Large inputs go through
the object store (:meth:`RayExecutor.put` once per call, never pickled per task); results stream
back with ``ray.wait`` into a progress bar.

Faults: a chunk whose actor dies (its process killed, its node lost) is submitted again, to
another actor when there is one, while Ray restarts the dead one (``max_restarts``); each chunk's
result is placed exactly once, so nothing is lost or counted twice. A chunk is tried at most
``1 + max_retries`` times. A wrong address or a dead cluster raises :class:`ClusterError` within
``connect_timeout`` seconds (Ray's own ``ray.init`` would retry forever); workers that cannot
start (no free CPUs) raise it within ``start_timeout``.

``ray`` is an optional dependency (``pip install "profrobot[ray]"``); this module imports it
only when an executor first connects.
"""

from __future__ import annotations

import collections
import os
import pickle
import socket
import threading
import time
import types
from collections.abc import Callable, Generator, Iterable, Sequence
from dataclasses import dataclass
from typing import Any


from ..errors import ClusterError, InputError
from .base import ChunkFn, robot_payload
from ..robot.robot import Robot
from .progress import progress_bar
from ..robot.gate import count

__all__ = ["RayExecutor", "ClusterError", "RunStats"]


def _import_ray():
    try:
        import ray
    except ImportError as e:
        raise ClusterError('RayExecutor needs Ray: pip install "profrobot[ray]" (or pip install "ray>=2.9")') from e
    return ray


def _actor_errors(ray) -> tuple[type[BaseException], ...]:
    """The exceptions that mean "the actor (or its node) died", not "the chunk failed"."""
    ex = ray.exceptions
    names = ("RayActorError", "ActorDiedError", "ActorUnavailableError", "WorkerCrashedError", "NodeDiedError",
             "ObjectLostError", "OwnerDiedError", "LocalRayletDiedError")
    return tuple(getattr(ex, n) for n in names if isinstance(getattr(ex, n, None), type))


# --------------------------------------------------------------------------------------------
# The actor: one robot, loaded once
# --------------------------------------------------------------------------------------------

class _RobotWorker:
    """A Ray actor holding one robot (unpickled once). :meth:`run` calls a chunk function on it;
    chunk functions are pure, so a restarted actor (Ray re-runs ``__init__``) computes the same."""

    def __init__(self, robot_ref: list):
        import ray

        from ..gl import import_mujoco

        import_mujoco()  # mujoco with its GL deferred (done already by profrobot's import; never twice)

        # the robot's bytes, from the object store (nested in a list, so that Ray hands over the
        # reference and this actor, on every restart too, reads the one stored copy)
        self.robot = pickle.loads(ray.get(robot_ref[0]))

    def pid(self) -> int:
        return os.getpid()

    def ping(self) -> int:
        return os.getpid()

    def run(self, fn: ChunkFn, *args):
        """``fn(robot, *args)``; a drawing chunk function first gets the backend that renders on
        this node in ``MUJOCO_GL``, before MuJoCo's GL stack loads (its first renderer)."""
        from ..gl import needs_gl, select_backend

        if needs_gl(fn):
            select_backend()
        return fn(self.robot, *args)


# --------------------------------------------------------------------------------------------
# Scheduling: bounded in-flight chunks per actor, retried on actor death, placed by index
# --------------------------------------------------------------------------------------------

@dataclass
class RunStats:
    """What the last run did: ``chunks`` placed (each exactly once), ``submitted`` task
    submissions (chunks + retries + any speculative chunks cancelled), ``retries`` after an
    actor died, ``duplicates`` results of a chunk already placed (dropped), ``cancelled``
    chunks no longer needed (make_dataset's rounds beyond the quota)."""

    chunks: int = 0
    submitted: int = 0
    retries: int = 0
    duplicates: int = 0
    cancelled: int = 0
    placed: collections.Counter | None = None   # chunk index -> times placed (always 1)


class _Pool:
    """``n`` actors for one robot."""

    def __init__(self, ray, key: str, robot_bytes: bytes, n: int, threads: int, max_restarts: int,
                 start_timeout: float, runtime_env: dict | None):
        self.ray, self.key = ray, key
        self.robot_ref = ray.put(robot_bytes)  # once; every actor (and every restart) reads it
        cls = ray.remote(_RobotWorker)
        opts: dict[str, Any] = dict(num_cpus=threads, max_restarts=max_restarts, max_task_retries=0)
        if runtime_env:
            opts["runtime_env"] = runtime_env
        self.actors = [cls.options(**opts).remote([self.robot_ref]) for _ in range(n)]
        try:
            self.pids = ray.get([a.ping.remote() for a in self.actors], timeout=start_timeout)
        except ray.exceptions.GetTimeoutError:
            free = ray.available_resources().get("CPU", 0)
            self.kill()
            raise ClusterError(f"{n} Ray workers ({threads} CPU each) did not start within {start_timeout:.0f} s "
                               f"(start_timeout); the cluster has {free:g} CPUs free. Use fewer workers or a "
                               "bigger cluster.") from None
        except _actor_errors(ray) as e:
            self.kill()
            raise ClusterError(f"a Ray worker died while loading the robot (is profrobot installed, the same "
                               f"version, on every node?): {type(e).__name__}: {str(e)[:500]}") from e

    def kill(self) -> None:
        for a in self.actors:
            try:
                self.ray.kill(a, no_restart=True)
            except Exception:  # already gone
                pass
        self.actors = []


class _Run:
    """One call's chunks on a pool: ``submit(index, *args)`` (``actor.run(fn_ref, *args)``), then
    ``next()`` yields ``(index, result)`` as results arrive. A chunk whose actor died is resubmitted (to another
    actor when there is one); a result for an index already placed is dropped."""

    def __init__(self, executor: "RayExecutor", pool: _Pool, per_actor: int, fn: ChunkFn):
        self.ex, self.pool, self.ray = executor, pool, executor._ray
        self.fn = self.ray.put(fn)  # once per call: the chunk function, through the object store
        self.per_actor = max(1, int(per_actor))
        n = len(pool.actors)
        self.load = [0] * n
        self.down: dict[int, Any] = {}                        # actor -> its ping while Ray restarts it
        self.gone: set[int] = set()                           # actors that will not come back
        self.queue: collections.deque = collections.deque()   # (index, args, attempt, avoid)
        self.pending: dict = {}                               # ObjectRef -> (index, args, attempt, actor)
        self.pings: dict = {}                                 # ObjectRef -> (actor, tries)
        self.placed: collections.Counter = collections.Counter()
        self.stats = RunStats(placed=self.placed)
        self.dead = _actor_errors(self.ray)
        executor.last_run = self.stats

    def submit(self, index: int, *args) -> None:
        self.queue.append((index, args, 0, -1))
        self._fill()

    def _fill(self) -> None:
        up = [a for a in range(len(self.load)) if a not in self.down and a not in self.gone]
        while self.queue and up:
            index, args, attempt, avoid = self.queue[0]
            a = min(up, key=lambda a: (a == avoid, self.load[a], a))
            if self.load[a] >= self.per_actor:
                return
            self.queue.popleft()
            ref = self.pool.actors[a].run.remote(self.fn, *args)
            self.pending[ref] = (index, args, attempt, a)
            self.load[a] += 1
            self.stats.submitted += 1

    def _mark_down(self, a: int, tries: int = 0) -> None:
        """Actor ``a`` died: no new chunks for it until it answers a ping (Ray restarts it)."""
        if a in self.down or a in self.gone:
            return
        ref = self.pool.actors[a].ping.remote()
        self.down[a] = ref
        self.pings[ref] = (a, tries)

    @property
    def busy(self) -> int:
        return len(self.pending) + len(self.queue)

    def next(self) -> tuple[int, Any]:
        ray = self.ray
        waited = 0.0
        while True:
            if not self.pending:
                if self.queue and len(self.gone) == len(self.load):
                    raise ClusterError(f"every Ray worker died and none was restarted (max_restarts="
                                       f"{self.ex.max_restarts}) on {self.ex.address_text}")
                if not self.queue:
                    raise ClusterError(f"no chunk in flight and none queued on {self.ex.address_text}: the scheduler lost track of its work")
            t = time.monotonic()
            ready, _ = ray.wait(list(self.pending) + list(self.pings), num_returns=1, timeout=1.0)
            if not ready:
                waited += time.monotonic() - t
                if self.ex.task_timeout is not None and waited > self.ex.task_timeout:
                    raise ClusterError(f"no chunk finished within {self.ex.task_timeout:.0f} s (task_timeout) on the "
                                       f"Ray cluster at {self.ex.address_text}; is it still running?")
                continue
            ref = ready[0]
            if ref in self.pings:  # a restarted actor answering (or not)
                a, tries = self.pings.pop(ref)
                del self.down[a]
                try:
                    ray.get(ref)
                except self.dead:
                    if tries >= 3:
                        self.gone.add(a)
                    else:
                        self._mark_down(a, tries + 1)
                self._fill()
                continue
            index, args, attempt, a = self.pending.pop(ref)
            self.load[a] -= 1
            try:
                value = ray.get(ref)
            except self.dead as e:
                if attempt >= self.ex.max_retries:
                    raise ClusterError(f"chunk {index} lost its Ray worker {attempt + 1} times (max_retries="
                                       f"{self.ex.max_retries}); last: {type(e).__name__}: {str(e)[:300]}") from e
                self.stats.retries += 1
                self._mark_down(a)
                self.queue.appendleft((index, args, attempt + 1, a))
                self._fill()
                continue
            except ray.exceptions.RayTaskError as e:  # the chunk itself raised: the caller's exception
                self.cancel()
                raise e.as_instanceof_cause() from None
            self._fill()
            if self.placed[index]:
                self.stats.duplicates += 1
                continue
            self.placed[index] += 1
            self.stats.chunks += 1
            self.ex.on_chunk(index, a)
            return index, value

    def cancel(self) -> None:
        """Drop the chunks not needed any more (queued and in flight)."""
        self.stats.cancelled += len(self.queue) + len(self.pending)
        self.queue.clear()
        for ref in list(self.pending):
            try:
                self.ray.cancel(ref)
            except Exception:  # finished, or not cancellable: its result is simply never read
                pass
        self.pending.clear()
        self.pings.clear()
        self.down.clear()
        self.load = [0] * len(self.load)


# --------------------------------------------------------------------------------------------
# The executor
# --------------------------------------------------------------------------------------------

class RayExecutor:
    """Runs profrobot's chunked work on a Ray cluster; the output for a given seed is identical
    to the local run.

    Args:
        address: ``None`` starts a local Ray cluster (or uses the one this process already
            joined with ``ray.init``); ``"auto"`` joins the cluster started on this machine with
            ``ray start --head``; ``"host:6379"`` a cluster's GCS; ``"ray://host:10001"`` Ray
            Client.
        workers: actors per robot (one CPU each, ``threads`` CPUs with ``threads``); default:
            the cluster's CPUs divided by ``threads``.
        threads: labeller threads (and CPUs reserved) per actor: what chunk functions that
            label use there (:attr:`threads` of the executor protocol).
        num_cpus: CPUs of the local cluster started when ``address`` is ``None``.
        connect_timeout: seconds to reach the cluster before :class:`ClusterError`.
        start_timeout: seconds for the workers to start before :class:`ClusterError`.
        task_timeout: seconds without any chunk finishing before :class:`ClusterError` (None:
            wait as long as chunks take).
        max_retries: times a chunk is resubmitted after its actor died.
        max_restarts: times Ray restarts a dead actor (``-1``: always).
        per_actor: chunks in flight per actor (2 keeps each busy while a result travels).
        runtime_env: Ray's ``runtime_env`` for the actors (e.g. ``{"env_vars": {...}}``).

    Use it as a context manager, or call :meth:`shutdown`, to free its actors; the local cluster
    it started stops with it.
    """

    def __init__(self, address: str | None = None, *, workers: int | None = None, threads: int = 1,
                 num_cpus: int | None = None, connect_timeout: float = 30.0, start_timeout: float = 120.0,
                 task_timeout: float | None = None, max_retries: int = 3, max_restarts: int = 4,
                 per_actor: int = 2, runtime_env: dict | None = None):
        for name, v in (("workers", workers), ("num_cpus", num_cpus)):
            if v is not None:
                count(name, v)
        count("threads", threads)
        if address is not None and not isinstance(address, str):
            raise InputError(f"address must be None or a string such as 'auto' or 'ray://host:10001'; got {address!r}")
        self.address = address
        self.workers = None if workers is None else int(workers)
        self.threads = int(threads)
        self.num_cpus = num_cpus
        self.connect_timeout = float(connect_timeout)
        self.start_timeout = float(start_timeout)
        self.task_timeout = task_timeout
        self.max_retries = int(max_retries)
        self.max_restarts = int(max_restarts)
        self.per_actor = int(per_actor)
        self.runtime_env = runtime_env
        self.last_run: RunStats | None = None
        self._ray: Any = None   # the ray module, once connected (imported lazily: an optional dependency)
        self._started_ray = False
        self._pools: dict[str, _Pool] = {}

    def __repr__(self) -> str:
        return f"RayExecutor(address={self.address!r}, workers={self.workers})"

    @property
    def address_text(self) -> str:
        return "a local cluster" if self.address is None else repr(self.address)

    # ---- connection ---------------------------------------------------------------------------
    def connect(self) -> types.ModuleType:
        """Join (or start) the cluster; idempotent. Returns the ``ray`` module."""
        if self._ray is not None and self._ray.is_initialized():
            return self._ray
        ray = _import_ray()
        if not ray.is_initialized():
            if self.address not in (None, "auto", "local"):
                _check_reachable(self.address, self.connect_timeout)
            kwargs: dict[str, Any] = dict(address=self.address, ignore_reinit_error=True, log_to_driver=False)
            if self.address is None:
                # started here, in this thread: Ray ties its daemons' lives to the starting thread
                kwargs.update(num_cpus=self.num_cpus, include_dashboard=False)
                try:
                    ray.init(**kwargs)
                except Exception as e:
                    raise ClusterError(f"could not start a local Ray cluster: {type(e).__name__}: {e}") from e
            else:
                _init_with_timeout(ray, kwargs, self.connect_timeout, self.address_text)
            self._started_ray = True
        self._ray = ray
        return ray

    def cluster_cpus(self) -> int:
        ray = self.connect()
        return max(1, int(ray.cluster_resources().get("CPU", 1)))

    def n_workers(self) -> int:
        return self.workers or max(1, self.cluster_cpus() // self.threads)

    # ---- pools ----------------------------------------------------------------------------------
    def _pool(self, robot) -> _Pool:
        ray = self.connect()
        key, data = robot_payload(robot)
        pool = self._pools.get(key)
        if pool is not None and pool.actors:
            return pool
        n = self.n_workers()
        # actors hold their CPUs while alive: make room by retiring other robots' pools first
        while self._pools and ray.available_resources().get("CPU", 0) < n * self.threads:
            self._pools.pop(next(iter(self._pools))).kill()
        pool = _Pool(ray, key, data, n, self.threads, self.max_restarts, self.start_timeout, self.runtime_env)
        self._pools[key] = pool
        return pool

    def worker_pids(self, robot: Robot) -> list[int]:
        """The process ids of the actors that hold ``robot`` (started if need be). An actor Ray is
        restarting after it lost its process (``max_restarts``) is waited for, within
        ``start_timeout`` (:class:`ClusterError` past it), not reported as an error."""
        pool = self._pool(robot)
        ray = self._ray
        # (ActorUnavailableError: the actor is restarting; Ray versions without it raise none)
        restarting = getattr(ray.exceptions, "ActorUnavailableError", ())
        deadline = time.monotonic() + self.start_timeout
        while True:
            try:
                return ray.get([a.pid.remote() for a in pool.actors], timeout=max(deadline - time.monotonic(), 0.01))
            except restarting as e:
                if time.monotonic() > deadline:
                    raise ClusterError(f"a Ray worker was still restarting after {self.start_timeout:.0f} s "
                                       f"(start_timeout) on {self.address_text}") from e
                time.sleep(0.05)

    def put(self, value: Any) -> Any:
        """``value`` in the object store, once (an ObjectRef to pass as a chunk argument)."""
        return self.connect().put(value)

    def _run(self, robot, fn: ChunkFn) -> _Run:
        return _Run(self, self._pool(robot), self.per_actor, fn)

    def on_chunk(self, index: int, actor: int) -> None:
        """Called as chunk ``index``'s result, from actor ``actor`` (its position in
        :meth:`worker_pids`), is placed: a hook for tests and subclasses."""

    # ---- the executor protocol ------------------------------------------------------------------
    def map(self, fn: ChunkFn, chunks: Iterable, *, robot: Robot, sizes: Sequence[int] | None = None,
            desc: str = "chunks", unit: str = "chunk", progress: bool = True) -> list:
        """``[fn(robot, *args) for args in chunks]`` (a non-tuple item is one argument) on the
        robot's actors, results in order. ``fn`` travels once through the object store
        (functions defined in a script's ``__main__`` travel by value; others must be importable
        on the workers); top-level :meth:`put` handles among the arguments arrive as values."""
        chunks = [tuple(c) if isinstance(c, tuple) else (c,) for c in chunks]
        sizes = list(sizes) if sizes is not None else [1] * len(chunks)
        out: list = [None] * len(chunks)
        if not chunks:
            return out
        run = self._run(robot, fn)
        for i, args in enumerate(chunks):
            run.submit(i, *args)
        with progress_bar(sum(sizes), desc=desc, unit=unit, progress=progress) as bar:
            try:
                for _ in range(len(chunks)):
                    i, value = run.next()
                    out[i] = value
                    bar.update(sizes[i])
            except BaseException:
                run.cancel()
                raise
        return out

    def ordered(self, fn: ChunkFn, args_of: Callable[[int], tuple], limit: int, demand: Callable[[], int], *,
                robot: Robot) -> Generator[tuple[int, Any], None, None]:
        """Chunks ``0, 1, 2, ...`` (< ``limit``) yielded in index order, ``args_of(i)`` their
        arguments. At most ``demand()`` chunks (asked after each one is consumed: the caller's
        estimate of how many more it needs) are in flight or buffered beyond those consumed;
        closing the generator cancels the rest."""
        run = self._run(robot, fn)
        buffered: dict[int, Any] = {}
        nxt = sub = 0
        try:
            while nxt < limit:
                want = max(1, int(demand()))
                while sub < limit and sub - nxt < want:
                    run.submit(sub, *args_of(sub))
                    sub += 1
                while nxt not in buffered:
                    i, value = run.next()
                    buffered[i] = value
                yield nxt, buffered.pop(nxt)
                nxt += 1
        finally:
            run.cancel()

    # ---- teardown -------------------------------------------------------------------------------
    def release(self) -> None:
        """Kill this executor's actors (freeing their CPUs); it stays connected, and starts new
        ones on its next call."""
        for pool in self._pools.values():
            pool.kill()
        self._pools.clear()

    def shutdown(self) -> None:
        """Kill this executor's actors; stop the local cluster if this executor started it."""
        self.release()
        if self._started_ray and self._ray is not None and self._ray.is_initialized():
            self._ray.shutdown()
        self._started_ray = False
        self._ray = None

    close = shutdown

    def __enter__(self) -> "RayExecutor":
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()


# --------------------------------------------------------------------------------------------
# Connection checks (Ray's ray.init retries a wrong address forever)
# --------------------------------------------------------------------------------------------

def _host_port(address: str) -> tuple[str, int] | None:
    a = address
    for scheme in ("ray://", "http://", "https://"):
        if a.startswith(scheme):
            a = a[len(scheme):]
            break
    a = a.split("/")[0]
    host, sep, port = a.rpartition(":")
    if not sep or not port.isdigit():
        return None
    return host.strip("[]") or "127.0.0.1", int(port)


def _check_reachable(address: str, timeout: float) -> None:
    hp = _host_port(address)
    if hp is None:
        raise ClusterError(f"Ray address {address!r} is not 'auto', 'host:port' or 'ray://host:port'")
    try:
        with socket.create_connection(hp, timeout=timeout):
            pass
    except TimeoutError:
        raise ClusterError(f"no Ray cluster answered at {address!r} within {timeout:.0f} s (connect_timeout); "
                           "is the head node running (`ray start --head`) and the port open?") from None
    except OSError as e:
        raise ClusterError(f"cannot reach a Ray cluster at {address!r}: {e.strerror or e}; start one with "
                           "`ray start --head` and pass the address it prints") from None


def _init_with_timeout(ray, kwargs: dict, timeout: float, where: str) -> None:
    """``ray.init(**kwargs)`` in a daemon thread, abandoned (and the half-made connection shut
    down) after ``timeout`` seconds."""
    box: dict[str, Any] = {}

    def target():
        try:
            box["ctx"] = ray.init(**kwargs)
        except BaseException as e:  # handed to the caller
            box["error"] = e

    th = threading.Thread(target=target, name="profrobot-ray-init", daemon=True)
    th.start()
    th.join(timeout)
    if th.is_alive():
        raise ClusterError(f"Ray did not connect to {where} within {timeout:.0f} s (connect_timeout); is the "
                           "cluster running and its address right?")
    if "error" in box:
        e = box["error"]
        raise ClusterError(f"could not connect to the Ray cluster at {where}: {type(e).__name__}: {e}") from e
