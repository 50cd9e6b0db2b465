"""Instruction counts of the native renderer per composited pair (issue 22, acceptance 4).

    python benches/render.py --skip-pose            # writes benches/out/render/native_scene.npz
    valgrind --tool=callgrind --callgrind-out-file=/tmp/cg.1 python benches/render_callgrind.py --reps 1
    valgrind --tool=callgrind --callgrind-out-file=/tmp/cg.3 python benches/render_callgrind.py --reps 3
    # instructions per forward + backward = (Ir(3) - Ir(1)) / 2; per pair: divide by the pairs printed

Loads only numpy and the compiled ``_core`` (no torch, no MuJoCo), so that callgrind counts the
renderer and little else: the scene (12 k Gaussians of the fitted Panda, 4 cameras at 128^2, world
means and covariances, SH frames) was saved by ``benches/render.py``. ``--kernel`` breaks the
counts down with ``callgrind_annotate --inclusive=yes`` (splat::forward_checked, splat::backward:
the rasterizer alone).
"""

import argparse
import glob
import importlib.util
import os

import numpy as np


def load_core():
    here = os.path.dirname(os.path.abspath(__file__))
    paths = glob.glob(os.path.join(here, "..", "python", "profrobot", "_core*.so"))
    if not paths:                                    # an installed (non-editable) package
        import sysconfig
        paths = glob.glob(os.path.join(sysconfig.get_paths()["platlib"], "profrobot", "_core*.so"))
    spec = importlib.util.spec_from_file_location("_core", paths[0])
    core = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(core)
    return core


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="benches/out/render/native_scene.npz")
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    core = load_core()
    d = np.load(a.scene)
    C = len(d["vm"])
    views = np.array([[0, c] for c in range(C)], dtype=np.int64)
    H, W = int(d["size"][0]), int(d["size"][1])
    g = [np.ones((C, H, W, 3), np.float32), np.ones((C, H, W), np.float32), np.ones((C, H, W), np.float32)]
    for _ in range(a.reps):
        out = core.render_forward(d["op"], d["vm"], d["K"], views, W, H, means=d["mu"], covs=d["cov"], sh=d["sh"],
                                  frames=d["fr"], threads=a.threads)
        core.render_backward(out[5], *g, threads=a.threads)
    print(f"composited pairs per forward: {out[4]}")


if __name__ == "__main__":
    main()
