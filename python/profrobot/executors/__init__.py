"""Where chunked work runs: one protocol, two executors.

Every client (:func:`profrobot.make_dataset`, :func:`profrobot.crosscheck`,
:func:`profrobot.render.make_views`, trajectory pictures, the batch benches) cuts its work into
chunks (:func:`chunk_bounds`, or seeded rounds) and hands an executor its own *chunk function*:
a module-level, pure ``fn(robot, *args)``. The executor maps it over the chunks and returns the
results in chunk order (:class:`Executor`), so the output for a seed is the same bytes whichever
executor ran it and however many workers it had.

- :class:`LocalExecutor` (``executor=None`` everywhere): this process, or worker processes;
  chunk functions that draw with MuJoCo (:func:`profrobot.gl.uses_gl`) always run in worker
  processes with the ``MUJOCO_GL`` profrobot chose.
- :class:`RayExecutor`: long-lived actors per robot on a Ray cluster (``pip install
  "profrobot[ray]"``; Ray is imported only when it connects).
"""

from __future__ import annotations

from ..errors import ClusterError, InputTypeError
from .base import ChunkFn, Executor, chunk_bounds, chunk_sizes, on_release, release_caches
from .local import LocalExecutor, close_workers
from .progress import progress_bar
from .ray_cluster import RayExecutor, RunStats

__all__ = ["Executor", "ChunkFn", "LocalExecutor", "RayExecutor", "ClusterError", "RunStats", "check_executor",
           "chunk_bounds", "chunk_sizes", "on_release", "release_caches", "close_workers", "progress_bar"]


def check_executor(executor: Executor | None, *, processes: int = 1) -> Executor:
    """``executor`` if it follows the :class:`Executor` protocol (a :class:`LocalExecutor`, a
    :class:`RayExecutor`, or your own); ``None``: ``LocalExecutor(processes)``."""
    if executor is None:
        return LocalExecutor(processes)
    if isinstance(executor, (LocalExecutor, RayExecutor)) or isinstance(executor, Executor):
        return executor
    raise InputTypeError("executor must be None (local), a profrobot.executors.LocalExecutor or RayExecutor, or follow "
                    f"the profrobot.executors.Executor protocol; got {type(executor).__name__}")
