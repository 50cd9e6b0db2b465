"""The pick-and-place beside mplib (the ManiSkill planner: OMPL + FCL, screw motions, TOPP-RA),
on one URDF arm both load: pybullet_data's Panda.

    python benches/pick_place_peers.py --mplib-python /path/to/mplib-venv/bin/python

mplib needs numpy < 2, so it runs in its own venv (``pip install "numpy<2" mplib pybullet``)
through ``benches/mplib_stages.py``; pybullet_data's collision meshes are re-exported first
(trimesh) because mplib's loader refuses them, and both planners get the re-exported ones.
The stages (``benches/pick_place_scene.py``): pre-grasp, approach 8 cm down, close (attach),
lift 10 cm, carry over a wall, place, open (detach), retreat. Ours: ``plan_to_pose``,
``plan_cartesian``, ``Robot.attach`` / ``detach``, ``time_path``; mplib: ``plan_pose``,
``plan_screw``, ``update_attached_object`` / ``detach_object``, its TOPP-RA. Each planner's
executed motion is replayed in MuJoCo at 1 kHz (the mug held where each planner grasped it) and
every sample's contacts counted. Reported: stages solved, planning time, trajectory duration,
samples in contact. Markdown in ``benches/pick_place_peers_results.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import profrobot
from profrobot import Box, Cylinder

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pick_place_scene import (ARM_A, ARM_V, DOWN_QUAT, HOME, MUG, PICK, PLACE, STAGES, TABLE, TCP, WALL,  # noqa: E402
                              grasp_z)
from results import write_results  # noqa: E402

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "pick_place_peers_results.md"


def clean_urdf(mplib_python: str, folder: Path) -> Path:
    """pybullet_data's Panda with its collision meshes re-exported as STL and no visuals."""
    import trimesh
    data = subprocess.run([mplib_python, "-c", "import pybullet_data; print(pybullet_data.getDataPath())"],
                          check=True, capture_output=True, text=True).stdout.strip()
    src = Path(data) / "franka_panda"
    text = (src / "panda.urdf").read_text()
    text = re.sub(r"<visual>.*?</visual>", "", text, flags=re.S)
    for mesh in sorted(set(re.findall(r'package://(meshes/collision/[\w.]+)', text))):
        out = folder / (Path(mesh).stem + ".stl")
        trimesh.load(src / mesh, force="mesh").export(out)
        text = text.replace(f"package://{mesh}", out.name)          # (relative: both loaders read it so)
    urdf = folder / "panda.urdf"
    urdf.write_text(text)
    return urdf


def world(urdf: Path) -> profrobot.Robot:
    centre, radius, half = MUG
    arm = profrobot.Robot.from_urdf(urdf)
    return arm.with_obstacles([Box(pos=TABLE[0], half_size=TABLE[1], name="table"),
                               Box(pos=WALL[0], half_size=WALL[1], name="wall"),
                               Cylinder(pos=centre, radius=radius, half_length=half, name="mug")])


def _target(xy, z) -> np.ndarray:
    t = np.eye(4)
    w, x, y, zq = DOWN_QUAT
    t[:3, :3] = np.array([[1 - 2 * (y * y + zq * zq), 2 * (x * y - zq * w), 2 * (x * zq + y * w)],
                          [2 * (x * y + zq * w), 1 - 2 * (x * x + zq * zq), 2 * (y * zq - x * w)],
                          [2 * (x * zq - y * w), 2 * (y * zq + x * w), 1 - 2 * (x * x + y * y)]])
    t[:3, 3] = (xy[0], xy[1], z)
    return t


