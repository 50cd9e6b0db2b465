"""Beyond one machine (issue 14): make_dataset, make_views and crosscheck on a local 2-worker Ray
cluster give byte-identical outputs to the local run for the same seed, whatever the number of
workers; a worker killed mid-run loses and duplicates nothing; a wrong address raises a clear
ClusterError within the stated time-out; nothing imports ray unless asked."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import profrobot
from profrobot.executors import ClusterError, LocalExecutor, RayExecutor, chunk_bounds

from conftest import scene

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LABELS = ("poses", "collides", "self_collides", "scene_collides", "n_pairs")


def same_array(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def same_dataset(a, b) -> bool:
    return all(same_array(getattr(a, k), getattr(b, k)) for k in LABELS) and a.metadata == b.metadata


def same_views(a, b) -> bool:
    return (all(same_array(getattr(a, k), getattr(b, k)) for k in ("poses", "rgb", "depth", "mask"))
            and a.metadata == b.metadata and a.cameras.to_dict() == b.cameras.to_dict())


class KillOnce(RayExecutor):
    """Once armed with the actors' pids, kills (SIGKILL) the process of the actor whose result
    arrives as the ``after``-th chunk is placed, shortly after that actor was handed its next
    chunk: the kill lands mid-chunk while other chunks are in flight."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self.pids: list[int] | None = None
        self.after = 1
        self.seen = 0
        self.killed: int | None = None

    def arm(self, robot, after: int = 1) -> list[int]:
        self.pids = self.worker_pids(robot)
        self.after, self.seen, self.killed = after, 0, None
        return self.pids

    def on_chunk(self, index: int, actor: int) -> None:
        self.seen += 1
        if self.pids is not None and self.seen == self.after:
            time.sleep(0.03)  # its next chunk reaches it and starts
            os.kill(self.pids[actor], signal.SIGKILL)
            self.killed, self.pids = self.pids[actor], None


@pytest.fixture(scope="module")
def ray_executor():
    pytest.importorskip("ray")
    ex = KillOnce(num_cpus=2, workers=2, max_restarts=4, max_retries=3, start_timeout=180)
    ex.connect()
    yield ex
    ex.shutdown()


def assert_each_chunk_once(ex: RayExecutor) -> None:
    st = ex.last_run
    assert st is not None and st.duplicates == 0
    assert set(st.placed.values()) == {1} and st.chunks == len(st.placed)


# --------------------------------------------------------------------------------------------

def test_make_dataset_identical_to_local(ray_executor):
    robot = scene("panda_blocks")
    local = profrobot.make_dataset(robot, 3000, 0.5, seed=7, batch=1000, progress=False)
    remote = profrobot.make_dataset(robot, 3000, 0.5, seed=7, batch=1000, progress=False, executor=ray_executor)
    assert same_dataset(local, remote)
    assert_each_chunk_once(ray_executor)
    # rounds are placed by index: the rounds the quotas consumed, each once
    assert ray_executor.last_run.chunks >= local.metadata["samples_drawn"] // 1000
    # other fractions (a different quota order) and the one-worker cluster give the same data
    local = profrobot.make_dataset(robot, 1000, 0.2, seed=2, batch=500, progress=False)
    ray_executor.release()
    one = RayExecutor(workers=1)
    try:
        assert same_dataset(local, profrobot.make_dataset(robot, 1000, 0.2, seed=2, batch=500, progress=False,
                                                          executor=one))
    finally:
        one.release()
    assert same_dataset(local, profrobot.make_dataset(robot, 1000, 0.2, seed=2, batch=500, progress=False,
                                                      executor=ray_executor))


def test_make_dataset_errors_come_back_as_ours(ray_executor):
    robot = scene("panda_blocks")
    with pytest.raises(profrobot.ProfrobotError, match="could not fill the quotas"):
        profrobot.make_dataset(robot, 100, 1.0, seed=0, batch=50, max_samples=200, progress=False,
                               executor=ray_executor)
    with pytest.raises(TypeError, match="executor must be None"):
        profrobot.make_dataset(robot, 100, executor="ray")
    assert profrobot.errors.ClusterError is ClusterError


