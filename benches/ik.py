"""Certified collision-free IK (``profrobot.ik``) against mink on the same targets, in the same run.

Targets are the frame poses (MuJoCo's FK) of certified free poses, so a collision-free answer
exists. Both solvers start from the same pose (the middle of the joint limits). mink: differential
IK (``mink.solve_ik`` with the daqp QP solver), a FrameTask on the frame, its ConfigurationLimit
and a CollisionAvoidanceLimit between every robot geom and every obstacle geom, integrated until
the error is within tolerance or ``--mink-iterations`` steps. A target counts as solved when the
frame is within 0.1 mm and 1 mrad (MuJoCo's FK) and the pose is certified free by the exact
labeller (no MuJoCo contact). cuRobo's published rate is printed as an anchor (GPU, not run here).

    python benches/ik.py [--targets 1000] [--mink-targets 200] [--scenes panda_blocks,ur5e_wall_box] [--motion 100]

Motion to a pose (``profrobot.plan_to_pose``): ``--motion`` start/target pairs on panda_blocks and
the UR5e scene, the targets the frame poses of the goals of ``problems.hard_pairs`` (the straight
path between them collides), timed end to end (IK candidates and the continuous-certified planner).

(pip install mink: the bench extra). Results: benches/ik_results.md (by hand, with the load).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import mujoco
import numpy as np

import profrobot
from profrobot.exact import problems

ARMS = {"panda_blocks": "hand", "ur5e_wall_box": "attachment_site", "xarm7_table": "link_tcp",
        "vx300s_clutter": "pinch", "panda_shelf": "hand"}
CUROBO_ANCHOR = "cuRobo (published, GPU): collision-free IK at over 7 000 queries/s"


def frame_poses(robot, frame, poses):
    m, d = robot.mj_model, mujoco.MjData(robot.mj_model)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, frame) >= 0
    out = np.tile(np.eye(4), (len(poses), 1, 1))
    for i, q in enumerate(poses):
        d.qpos[robot.qpos_adr] = q
        mujoco.mj_kinematics(m, d)
        x = d.site(frame) if site else d.body(frame)
        out[i, :3, :3], out[i, :3, 3] = x.xmat.reshape(3, 3), x.xpos
    return out


def solved(robot, frame, poses, targets, certified):
    """Within 0.1 mm and 1 mrad by MuJoCo's FK, certified free by the labeller."""
    got = frame_poses(robot, frame, poses)
    pe = np.linalg.norm(got[:, :3, 3] - targets[:, :3, 3], axis=1)
    rel = np.einsum("nji,njk->nik", targets[:, :3, :3], got[:, :3, :3])
    re = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))
    return (pe <= 1e-4) & (re <= 1e-3) & certified


