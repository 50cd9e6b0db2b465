"""Wall time of two builds of the native renderer, alternated call by call (issue 39).

    python benches/render.py --skip-pose        # writes benches/out/render/native_scene.npz
    cp python/profrobot/_core.abi3.so /tmp/core_a.so      # a build before a change
    ...                                                    # change, rebuild (maturin develop -r)
    python benches/render_ab.py /tmp/core_a.so python/profrobot/_core.abi3.so --threads 2

On a machine whose speed drifts by tens of percent within minutes, timing one build and then the
other compares two moments as much as two builds. This script loads both ``_core`` builds into one
process (numpy and the compiled modules only, as ``render_callgrind.py``) and times them
alternately on the same scene (12 k Gaussians of the fitted Panda, 4 cameras at 128^2): forward,
then backward with fixed random image gradients. It prints per build the median and the fastest
call, and the process's page faults and system time per call, and checks that both builds give
the same images and gradients, bit for bit. Instruction counts (``render_callgrind.py``) are the
other way to compare; this one sees what they cannot: threads, memory, the allocator.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import resource
import time

import numpy as np


def load(path: str, alias: str):
    """The ``_core`` extension at ``path`` (a copy of a build), as its own module object."""
    spec = importlib.util.spec_from_file_location("_core", path)
    if spec is None or spec.loader is None:
        raise SystemExit(f"{alias}: cannot load {path}")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a", help="path of the first build's _core shared library")
    ap.add_argument("b", help="path of the second build's _core shared library")
    ap.add_argument("--scene", default="benches/out/render/native_scene.npz")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=40, help="calls per build (alternated)")
    a = ap.parse_args()
    if os.path.realpath(a.a) == os.path.realpath(a.b):
        raise SystemExit("the two paths are the same file: copy one build away first")
    builds = {"a": load(a.a, "a"), "b": load(a.b, "b")}
    d = dict(np.load(a.scene))
    c = len(d["vm"])
    views = np.array([[0, k] for k in range(c)], dtype=np.int64)
    h, w = int(d["size"][0]), int(d["size"][1])
    rng = np.random.default_rng(0)
    grads = [rng.standard_normal(s).astype(np.float32) for s in ((c, h, w, 3), (c, h, w), (c, h, w))]

    def call(core):
        out = core.render_forward(d["op"], d["vm"], d["K"], views, w, h, means=d["mu"], covs=d["cov"], sh=d["sh"],
                                  frames=d["fr"], threads=a.threads)
        t = time.perf_counter()
        g = core.render_backward(out[5], *grads, threads=a.threads)
        return out, g, t

    first = {k: call(core)[:2] for k, core in builds.items()}       # warm-up, and the outputs compared
    (oa, ga), (ob, gb) = first["a"], first["b"]
    same = all(np.array_equal(x, y) for x, y in zip(oa[:4], ob[:4])) and oa[4] == ob[4] \
        and ga.keys() == gb.keys() and all(np.array_equal(ga[k], gb[k]) for k in ga)
    times = {k: ([], []) for k in builds}
    usage = {k: [0, 0.0] for k in builds}
    print(f"{a.threads} threads, {a.reps} calls per build, alternated; load average {os.getloadavg()[0]:.2f}", flush=True)
    for _ in range(a.reps):
        for k, core in builds.items():
            r0 = resource.getrusage(resource.RUSAGE_SELF)
            t0 = time.perf_counter()
            out, g, t1 = call(core)
            t2 = time.perf_counter()
            r1 = resource.getrusage(resource.RUSAGE_SELF)
            del out, g
            times[k][0].append(t1 - t0)
            times[k][1].append(t2 - t1)
            usage[k][0] += r1.ru_minflt - r0.ru_minflt
            usage[k][1] += r1.ru_stime - r0.ru_stime
    for k, path in (("a", a.a), ("b", a.b)):
        f, b = (1e3 * np.array(x) for x in times[k])
        print(f"{k} {path}: forward median {np.median(f):.2f} ms (fastest {f.min():.2f}), backward median "
              f"{np.median(b):.2f} ms (fastest {b.min():.2f}); per call {usage[k][0] / a.reps:.0f} page faults, "
              f"{1e3 * usage[k][1] / a.reps:.1f} ms system time")
    print(f"images and gradients {'bit-identical' if same else 'DIFFER'}; load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