def test_crosscheck_identical_to_local(ray_executor):
    robot = scene("ur5e_wall_box")
    q = profrobot.sample_poses(robot, 600, seed=4)
    a = profrobot.crosscheck(robot, q)
    b = profrobot.crosscheck(robot, q, executor=ray_executor, chunk=64)
    assert_each_chunk_once(ray_executor)
    assert ray_executor.last_run.chunks == 10
    assert same_array(a.reference.ncon, b.reference.ncon) and same_array(a.reference.collides, b.reference.collides)
    assert a.reference.pairs == b.reference.pairs
    assert same_array(a.confusion, b.confusion) and same_array(a.mujoco_contacts, b.mujoco_contacts)
    assert (a.agreement, a.pair_agreement, a.disagreements) == (b.agreement, b.pair_agreement, b.disagreements)
    for k in ("collides", "self_collides", "scene_collides", "n_pairs", "colliding_pairs"):
        assert same_array(getattr(a.ours, k), getattr(b.ours, k))


def test_make_views_identical_to_local(ray_executor, renderer):
    from profrobot.render import make_views, ring_cameras

    robot = scene("panda_blocks")
    q = profrobot.sample_poses(robot, 5, seed=1)
    cams = ring_cameras(2, size=24, distance=1.6)
    a = make_views(robot, q, cams, progress=False, chunk=2)
    b = make_views(robot, q, cams, progress=False, chunk=2, executor=ray_executor)
    assert same_views(a, b) and a.mask.any()
    assert_each_chunk_once(ray_executor)
    # the actors keep the robot; new cameras re-make only the renderer
    c = make_views(robot, q[:2], cams.resized(16), progress=False, chunk=1, executor=ray_executor)
    assert same_views(make_views(robot, q[:2], cams.resized(16), progress=False), c)


def test_killed_worker_loses_and_duplicates_nothing(ray_executor, renderer):
    robot = scene("panda_blocks")
    ex = ray_executor
    # rounds of 20 000 poses (~0.1 s each on one core), six or so needed
    clean = profrobot.make_dataset(robot, 40_000, 0.5, seed=11, batch=20_000, progress=False)
    ex.arm(robot, after=1)
    got = profrobot.make_dataset(robot, 40_000, 0.5, seed=11, batch=20_000, progress=False, executor=ex)
    assert ex.killed is not None, "the kill did not happen"
    assert ex.last_run.retries >= 1, ex.last_run
    assert_each_chunk_once(ex)
    assert same_dataset(clean, got)
    # the restarted actor renders: views with one actor killed mid-run, byte-identical too
    from profrobot.render import make_views, ring_cameras

    q = profrobot.sample_poses(robot, 8, seed=3)
    cams = ring_cameras(3, size=48, distance=1.6)
    clean_views = make_views(robot, q, cams, progress=False, chunk=2)
    before = ex.arm(robot, after=1)
    views = make_views(robot, q, cams, progress=False, chunk=2, executor=ex)
    assert ex.killed is not None and ex.last_run.retries >= 1, ex.last_run
    assert_each_chunk_once(ex)
    assert ex.last_run.chunks == 4
    assert same_views(clean_views, views)
    after = ex.worker_pids(robot)
    assert ex.killed not in after and len(set(after) - set(before)) == 1  # Ray restarted it, a new process