def run_mink(robot, frame, targets, start, iterations: int):
    """mink from ``start`` to each target: (poses, seconds per target)."""
    import mink

    m = robot.mj_model
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, frame) >= 0
    robot_geoms = sorted({int(g) for g, s in zip(robot.pair_geoms[:, 0], robot.pair_is_self) if not s}
                         | {int(g) for g, s in zip(robot.pair_geoms[:, 1], robot.pair_is_self) if not s})
    static = {g for g in robot_geoms if m.body_weldid[m.geom_bodyid[g]] == 0}
    moving = [g for g in robot_geoms if g not in static]
    limits_ = [mink.ConfigurationLimit(m)]
    if moving and static:
        limits_.append(mink.CollisionAvoidanceLimit(m, [(moving, sorted(static))]))
    out = np.zeros((len(targets), robot.njoint))
    t0 = time.perf_counter()
    for i, t in enumerate(targets):
        cfg = mink.Configuration(m)
        q = m.qpos0.copy()
        q[robot.qpos_adr] = start
        cfg.update(q)
        task = mink.FrameTask(frame, "site" if site else "body", position_cost=1.0, orientation_cost=1.0, lm_damping=1e-6)
        task.set_target(mink.SE3.from_matrix(t))
        for _ in range(iterations):
            vel = mink.solve_ik(cfg, [task], 0.05, "daqp", damping=1e-3, limits=limits_)
            cfg.integrate_inplace(vel, 0.05)
            err = task.compute_error(cfg)
            if np.linalg.norm(err[:3]) <= 1e-5 and np.linalg.norm(err[3:]) <= 1e-4:
                break
        out[i] = cfg.q[robot.qpos_adr]
    return out, (time.perf_counter() - t0) / len(targets)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--targets", type=int, default=1000, help="targets per scene for profrobot.ik")
    p.add_argument("--mink-targets", type=int, default=200, help="of those, the first this many for mink too")
    p.add_argument("--mink-iterations", type=int, default=300, help="mink's integration steps per target at most")
    p.add_argument("--scenes", default=",".join(ARMS), help="comma-separated bundled arm scenes")
    p.add_argument("--no-mink", action="store_true", help="ours only")
    p.add_argument("--motion", type=int, default=100, help="start/target problems for plan_to_pose per scene (0: none)")
    args = p.parse_args(argv)
    warnings.simplefilter("ignore")
    print(f"load average {os.getloadavg()[0]:.2f} at the start; {CUROBO_ANCHOR}")
    print("| scene | ours: targets/s | ours solved | mink: targets/s | mink solved | ours on mink's targets | ratio |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenes.split(","):
        robot, frame = profrobot.scenes.load(name), ARMS[name]
        q = problems.free_poses(robot, 3 * args.targets, seed=11)
        q = q[profrobot.certify_poses(robot, q)][: args.targets]
        targets = frame_poses(robot, frame, q)
        start = robot.project(robot.joint_limits.mean(1))
        profrobot.ik(robot, targets[:8], frame=frame)               # warm (the likely-pairs cover)
        res = profrobot.ik(robot, targets, frame=frame, start=start)
        ours = solved(robot, frame, res.poses, targets, res.certified)
        ours_rate = len(targets) / res.seconds
        row = f"| {name} | {ours_rate:,.0f} | {ours.mean():.1%} | "
        if args.no_mink:
            print(row + "— | — | — | — |", flush=True)
            continue
        n = min(args.mink_targets, len(targets))
        mp, per = run_mink(robot, frame, targets[:n], start, args.mink_iterations)
        mink_ok = solved(robot, frame, mp, targets[:n], profrobot.certify_poses(robot, robot.project(mp)))
        sub = profrobot.ik(robot, targets[:n], frame=frame, start=start)
        print(row + f"{1 / per:,.0f} | {mink_ok.mean():.1%} | "
              f"{solved(robot, frame, sub.poses, targets[:n], sub.certified).mean():.1%} in {sub.seconds * 1e3:.0f} ms | "
              f"{ours_rate * per:,.0f}x |", flush=True)
    if args.motion:
        print("\n| scene | motion to a pose: certified | median ms | p90 ms | IK candidates tried (mean) |")
        print("|---|---|---|---|---|")
        for name in ("panda_blocks", "ur5e_wall_box"):
            robot, frame = profrobot.scenes.load(name), ARMS[name]
            starts, goals = problems.hard_pairs(robot, args.motion, seed=21)
            targets = frame_poses(robot, frame, goals)
            times, ok, cands = [], 0, []
            for a, t in zip(starts, targets):
                t0 = time.perf_counter()
                m = profrobot.plan_to_pose(robot, a, t, frame=frame)
                ok += bool(m.certified)
                if m.plan is not None:
                    cands.append(m.candidates)
                times.append(time.perf_counter() - t0)
            print(f"| {name} | {ok}/{len(starts)} | {1e3 * np.median(times):.2f} | {1e3 * np.percentile(times, 90):.2f} "
                  f"| {np.mean(cands):.2f} |", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