def ours(robot: profrobot.Robot) -> list[dict]:
    fingers = [n for n in robot.joint_names if "finger" in n]
    arm = [j for j, n in enumerate(robot.joint_names) if n not in fingers]
    v = np.full(robot.njoint, 0.2)
    a = np.full(robot.njoint, 0.5)
    v[arm], a[arm] = ARM_V, ARM_A
    tool = (0.0, 0.0, TCP)
    z = grasp_z()
    q = np.array(HOME, dtype=float)
    stages, held = [], robot
    for name in STAGES:
        t0 = time.perf_counter()
        if name in ("pre-grasp", "carry"):
            xy, dz = (PICK, 0.08) if name == "pre-grasp" else (PLACE, 0.10)
            m = profrobot.plan_to_pose(held, q, _target(xy, z + dz), frame="panda_hand", tool=tool, free_axis="z",
                                       locked=fingers)
            path = m.path if m.outcome == "certified" else None
        elif name in ("approach", "lift", "place", "retreat"):
            dz = {"approach": -0.08, "lift": 0.10, "place": -0.10, "retreat": 0.08}[name]
            xpos, xquat = held.core.forward_kinematics(q[None])
            b = held.mj_model.body("panda_hand").id
            from scipy.spatial.transform import Rotation
            tip = xpos[0, b] + Rotation.from_quat(xquat[0, b][[1, 2, 3, 0]]).apply(tool)
            c = profrobot.plan_cartesian(held, q, tip + [0.0, 0.0, dz], frame="panda_hand", tool=tool, locked=fingers)
            path = c.path if c.reached else None
        else:
            if name == "close":
                held = robot.attach("mug", to="panda_hand", at=q)
            value = MUG[1] - 0.001 if name == "close" else 0.04
            goal = q.copy()
            goal[[robot.joint_names.index(n) for n in fingers]] = value
            path = np.stack([q, goal])
        if path is None:
            stages.append(dict(name=name, success=False, seconds=time.perf_counter() - t0))
            break
        timed = profrobot.time_path(held, path, velocity=v, acceleration=a)
        seconds = time.perf_counter() - t0
        stages.append(dict(name=name, success=timed.certified, seconds=seconds, duration=timed.duration,
                           robot=held, samples=timed.at_rate(1000)[1]))
        q = np.asarray(path)[-1]
        if name == "open":
            held = held.detach("mug", at=q)
    return stages


def replay_mplib(robot: profrobot.Robot, stages: list[dict]) -> list[dict]:
    """mplib's stages as joint samples at 1 kHz on our robot (the mug held where mplib grasped it)."""
    q = np.array(HOME, dtype=float)
    held = robot
    fingers = [j for j, n in enumerate(robot.joint_names) if "finger" in n]
    out = []
    for st in stages:
        if st["name"] == "close":
            held = robot.attach("mug", to="panda_hand", at=q)
        q[fingers] = st["fingers"]
        if st["position"]:
            t = np.asarray(st["time"])
            pos = np.asarray(st["position"])
            tt = np.arange(0.0, t[-1], 1e-3)
            samples = np.repeat(q[None], len(tt), axis=0)
            for j in range(7):
                samples[:, j] = np.interp(tt, t, pos[:, j])
            q[:7] = pos[-1]
        else:
            samples = q[None].copy()
        out.append(dict(st, robot=held, samples=samples))
        if st["name"] == "open":
            held = held.detach("mug", at=q)
    return out


def contacts(stages: list[dict]) -> tuple[int, int]:
    hit = total = 0
    for st in stages:
        if "samples" in st and len(st["samples"]):
            hit += int(profrobot.mujoco_labels(st["robot"], st["samples"], progress=False).collides.sum())
            total += len(st["samples"])
    return hit, total


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mplib-python", required=True, help="the python of a venv with mplib (numpy < 2)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        urdf = clean_urdf(args.mplib_python, Path(tmp))
        robot = world(urdf)
        mine = ours(robot)
        out = Path(tmp) / "mplib.json"
        subprocess.run([args.mplib_python, str(HERE / "mplib_stages.py"), str(urdf), str(out)], check=True)
        theirs = replay_mplib(robot, json.loads(out.read_text()))
    rows = []
    for label, stages in (("profrobot", mine), ("mplib", theirs)):
        hit, total = contacts(stages)
        solved = sum(bool(s["success"]) for s in stages)
        rows.append(f"| {label} | {solved} / {len(STAGES)} | {sum(s['seconds'] for s in stages) * 1e3:.0f} | "
                    f"{sum(s.get('duration') or 0.0 for s in stages):.2f} | {hit} of {total} | "
                    + ", ".join(f"{s['name']} {s['seconds'] * 1e3:.0f} ms / {s.get('duration') or 0.0:.2f} s" for s in stages) + " |")
    text = ("# Pick-and-place beside mplib\n\n`python benches/pick_place_peers.py --mplib-python ...`\n\n"
            f"pybullet_data's Panda, the scene of `benches/pick_place_scene.py`; load average "
            f"{os.getloadavg()[0]:.2f}.\n\n"
            "| planner | stages solved | planning ms (total) | trajectory s (total) | 1 kHz samples in contact "
            "(MuJoCo) | per stage |\n|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n")
    write_results(RESULTS, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
