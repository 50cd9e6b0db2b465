"""Layouts from depth (``profrobot.estimate_layout``): accuracy, time, and the closed loop.

For each family, ``--layouts`` held-out layouts δ (seeded uniform draws in the family's ranges
that ``family.at`` accepts) and a robot pose certified free there. MuJoCo renders the whole scene's
depth from two calibrated cameras (320 × 240, different intrinsics, off-centre principal
points), with the robot in view; noise σ = 2 mm + 0.5 % of depth (Gaussian, along z) and 5 % of
the pixels dropped (0). Reported:

- δ error per scene joint: slides in cm, hinges in degrees *modulo the obstacle's own symmetry*
  (a square block turned by 90° is the same block: the error is to the nearest equivalent angle);
  and the largest displacement of any point of an obstacle (mm), which is what a margin must
  cover, beside the suggested margin;
- seconds per layout (``estimate_layout`` alone, two cores, nothing else running);
- the closed loop (``--loop``): at each *estimated* layout with its suggested margin, 50 poses
  colliding there resolved (``resolve(sdf=None)``: the exact labeller's search) and 5 hard
  problems planned (``plan_path``); every answer must be certified, and MuJoCo at the **true**
  layout must find 0 contacts: resolved poses as they are, paths re-interpolated so that no
  joint moves more than 0.0005 rad between checked poses.

    python benches/layout.py [--families panda_blocks_moving,vx300s_clutter_moving] [--layouts 20] [--loop]

Results: benches/layout_results.md (by hand, with the load average).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import profrobot
from profrobot import scenes
from profrobot.exact import problems
from profrobot.exact.crosscheck import mujoco_labels
from profrobot.exact.labels import so2_steps
from profrobot.perception.layouts.fit import Placer, movable_obstacles
from profrobot.perception.layouts.depth import DEFAULT_GEOMGROUP
from profrobot.render import Cameras, render_depth

NOISE = (0.002, 0.005)
DROP = 0.05

# two calibrated cameras per family: (eye, target), intrinsics (fx, fy, cx, cy) at 320 × 240
CAMERAS = {
    "panda_blocks_moving": ([(1.55, -1.0, 1.25), (1.2, 1.25, 1.35)], [(0.4, 0.0, 0.25), (0.35, 0.05, 0.25)]),
    "vx300s_clutter_moving": ([(1.25, -0.85, 1.0), (0.95, 1.15, 1.1)], [(0.2, 0.05, 0.15), (0.2, 0.05, 0.15)]),
}
INTRINSICS = [(262.0, 263.5, 161.3, 118.2), (251.0, 250.2, 157.6, 121.9)]


def cameras_for(name: str) -> Cameras:
    eyes, targets = CAMERAS[name]
    K = np.array([[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] for fx, fy, cx, cy in INTRINSICS])
    return Cameras.look_at(eyes, targets, width=320, height=240, K=K)


def layouts(family, n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    lo, hi = family.joint_limits[family.scene_index].T
    out = []
    while len(out) < n:
        d = rng.uniform(lo, hi)
        try:
            family.at(d)
        except profrobot.InputError:
            continue
        out.append(d)
    return out


def noisy(depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    z = depth.astype(np.float64)
    seen = z > 0
    z = np.where(seen, z + rng.normal(size=z.shape) * (NOISE[0] + NOISE[1] * z), 0.0)
    z[rng.random(z.shape) < DROP] = 0.0
    return z


def yaw_period(ob, solid_frames) -> float | None:
    """The smallest rotation about world z (90° or 180°) that maps the obstacle onto itself, or
    None (no such symmetry below 360°)."""
    for period in (np.pi / 2, np.pi):
        Rz = np.array([[np.cos(period), -np.sin(period), 0], [np.sin(period), np.cos(period), 0], [0, 0, 1]])
        ok = True
        for s, (x, R) in zip(ob.solids, solid_frames):
            pts = s.extreme_points() @ R.T + x
            c = x
            rot = (pts - c) @ Rz.T + c
            if np.abs(s.sdf((rot - x) @ R)).max() > 1e-9 and s.kind != "sphere":
                ok = False
        if ok:
            return period
    return None


def errors(family, true: np.ndarray, est: np.ndarray, theta: np.ndarray):
    """(slide errors m, hinge errors rad modulo symmetry, per-obstacle max point displacement m)."""
    m = family.mj_model
    qpos = m.qpos0.copy()
    qpos[family.qpos_adr[family.robot_index]] = theta
    placer = Placer(m, qpos)
    slides, hinges, disp = [], [], {}
    for ob in movable_obstacles(family, np.asarray(DEFAULT_GEOMGROUP, np.uint8)):
        t, e = true[ob.joints], est[ob.joints]
        ft, _, _ = placer.frames(ob, t)
        fe, _, _ = placer.frames(ob, e)
        period = yaw_period(ob, ft)
        for k, ang in enumerate(ob.angular):
            if ang:
                err = abs(e[k] - t[k])
                if period is not None:
                    err = abs((e[k] - t[k] + period / 2) % period - period / 2)
                hinges.append(err)
            else:
                slides.append(abs(e[k] - t[k]))
        # how far the estimated surface is from the true one, up to the solid's symmetry: the
        # Hausdorff distance between the two surfaces (sampled), what a margin must cover
        worst = 0.0
        for s, (xt, Rt), (xe, Re) in zip(ob.solids, ft, fe):
            surf = s.surface_points(600)
            worst = max(worst, float(np.abs(s.sdf(((surf @ Rt.T + xt) - xe) @ Re)).max()),
                        float(np.abs(s.sdf(((surf @ Re.T + xe) - xt) @ Rt)).max()))
        disp[ob.name] = worst
    return np.array(slides), np.array(hinges), disp


def dense(robot, path: np.ndarray, step: float = 0.0005) -> np.ndarray:
    """``path`` re-interpolated (SO(2), the motion certified) so that no joint moves more than ``step``."""
    out = [path[:1]]
    for a, b, d in zip(path[:-1], path[1:], so2_steps(robot, path)):
        n = int(np.ceil(np.abs(d).max() / step)) + 1
        out.append(profrobot.interpolate(robot, a, b, max(n, 2))[1:])
    return np.concatenate(out)


def closed_loop(family, true_d, est, seed: int) -> dict:
    """resolve 50 colliding poses and plan 5 hard problems at the estimate with its margin;
    MuJoCo at the true layout."""
    at_est = family.at(est.scene)
    safe = at_est.with_margin(est.margin)
    at_true = family.at(true_d)
    out = dict(resolved=0, resolved_certified=0, resolve_contacts=0, plans=0, plans_certified=0, plan_contacts=0,
               plan_ms=[])
    poses = problems.colliding_poses(safe, 50, seed=seed)
    res = profrobot.resolve(None, poses, robot=at_est, margin=est.margin)
    out["resolved"] = len(poses)
    out["resolved_certified"] = int(res.certified.sum())
    lab = mujoco_labels(at_true, res.poses[res.certified], progress=False)
    out["resolve_contacts"] = int((np.asarray(lab.ncon) > 0).sum())
    starts, goals = problems.hard_pairs(safe, 5, seed=seed)
    for s, g in zip(starts, goals):
        r = profrobot.plan_path(at_est, s, g, margin=est.margin, seed=seed, max_time=10.0)
        out["plans"] += 1
        out["plan_ms"].append(r.seconds * 1e3)
        if not (r.found and r.certified):
            continue
        out["plans_certified"] += 1
        lab = mujoco_labels(at_true, dense(at_true, r.path), progress=False)
        out["plan_contacts"] += int((np.asarray(lab.ncon) > 0).sum())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="panda_blocks_moving,vx300s_clutter_moving")
    ap.add_argument("--layouts", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2025)
    ap.add_argument("--loop", action="store_true", help="the closed loop (resolve + plan at each estimate)")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}; threads {os.cpu_count()}")
    for name in args.families.split(","):
        family = scenes.load(name)
        cams = cameras_for(name)
        deltas = layouts(family, args.layouts, args.seed)
        robot_at = [family.at(d) for d in deltas]
        thetas = [profrobot.exact.problems.free_poses(r, 1, seed=args.seed + i)[0] for i, r in enumerate(robot_at)]
        full = np.stack([family.compose(t, d) for t, d in zip(thetas, deltas)])
        depth = render_depth(family, full, cams)
        S, H, R, T, M, worst_ratio = [], [], [], [], [], []
        loop_rows = []
        for i, (d, th) in enumerate(zip(deltas, thetas)):
            z = noisy(depth[i], np.random.default_rng(args.seed + 1000 + i))  # each layout its own noise
            t0 = time.perf_counter()
            est = profrobot.estimate_layout(family, z, cams, pose=th, depth_noise=NOISE)
            T.append(time.perf_counter() - t0)
            if not est.ok:
                print(f"  layout {i}: {est.unsupported}")
                continue
            s, h, disp = errors(family, d, est.scene, th)
            S.append(s)
            H.append(h)
            M.append(est.margin)
            worst = max(disp.values())
            R.append(worst)
            worst_ratio.append(worst / est.margin)
            print(f"  layout {i:2d}: {T[-1]:.2f} s, max slide err {s.max() * 100:.2f} cm, max yaw err "
                  f"{np.degrees(h.max()) if len(h) else 0:.2f}°, worst displacement {worst * 1000:.1f} mm, "
                  f"margin {est.margin * 1000:.1f} mm", flush=True)
            if args.loop:
                row = closed_loop(family, d, est, args.seed + i)
                loop_rows.append(row)
                print(f"     loop: resolve {row['resolved_certified']}/{row['resolved']} certified, "
                      f"{row['resolve_contacts']} MuJoCo contacts at the truth; plans {row['plans_certified']}/"
                      f"{row['plans']} certified, {row['plan_contacts']} contacts", flush=True)
        s, h = np.concatenate(S), np.degrees(np.concatenate(H)) if H and len(np.concatenate(H)) else np.zeros(1)
        print(f"{name}: {len(S)}/{len(deltas)} layouts estimated")
        print(f"  slide error: median {np.median(s) * 100:.2f} cm, p95 {np.percentile(s, 95) * 100:.2f} cm, "
              f"max {s.max() * 100:.2f} cm")
        print(f"  yaw error:   median {np.median(h):.2f}°, p95 {np.percentile(h, 95):.2f}°, max {h.max():.2f}°")
        print(f"  worst point displacement per layout: median {np.median(R) * 1000:.1f} mm, max {max(R) * 1000:.1f} mm; "
              f"margin median {np.median(M) * 1000:.1f} mm; displacement / margin max {max(worst_ratio):.2f}")
        print(f"  seconds per layout: median {np.median(T):.2f}, max {max(T):.2f}")
        if loop_rows:
            tot = {k: sum(r[k] for r in loop_rows) for k in loop_rows[0] if k != "plan_ms"}
            ms = [x for r in loop_rows for x in r["plan_ms"]]
            print(f"  closed loop: resolve {tot['resolved_certified']}/{tot['resolved']} certified, "
                  f"{tot['resolve_contacts']} contacts at the truth; plan {tot['plans_certified']}/{tot['plans']} "
                  f"certified, {tot['plan_contacts']} contacts at the truth (checked at 0.0005 rad); plan median "
                  f"{np.median(ms):.1f} ms")


if __name__ == "__main__":
    main()
