"""MotionBenchMaker (Chamzas et al., RA-L 2022) on the Menagerie Panda: profrobot's planner with
its defaults (every returned path proven free continuously) beside VAMP run in the same bench and
OMPL's RRT-Connect.

    python benches/mbm.py [--mbm ../shared/mbm] [--classes box,bookshelf_small,bookshelf_tall,table_pick]
                          [--problems 100] [--vamp ../vamp] [--ompl 10] [--ompl-time 10]

Each problem (``../shared/mbm/<class>_panda/sceneNNNN.yaml`` and ``requestNNNN.yaml``: MoveIt's
planning scene and request) becomes the Menagerie Panda (its ``panda`` entry: no floor; fingers open
at 0.04 m and held) with the scene's boxes and cylinders as obstacles, replacing the previous
problem's (``Robot.with_obstacles`` on one built Panda: no MuJoCo compile, ``robot/world.py``).
A problem is *valid* when its start and goal are within the Menagerie Panda's limits and free
with the certificate's clearance (``plan_path`` refuses it otherwise, naming why). Per problem:

- **scene**: the obstacles replaced (``with_obstacles``), milliseconds;
- **total**: ``plan_path``'s Python call, wall time, proof included, its first call on the new
  scene (so the proofs of the new robot–obstacle pairs made on first use are in it): the default
  two threads, and one thread on the same problem in a scene replaced again, the two calls in
  turns first (the second call on a problem finds its data warmer); **planning** and
  **simplification**: the planner's own split (``PathResult.seconds - shortcut_seconds`` and
  ``shortcut_seconds``);
- every returned path replayed in MuJoCo (``mj_kinematics`` + ``mj_collision``) with no joint
  moving more than 0.001 rad between replayed poses: contacts counted; the MuJoCo model compiled
  on first use (``robot.mj_model``), timed apart.

VAMP (``../shared/peers/vamp/build.sh DIR``, then ``--vamp DIR``; default ``../vamp`` beside the
repository) runs in its own venv on its own
copy of the same problems (``benches/vamp_mbm.py``: RRT-Connect, Halton, default settings, one
thread, as its ``evaluate_mbm.py``), its published figures otherwise. OMPL's RRT-Connect
(``pip install ".[bench]"``) with our exact labeller as its validity checker at 0.01 rad on the
first ``--ompl`` problems of each class. Markdown in ``benches/mbm_results.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import yaml

import profrobot
from profrobot import Box, Cylinder, Sphere
from profrobot.errors import InputError

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import load  # noqa: E402
from planning import ompl_plan  # noqa: E402
from results import write_results  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "mbm_results.md"

CLASSES = ("box", "bookshelf_small", "bookshelf_tall", "table_pick")
#: MoveIt's joint names for the Menagerie Panda's
JOINTS = {f"panda_joint{i}": f"joint{i}" for i in range(1, 8)}
FINGERS = ("finger_joint1", "finger_joint2")
OPEN = 0.04
#: the replay's step: no joint moves more than this between poses MuJoCo checks (rad)
REPLAY = 0.001
#: VAMP's published figures on all seven MBM classes (Ryzen 9 7950X, one core), microseconds
VAMP_PUBLISHED = dict(planning=35.0, total=99.0, total_p95=441.6)


def _quat(xyzw) -> tuple[float, float, float, float]:
    x, y, z, w = (float(v) for v in xyzw)
    return (w, x, y, z)


def read_scene(path: Path) -> list:
    """A MoveIt planning scene's collision objects as profrobot obstacles (boxes: full extents;
    cylinders: [height, radius]; spheres: [radius]; quaternions x, y, z, w)."""
    scene = yaml.safe_load(path.read_text())
    out = []
    for obj in scene["world"]["collision_objects"]:
        for k, (prim, pose) in enumerate(zip(obj.get("primitives", []), obj.get("primitive_poses", []))):
            pos, quat = tuple(map(float, pose["position"])), _quat(pose["orientation"])
            d = [float(v) for v in prim["dimensions"]]
            name = f"{obj['id']}_{k}" if k else obj["id"]
            if prim["type"] == "box":
                out.append(Box(pos=pos, quat=quat, name=name, half_size=(d[0] / 2, d[1] / 2, d[2] / 2)))
            elif prim["type"] == "cylinder":
                out.append(Cylinder(pos=pos, quat=quat, name=name, radius=d[1], half_length=d[0] / 2))
            elif prim["type"] == "sphere":
                out.append(Sphere(pos=pos, quat=quat, name=name, radius=d[0]))
            else:
                raise ValueError(f"{path}: primitive type {prim['type']!r} is not read here")
    return out


def read_request(path: Path, robot) -> tuple[np.ndarray, np.ndarray]:
    """(start, goal) in the robot's joint order: the arm's joints from the request, the fingers open."""
    req = yaml.safe_load(path.read_text())
    js = req["start_state"]["joint_state"]
    start = np.full(robot.njoint, OPEN)
    goal = np.full(robot.njoint, OPEN)
    index = {n: i for i, n in enumerate(robot.joint_names)}
    for name, v in zip(js["name"], js["position"]):
        if name in JOINTS:
            start[index[JOINTS[name]]] = float(v)
    for c in req["goal_constraints"][0]["joint_constraints"]:
        goal[index[JOINTS[c["joint_name"]]]] = float(c["position"])
    return start, goal


def replay(robot, path: np.ndarray) -> tuple[int, int]:
    """(poses with a MuJoCo contact, poses replayed): every segment of ``path`` at ``REPLAY``."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    bad = total = 0
    for a, b in zip(path[:-1], path[1:]):
        n = max(int(np.ceil(np.abs(b - a).max() / REPLAY)), 1) + 1
        for q in np.linspace(a, b, n)[1:] if total else np.linspace(a, b, n):
            d.qpos[robot.qpos_adr] = q
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
            bad += d.ncon > 0
            total += 1
    return bad, total


