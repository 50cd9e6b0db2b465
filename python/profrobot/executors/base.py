"""The protocol every executor follows, the one place chunks are cut, and the per-process caches
chunk functions keep.

A *chunk function* is a module-level, pure function ``fn(robot, *args)``: its result depends only
on the robot and its arguments (a seed, a chunk index, row bounds), never on which process runs
it or when. An executor maps one over the chunks of a call and returns the results in chunk
order, so any executor gives the caller the same bytes. What a chunk function keeps between
calls in its process (a MuJoCo renderer, a GL context) lives in its own module, registered with
:func:`on_release` so that a local worker frees it when its call ends.
"""

from __future__ import annotations

import hashlib
import pickle
import weakref
from collections.abc import Callable, Generator, Sequence
from typing import Any, Protocol, runtime_checkable


from ..errors import InputTypeError
from ..robot.robot import Robot
from ..robot.gate import count

__all__ = ["ChunkFn", "Executor", "chunk_bounds", "chunk_sizes", "on_release", "release_caches"]

ChunkFn = Callable[..., Any]
"""``fn(robot, *args) -> result``: module-level (importable by the workers) and pure."""


def chunk_bounds(n: int, chunk: int) -> list[tuple[int, int]]:
    """``[(start, stop), ...]``: rows ``0..n`` cut into consecutive chunks of ``chunk`` rows (the
    last may be shorter). Every client cuts its work here, so a chunk's rows depend only on
    ``n`` and ``chunk``."""
    chunk, n = count("chunk", chunk), count("n", n, 0)
    return [(i, min(i + chunk, n)) for i in range(0, n, chunk)]


def chunk_sizes(bounds: Sequence[tuple[int, int]]) -> list[int]:
    """Rows per chunk of :func:`chunk_bounds` (a progress bar's steps)."""
    return [b - a for a, b in bounds]


@runtime_checkable
class Executor(Protocol):
    """What :func:`profrobot.make_dataset`, :func:`profrobot.crosscheck`,
    :func:`profrobot.render.make_views` and the benches need of an executor.

    ``threads``: labeller threads a chunk function should use in a worker (``None``: as the
    caller asked).
    """

    @property
    def threads(self) -> int | None: ...

    def put(self, value: Any) -> Any:
        """A handle to ``value``, stored once, to pass as a top-level chunk argument: the chunk
        function receives ``value`` itself (large inputs travel once, not once per chunk)."""
        ...

    def map(self, fn: ChunkFn, chunks: Sequence[tuple], *, robot: Robot, sizes: Sequence[int] | None = None,
            desc: str = "chunks", unit: str = "chunk", progress: bool = True) -> list:
        """``[fn(robot, *args) for args in chunks]``, computed anywhere, returned in order."""
        ...

    def ordered(self, fn: ChunkFn, args_of: Callable[[int], tuple], limit: int, demand: Callable[[], int], *,
                robot: Robot) -> Generator[tuple[int, Any], None, None]:
        """``(i, fn(robot, *args_of(i)))`` for ``i = 0, 1, ...`` (< ``limit``), yielded in order;
        at most ``demand()`` chunks (asked after each is consumed: the caller's estimate of how
        many more it needs) computed ahead. Closing the generator cancels the rest."""
        ...


# --------------------------------------------------------------------------------------------
# Per-process caches of chunk functions
# --------------------------------------------------------------------------------------------

_RELEASE: list[Callable[[], None]] = []


def on_release(fn: Callable[[], None]) -> Callable[[], None]:
    """Register ``fn`` (no arguments) to free a chunk module's per-process caches (renderers and
    their GL contexts). Local worker processes call every registered function when a call ends
    (they may then wait idle for the next one); Ray actors keep their caches while they live."""
    if fn not in _RELEASE:
        _RELEASE.append(fn)
    return fn


def release_caches() -> None:
    """Call every function registered with :func:`on_release`, in this process."""
    for fn in list(_RELEASE):
        fn()


_PAYLOADS: "weakref.WeakKeyDictionary[Any, tuple[str, bytes]]" = weakref.WeakKeyDictionary()


def robot_payload(robot) -> tuple[str, bytes]:
    """``(key, bytes)``: ``robot`` pickled once (remembered per robot object, for every executor)
    and the sha256 of those bytes, which names the workers that hold it."""
    if not isinstance(robot, Robot):
        raise InputTypeError(f"expected a profrobot.Robot; got {type(robot).__name__}")
    hit = _PAYLOADS.get(robot)
    if hit is None:
        data = pickle.dumps(robot, protocol=pickle.HIGHEST_PROTOCOL)
        hit = _PAYLOADS[robot] = (hashlib.sha256(data).hexdigest(), data)
    return hit
