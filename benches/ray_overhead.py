"""What Ray costs on one machine: make_dataset locally against the same call through a local
2-worker Ray cluster, and make_views through 1 and then 2 Ray workers, in one run.

    python benches/ray_overhead.py [--n 1000000] [--views 200] [--cameras 4] [--size 128] [--repeats 2]

make_dataset: the local run uses all cores in one process (the labeller's threads); the Ray run
uses ``workers`` actors of one CPU each, rounds farmed out, quotas filled here. Both produce the
same dataset (checked, byte for byte). Times are best of ``--repeats``, local and Ray alternated;
the Ray actors are started (robot loaded, one warm-up call) before timing, as the long-lived
actors of a session are; their cold start is printed beside. make_views: ``--views`` poses times
``--cameras`` cameras at ``--size``², MuJoCo offscreen in the actors (backend as
:mod:`profrobot.gl` chooses), with 1 then 2 workers (renderers made before timing); the ratio
is the speed-up. The load average (``uptime``) is printed before and after: other work on the
machine shows there.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import time

import profrobot
from profrobot.executors import RayExecutor
from profrobot.render import make_views, ring_cameras


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "load average: {:.2f}, {:.2f}, {:.2f}".format(*os.getloadavg())


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def same(a, b, keys) -> bool:
    return all(getattr(a, k).tobytes() == getattr(b, k).tobytes() for k in keys)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="panda_blocks")
    ap.add_argument("--n", type=int, default=1_000_000, help="make_dataset poses")
    ap.add_argument("--views", type=int, default=200, help="make_views poses")
    ap.add_argument("--cameras", type=int, default=4)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--chunk", type=int, default=8, help="make_views poses per task")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    print("before:", uptime(), flush=True)
    robot = profrobot.scenes.load(args.scene)
    keys = ("poses", "collides", "self_collides", "scene_collides", "n_pairs")

    ex = RayExecutor(num_cpus=args.workers, workers=args.workers)
    cold, _ = timed(lambda: profrobot.make_dataset(robot, 2000, seed=1, batch=1000, progress=False, executor=ex))
    local_t, ray_t = [], []
    for _ in range(args.repeats):
        t, local = timed(lambda: profrobot.make_dataset(robot, args.n, seed=0, progress=False))
        local_t.append(t)
        t, remote = timed(lambda: profrobot.make_dataset(robot, args.n, seed=0, progress=False, executor=ex))
        ray_t.append(t)
        assert same(local, remote, keys) and local.metadata == remote.metadata, "Ray dataset differs from local"
    st = ex.last_run
    print(f"make_dataset {args.scene}, {args.n:,} poses ({local.metadata['samples_drawn']:,} drawn in rounds of "
          f"100 000): local (one process, {os.cpu_count()} cores) {min(local_t):.2f} s "
          f"[{', '.join(f'{t:.2f}' for t in local_t)}]; Ray {args.workers} workers {min(ray_t):.2f} s "
          f"[{', '.join(f'{t:.2f}' for t in ray_t)}]; ratio Ray/local {min(ray_t) / min(local_t):.3f} "
          f"(identical bytes: yes; rounds used {local.metadata['samples_drawn'] // 100_000}, finished on Ray "
          f"{st.chunks}, cancelled in flight {st.cancelled}); actors' cold start + a 2 000-pose call {cold:.2f} s",
          flush=True)
    print("after make_dataset:", uptime(), flush=True)

    q = profrobot.sample_poses(robot, args.views, seed=5)
    cams = ring_cameras(args.cameras, size=args.size, distance=1.8, elevation=-25.0)
    ex.release()
    times, outs = {}, {}
    for w in (1, 2):
        one = RayExecutor(workers=w)
        warm, _ = timed(lambda one=one, w=w: make_views(robot, q[:w * 2], cams, chunk=2, progress=False, executor=one))
        times[w], outs[w] = timed(lambda one=one: make_views(robot, q, cams, chunk=args.chunk, progress=False,
                                                             executor=one))
        print(f"make_views {args.views} poses x {args.cameras} cameras at {args.size}^2, {w} Ray worker(s): "
              f"{times[w]:.2f} s ({args.views / times[w]:.1f} poses/s; cold start + warm-up {warm:.2f} s)", flush=True)
        one.release()
    ok = same(outs[1], outs[2], ("rgb", "depth", "mask"))
    print(f"make_views speed-up 1 -> 2 workers: {times[1] / times[2]:.2f}x (identical bytes: {'yes' if ok else 'NO'})")
    print("after:", uptime(), flush=True)
    ex.shutdown()
    if not ok:
        raise SystemExit("views differ between 1 and 2 workers")


if __name__ == "__main__":
    main()