def ours(base, folder: Path, i: int) -> dict:
    """Problem ``i`` of a class folder with profrobot (see the module docs)."""
    obstacles = read_scene(folder / f"scene{i:04d}.yaml")
    t = time.perf_counter()
    robot = base.with_obstacles(obstacles)
    scene_s = time.perf_counter() - t
    start, goal = read_request(folder / f"request{i:04d}.yaml", robot)
    row = dict(index=i, scene_s=scene_s, valid=bool(robot.feasible(np.stack([start, goal])).all()))
    if not row["valid"]:
        row["why"] = "outside the Menagerie Panda's limits"
        return row
    # The default call and the one-thread call each on a new scene (each its scene's first
    # call), in turns first: the second of two calls on the same problem finds its data warmer
    # (caches, the allocator's pages), which always favoured the one-thread figure.
    again = base.with_obstacles(obstacles)
    calls = [(robot, None, "total_s"), (again, 1, "total_1_s")]
    out = {}
    for on, threads, key in calls if i % 2 == 0 else calls[::-1]:
        try:
            t = time.perf_counter()
            out[key] = profrobot.plan_path(on, start, goal, locked=FINGERS, seed=i, threads=threads)
            row[key] = time.perf_counter() - t
        except InputError as e:
            row.update(valid=False, why=str(e).split(";")[0])
            return row
    r, r1 = out["total_s"], out["total_1_s"]
    row.update(solved=r.found, certified=r.certified, planning_s=r.seconds - r.shortcut_seconds,
               simplification_s=r.shortcut_seconds, waypoints=len(r.path), same_1=bool(np.array_equal(r.path, r1.path)))
    if r.found:
        t = time.perf_counter()
        assert robot.mj_model is not None   # compiled here, on first use
        row["compile_s"] = time.perf_counter() - t
        row["contacts"], row["replayed"] = replay(robot, r.path)
    return row


def ompl_row(base, folder: Path, i: int, max_time: float) -> dict:
    """Problem ``i`` with OMPL's RRT-Connect (``benches/planning.py``'s, our labeller at 0.01 rad)."""
    robot = base.with_obstacles(read_scene(folder / f"scene{i:04d}.yaml"))
    start, goal = read_request(folder / f"request{i:04d}.yaml", robot)
    lab = profrobot.label_poses(robot, np.stack([start, goal])).collides
    if not robot.feasible(np.stack([start, goal])).all() or lab.any():
        return dict(valid=False)
    r = ompl_plan(robot, start, goal, 0.01, max_time, seed=i)
    return dict(valid=True, solved=r["found"], seconds=r["seconds"])


def pct(values, unit: float = 1e3) -> str:
    """p25 / p50 / p95 / max of ``values`` (seconds) in ms (``unit`` 1e3) or µs (1e6)."""
    v = np.asarray([x for x in values if x == x], dtype=float) * unit
    if not len(v):
        return "–"
    return " / ".join(f"{x:.3g}" for x in (*np.percentile(v, [25, 50, 95]), v.max()))


