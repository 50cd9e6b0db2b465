"""Straight-line moves of a frame: 100 approach moves of 5-10 cm per bundled arm.

    python benches/cartesian.py [--moves 100] [--scenes a,b]

Per arm, ``--moves`` certified start poses (``sample_poses`` then ``certify_poses``), each moving
its tool frame 5-10 cm along its own z axis with its orientation held (``plan_cartesian``,
defaults: 1 mm and 0.01 rad of the line). Every returned path is checked here, independently
of the implementation: every segment certified (``certify_motions``), and the frame placed by
MuJoCo's forward kinematics (``mj_kinematics``) every 0.1 mm of its travel, its distance from
the line and its angle from the held orientation measured. Reported: moves that reach the
end, the fraction covered by those that stop and their reasons, the largest deviation seen,
and the time per move (median, p95; run it alone on the machine). Markdown in
``benches/cartesian_results.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

import profrobot
from results import write_results

FRAMES = {"panda_blocks": "hand", "panda_shelf": "hand", "ur5e_wall_box": "wrist_3_link", "xarm7_table": "link7",
          "vx300s_clutter": "gripper_link"}
RESULTS = Path(__file__).resolve().parent / "cartesian_results.md"


def frame_at(robot, d, q, body):
    d.qpos[robot.qpos_adr] = q
    mujoco.mj_kinematics(robot.mj_model, d)
    return d.xpos[body].copy(), d.xquat[body].copy()


def run(name: str, n: int) -> dict:
    robot = profrobot.scenes.load(name)
    frame = FRAMES[name]
    body = robot.mj_model.body(frame).id
    d = mujoco.MjData(robot.mj_model)
    q = profrobot.sample_poses(robot, 20 * n, seed=3)
    q = q[profrobot.certify_poses(robot, q)][:n]
    rng = np.random.default_rng(0)
    ms, reached, fractions, reasons, worst_d, worst_a, uncertified = [], 0, [], Counter(), 0.0, 0.0, 0
    for x in q:
        p, quat = frame_at(robot, d, x, body)
        r = Rotation.from_quat(quat[[1, 2, 3, 0]])
        target = p + r.as_matrix()[:, 2] * rng.uniform(0.05, 0.10)
        t0 = time.perf_counter()
        move = profrobot.plan_cartesian(robot, x, target, frame=frame)
        ms.append(time.perf_counter() - t0)
        if move.reached:
            reached += 1
        else:
            fractions.append(move.fraction)
            reasons[move.reason.split(" at ")[0].split(" near ")[0].split(" after ")[0]] += 1
        path = move.path
        if len(path) > 1 and not profrobot.certify_motions(robot, path[:-1], path[1:]).certified.all():
            uncertified += 1
        line = target - p
        for a, b in zip(path[:-1], path[1:]):
            pa, pb = frame_at(robot, d, a, body)[0], frame_at(robot, d, b, body)[0]
            steps = int(np.ceil(np.linalg.norm(pb - pa) / 1e-4)) + 2
            for y in profrobot.interpolate(robot, a, b, steps):
                pp, qq = frame_at(robot, d, y, body)
                u = np.clip((pp - p) @ line / (line @ line), 0, 1)
                worst_d = max(worst_d, float(np.linalg.norm(p + u * line - pp)))
                worst_a = max(worst_a, float((r.inv() * Rotation.from_quat(qq[[1, 2, 3, 0]])).magnitude()))
    return dict(scene=name, frame=frame, moves=len(q), reached=reached,
                fraction=float(np.median(fractions)) if fractions else np.nan, reasons=dict(reasons),
                deviation_mm=worst_d * 1e3, deviation_mrad=worst_a * 1e3, uncertified=uncertified,
                ms=float(np.median(ms) * 1e3), p95=float(np.percentile(ms, 95) * 1e3))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moves", type=int, default=100)
    ap.add_argument("--scenes", default=",".join(FRAMES))
    args = ap.parse_args(argv)
    rows = []
    for name in args.scenes.split(","):
        rows.append(run(name, args.moves))
        print(rows[-1], flush=True)
    load = os.getloadavg()[0]
    text = ("# Straight-line moves\n\n`python benches/cartesian.py`\n\n"
            f"Per arm, {args.moves} approach moves of 5-10 cm along the tool frame's z axis, orientation held, "
            f"from certified random poses; checked with MuJoCo's forward kinematics every 0.1 mm of the frame's "
            f"travel. Load average {load:.2f}.\n\n"
            "| scene | frame | moves | whole line | median fraction of the others | why they stop | largest deviation "
            "(mm, mrad) | paths not certified | ms per move (median, p95) |\n|---|---|---|---|---|---|---|---|---|\n"
            + "\n".join(f"| {r['scene']} | {r['frame']} | {r['moves']} | {r['reached']} | {r['fraction']:.2f} | "
                        f"{'; '.join(f'{k}: {v}' for k, v in r['reasons'].items())} | {r['deviation_mm']:.3f}, "
                        f"{r['deviation_mrad']:.2f} | {r['uncertified']} | {r['ms']:.2f}, {r['p95']:.2f} |" for r in rows)
            + "\n")
    write_results(RESULTS, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
