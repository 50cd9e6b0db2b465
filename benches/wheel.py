"""The installed wheel against the editable build, side by side in one run: labelling throughput
(``label_poses`` on panda_blocks, 200 000 poses, all cores) and one native render (12 000 random
Gaussians, 4 views of 128², forward and backward, the Rust kernel).

Each interpreter runs the same measurement in a subprocess, alternating A B A B ... (``--rounds``
each), so that drift on the machine hits both alike; the medians and their ratio are printed.

    python benches/wheel.py --editable EDITABLE_VENV/bin/python --wheel WHEEL_VENV/bin/python [--rounds 5]

(Nothing else running; the load average is printed.)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess

import numpy as np

MEASURE = r'''
import json, time, numpy as np, torch, profrobot
from profrobot import scenes
from profrobot.render.rasterize import rasterize
robot = scenes.load("panda_blocks")
q = profrobot.sample_poses(robot, 200_000, seed=0)
profrobot.label_poses(robot, q[:1000])
t = time.perf_counter(); profrobot.label_poses(robot, q); label = time.perf_counter() - t
g = torch.Generator().manual_seed(0)
N, C, S = 12_000, 4, 128
means = (torch.rand(N, 3, generator=g) - 0.5) * 0.6
A = torch.randn(N, 3, 3, generator=g, dtype=torch.float32) * 0.01
covs = A @ A.transpose(1, 2) + 1e-5 * torch.eye(3)
opac = torch.rand(N, generator=g) * 0.9
cols = torch.rand(N, 3, generator=g)
cams = profrobot.render.ring_cameras(C, distance=1.5, lookat=(0.0, 0.0, 0.0), size=S)
V = torch.as_tensor(cams.world_to_cam, dtype=torch.float32); K = torch.as_tensor(cams.K, dtype=torch.float32)
for x in (means, covs, opac, cols):
    x.requires_grad_(True)
def once():
    out = rasterize(means, covs, opac, cols, V, K, S, S, backend="rust")
    (out.rgb.sum() + out.alpha.sum()).backward()
once()
t = time.perf_counter(); once(); render = time.perf_counter() - t
print(json.dumps(dict(label=label, render=render, where=profrobot.__file__)))
'''


def run(python: str) -> dict:
    out = subprocess.run([python, "-c", MEASURE], capture_output=True, text=True, env=dict(os.environ))
    if out.returncode != 0:
        raise SystemExit(f"{python} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--editable", required=True, help="the python of the venv with the editable build")
    ap.add_argument("--wheel", required=True, help="the python of the venv with the installed wheel")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    res = {"editable": [], "wheel": []}
    for _ in range(args.rounds):
        for name in ("editable", "wheel"):
            res[name].append(run(getattr(args, name)))
    for name in res:
        print(f"{name}: {res[name][0]['where']}")
    for key, unit, scale in (("label", "poses/s", 200_000), ("render", "ms", 1e3)):
        e = np.median([r[key] for r in res["editable"]])
        w = np.median([r[key] for r in res["wheel"]])
        if unit == "poses/s":
            print(f"label_poses: editable {scale / e:,.0f} poses/s, wheel {scale / w:,.0f} poses/s "
                  f"(wheel / editable throughput {e / w:.3f})")
        else:
            print(f"render fwd+bwd: editable {e * scale:.1f} ms, wheel {w * scale:.1f} ms (wheel / editable time "
                  f"{w / e:.3f})")
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