def vamp_rows(vamp_dir: Path, classes, n: int) -> dict | None:
    python = vamp_dir / "venv" / "bin" / "python"
    dataset = vamp_dir / "vamp" / "resources" / "panda" / "problems.pkl"
    if not (python.exists() and dataset.exists()):
        return None
    out = subprocess.run([str(python), str(Path(__file__).with_name("vamp_mbm.py")), str(dataset), ",".join(classes),
                          str(n)], check=True, capture_output=True, text=True).stdout
    return json.loads(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    here = Path(__file__).resolve().parent
    ap.add_argument("--mbm", type=Path, default=here.parent.parent / "shared" / "mbm")
    ap.add_argument("--classes", default=",".join(CLASSES))
    ap.add_argument("--problems", type=int, default=100)
    ap.add_argument("--vamp", type=Path, default=here.parent.parent / "vamp",
                    help="where ../shared/peers/vamp/build.sh DIR built VAMP (default: ../vamp beside the repository)")
    ap.add_argument("--ompl", type=int, default=10, help="problems per class for OMPL (0: none)")
    ap.add_argument("--ompl-time", type=float, default=10.0)
    args = ap.parse_args()
    classes = args.classes.split(",")
    print("load before:", load(), flush=True)
    base = profrobot.Robot.from_menagerie("franka_emika_panda", "panda")
    rows: dict[str, list[dict]] = {}
    for c in classes:
        folder = args.mbm / f"{c}_panda"
        rows[c] = [ours(base, folder, i) for i in range(1, args.problems + 1)]
        done = [r for r in rows[c] if r["valid"]]
        print(c, f"valid {len(done)}/{len(rows[c])}, solved {sum(r['solved'] for r in done)}, total ms",
              pct([r["total_s"] for r in done]), flush=True)
    vamp = vamp_rows(args.vamp, classes, args.problems)
    ompl = {}
    if args.ompl:
        try:
            import ompl as _ompl  # noqa: F401
            for c in classes:
                ompl[c] = [ompl_row(base, args.mbm / f"{c}_panda", i, args.ompl_time) for i in range(1, args.ompl + 1)]
        except ImportError:
            print("OMPL not installed (pip install '.[bench]'): not run")
    print("load after:", load(), flush=True)
    md = markdown(rows, vamp, ompl, args)
    write_results(RESULTS, md)
    print(md)


def markdown(rows: dict, vamp: dict | None, ompl: dict, args) -> str:
    lines = ["# MotionBenchMaker beside VAMP and OMPL", "",
             f"`python benches/mbm.py --problems {args.problems} --ompl {args.ompl}`. Load average {load()} after the run; "
             "times p25 / p50 / p95 / max. The Menagerie Panda (fingers open, held), each problem's scene replacing "
             "the previous one's on one built robot; every returned path proven continuously by the planner "
             "and replayed in MuJoCo at 0.001 rad.",
             "", "| class | valid | solved | certified | MuJoCo contacts (poses) | scene update ms | planning ms | "
             "simplification ms | total ms (2 threads) | total ms (1 thread) | same path 1 thread |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    every = [r for c in rows for r in rows[c]]
    for c, rs in list(rows.items()) + [("all", every)]:
        ok = [r for r in rs if r["valid"]]
        solved = [r for r in ok if r.get("solved")]
        lines.append(f"| {c} | {len(ok)}/{len(rs)} | {len(solved)} | {sum(r['certified'] for r in solved)} | "
                     f"{sum(r['contacts'] for r in solved)} ({sum(r['replayed'] for r in solved)}) | "
                     f"{pct([r['scene_s'] for r in rs])} | {pct([r['planning_s'] for r in ok])} | "
                     f"{pct([r['simplification_s'] for r in ok])} | {pct([r['total_s'] for r in ok])} | "
                     f"{pct([r['total_1_s'] for r in ok])} | {sum(r['same_1'] for r in ok)}/{len(ok)} |")
    compile_s = [r["compile_s"] for r in every if "compile_s" in r]
    lines += ["", "The first scene update of a run also reads the robot's files once and proves its own pairs once "
              "(the largest figure); later ones share both. Total: the Python call's wall time; VAMP's: its own "
              "planning and simplification clocks.", "",
              f"MuJoCo model compiled for the replays (lazily, after the scene update): {pct(compile_s)} ms.", ""]
    why = {}
    for r in every:
        if not r["valid"]:
            why[r["why"]] = why.get(r["why"], 0) + 1
    lines += [f"- invalid ({n}): {w}" for w, n in sorted(why.items(), key=lambda x: -x[1])]
    if vamp:
        lines += ["", "VAMP in the same run (one thread; µs):", "",
                  "| class | valid | solved | scene µs | planning µs | simplification µs | total µs | ours / VAMP p50 | ours / VAMP p95 |",
                  "|---|---|---|---|---|---|---|---|---|"]
        allv = [r for c in vamp for r in vamp[c]]
        for c, vs in list(vamp.items()) + [("all", allv)]:
            ok = [r for r in vs if r["valid"]]
            tot = [(r["planning_ns"] + r["simplification_ns"]) * 1e-9 for r in ok if r["solved"]]
            mine = [r["total_s"] for r in (every if c == "all" else rows[c]) if r["valid"]]
            lines.append(f"| {c} | {len(ok)}/{len(vs)} | {sum(r['solved'] for r in ok)} | "
                         f"{pct([r['scene_ns'] * 1e-9 for r in ok], 1e6)} | {pct([r['planning_ns'] * 1e-9 for r in ok], 1e6)} | "
                         f"{pct([r['simplification_ns'] * 1e-9 for r in ok], 1e6)} | {pct(tot, 1e6)} | "
                         f"{np.median(mine) / np.median(tot):.0f}× | "
                         f"{np.percentile(mine, 95) / np.percentile(tot, 95):.0f}× |")
    else:
        lines += ["", f"VAMP not built here: its published figures {VAMP_PUBLISHED} (µs)."]
    if ompl:
        lines += ["", f"OMPL RRT-Connect (our labeller at 0.01 rad, {args.ompl_time} s budget), first {args.ompl} problems:", "",
                  "| class | valid | solved | total ms |", "|---|---|---|---|"]
        for c, os_ in ompl.items():
            ok = [r for r in os_ if r["valid"]]
            lines.append(f"| {c} | {len(ok)}/{len(os_)} | {sum(r['solved'] for r in ok)} | {pct([r['seconds'] for r in ok])} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