def test_map_runs_a_function_on_the_workers(ray_executor):
    robot = scene("panda_blocks")
    got = ray_executor.map(profrobot.sample_poses, [(50, s) for s in range(5)], robot=robot, progress=False)
    for s, q in enumerate(got):
        assert same_array(q, profrobot.sample_poses(robot, 50, s))
    # put: a handle that arrives as the value itself, top-level in a chunk's arguments (a chunk
    # function importable on the workers: profrobot's own)
    from profrobot.exact.crosscheck import mujoco_labels_chunk

    q = profrobot.sample_poses(robot, 40, seed=6)
    ref = ray_executor.put(q)
    bounds = chunk_bounds(len(q), 16)
    assert bounds == [(0, 16), (16, 32), (32, 40)]
    got = ray_executor.map(mujoco_labels_chunk, [(ref, a, b) for a, b in bounds], robot=robot, progress=False)
    assert same_array(np.concatenate([ncon for ncon, _ in got]), mujoco_labels_chunk(robot, q, 0, len(q))[0])


def rows_collide(robot, poses, start, stop):
    """A chunk function (module-level, pure): collisions of ``poses[start:stop]``. Local worker
    processes import it from here (they get this process's ``sys.path``)."""
    return profrobot.collides(robot, poses[start:stop])


def test_the_same_protocol_locally():
    """The chunk functions Ray runs, on a LocalExecutor with worker processes: the same results."""
    robot = scene("ur5e_wall_box")
    q = profrobot.sample_poses(robot, 300, seed=8)
    here = profrobot.crosscheck(robot, q, chunk=64)
    two = profrobot.crosscheck(robot, q, chunk=64, executor=LocalExecutor(processes=2))
    assert same_array(here.reference.ncon, two.reference.ncon) and here.reference.pairs == two.reference.pairs
    local = LocalExecutor(processes=2, threads=1)
    ds = profrobot.make_dataset(robot, 600, 0.5, seed=3, batch=200, progress=False, executor=local)
    assert same_dataset(profrobot.make_dataset(robot, 600, 0.5, seed=3, batch=200, progress=False), ds)
    ref = local.put(q)
    got = local.map(rows_collide, [(ref, a, b) for a, b in chunk_bounds(len(q), 128)], robot=robot, progress=False)
    assert same_array(np.concatenate(got), profrobot.collides(robot, q))


# --------------------------------------------------------------------------------------------

def run_fresh(code: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def test_wrong_or_silent_address_raises_within_the_timeout():
    pytest.importorskip("ray")
    done = run_fresh("""
        import socket, time
        from profrobot.executors import ClusterError, RayExecutor
        for addr in ("127.0.0.1:1", "ray://127.0.0.1:1", "not an address"):
            try:
                RayExecutor(addr, connect_timeout=5).connect()
            except ClusterError as e:
                print("ERR", e)
        srv = socket.socket(); srv.bind(("127.0.0.1", 0)); srv.listen(4)   # listens, never answers
        t = time.monotonic()
        try:
            RayExecutor(f"127.0.0.1:{srv.getsockname()[1]}", connect_timeout=3).connect()
        except ClusterError as e:
            print("ERR", e)
        print("SECONDS", time.monotonic() - t)
        """)
    assert done.returncode == 0, done.stderr[-3000:]
    errs = [ln for ln in done.stdout.splitlines() if ln.startswith("ERR")]
    assert len(errs) == 4, done.stdout
    assert "cannot reach a Ray cluster at '127.0.0.1:1'" in errs[0] and "ray start --head" in errs[0]
    assert "ray://127.0.0.1:1" in errs[1]
    assert "is not 'auto'" in errs[2]
    assert "did not connect" in errs[3] and "within 3 s (connect_timeout)" in errs[3]


def test_nothing_imports_ray_unless_asked():
    done = run_fresh("""
        import sys
        import profrobot
        robot = profrobot.scenes.load("panda_blocks")
        profrobot.make_dataset(robot, 200, progress=False)
        profrobot.crosscheck(robot, profrobot.sample_poses(robot, 20))
        import profrobot.executors
        assert "ray" not in sys.modules, "ray imported"
        print("OK")
        """)
    assert done.returncode == 0 and "OK" in done.stdout, done.stderr[-3000:]


def test_no_ray_installed_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(ClusterError, match=r"pip install \"profrobot\[ray\]\""):
        RayExecutor().connect()
