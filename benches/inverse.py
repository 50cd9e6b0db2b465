"""The paper's image-space inverse problems, measured its way and past it (issue 11).

    python benches/inverse.py t7 | t8 | t9 | video [--instances N] [--out benches/out/inverse]

``t7`` (Table 7, pose from images): Panda with blocks beside it (``panda_blocks``); 4 cameras at
128^2; targets are MuJoCo renders of the robot alone (the blocks are *not* in the images).
Target poses are rejection-sampled by MuJoCo's contact count into the paper's four groups
(any ncon > 0, exactly 2, exactly 1, 0); start = target + 0.1 U[0, 1) per joint. Baseline
(Dr. Robot): the image loss only (coarse to fine, as ``benches/render.py``). Ours: from the
baseline's result, the field phase (+ beta ReLU(g - l_thres), stopping once g <= l_thres), then
certify-and-continue. Reported per group: the share of results that collide (MuJoCo's ncon > 0,
the paper's metric, and our labeller), before and after certification, beside the paper's
numbers; median per-joint |dtheta| to the target and end-effector error (the paper reports
neither); a PNG per group (MuJoCo renders with the blocks: target | baseline | ours, collisions
framed red). ``--instances 100`` is the paper's full run; the default is what fits a CPU session.

``--executor ray [--address ADDR --workers N]`` runs the four rows as tasks on a Ray cluster
(:class:`profrobot.executors.RayExecutor`), with identical results.

``t9`` (Table 9, a pose from a goal): Shadow Hand, one camera looking down (0.4 m, look-at
(0.15, 0, 0)); frozen scorer; 200 Adam steps from the zero pose (``--runs`` runs, perturbed by
0.05 rad), without and then with 10 ReLU(g - l_thres); mean/std score and the share of results
that collide (MuJoCo and our labeller; with the field also after certify-and-resolve).
``--scorer image-goal`` (default; no CLIP weights can be downloaded here): the goal is a MuJoCo
render of the Menagerie keyframe ``--keyframe`` ("two finger pinch", the nearest to the paper's
"OK gesture"), score = −MSE at 64^2; ``--scorer clip --clip PATH`` runs the paper's prompt with a
local CLIP checkpoint. The table names its scorer.

Models are cached: the Gaussian Panda from ``benches/render.py`` (fitted there if missing), a
Gaussian Shadow Hand fitted here, and the fields from ``benches/fields.py``.

``t8`` (Table 8): start and end poses free (ncon == 0); from the start, one pose optimised against
the end pose's 4 views (Adam lr 0.05, + 10 |theta - theta_end|_1), every iterate a frame;
baseline vs the field at each ``--l-thres-list`` (+5 ReLU(g - l_thres), then the frames smoothed
on the field, certified, planner fallback). Every frame and every dense segment is scored (the
paper scored the last iterate). ``video``: a 60-frame, 3-camera MuJoCo video of a certified-free
path (our planner), recovered by ``actions_from_video`` with and without the field: median joint
error, colliding frames and segments, seconds per frame; a GIF of the recovered path.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

import profrobot  # noqa: E402
import profrobot.exact.certification  # noqa: E402
from profrobot import scenes  # noqa: E402
from profrobot.exact.crosscheck import mujoco_labels  # noqa: E402
from profrobot.inverse import pose_from_images  # noqa: E402
from profrobot.render import GaussianRobot, make_views, ring_cameras  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
PAPER_T7 = {"any": (78, 9), "2": (86, 2), "1": (78, 2), "0": (2, 0)}   # % colliding: Dr. Robot, ours
GROUPS = {"any": lambda n: n > 0, "2": lambda n: n == 2, "1": lambda n: n == 1, "0": lambda n: n == 0}


def _bench(name):
    spec = importlib.util.spec_from_file_location(name, os.path.join(HERE, f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def gaussian_panda(robot_img):
    path = os.path.join(HERE, "out", "render", "panda_10000_600.safetensors")
    if not os.path.exists(path):
        print("fitting the Gaussian Panda (benches/render.py) ...", flush=True)
        _bench("render").main(["--skip-pose", "--skip-speed"])
    return GaussianRobot.load(path, robot_img)


def group_targets(scene, group, n, seed, batch=20_000):
    """``n`` uniform poses whose MuJoCo contact count is in ``group`` (seeded), and those counts."""
    keep, ncon = [], []
    for r in range(1000):
        q = profrobot.sample_poses(scene, batch, seed=seed * 1000 + r)
        # our labeller first (cheap), MuJoCo's count on the candidates
        lab = profrobot.label_poses(scene, q).collides
        cand = q[lab] if group != "0" else q[~lab]
        cand = cand[: 40 * n]
        c = mujoco_labels(scene, cand).ncon
        ok = np.array([GROUPS[group](x) for x in c], dtype=bool)
        keep.append(cand[ok])
        ncon.append(c[ok])
        if sum(len(k) for k in keep) >= n:
            break
    return np.concatenate(keep)[:n], np.concatenate(ncon)[:n]


def ee_error(scene, a, b):
    """End-effector (the Panda's hand body) position error in metres."""
    import mujoco

    m = scene.mj_model
    hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "hand")
    d = mujoco.MjData(m)
    out = []
    for qa, qb in zip(a, b):
        pos = []
        for q in (qa, qb):
            d.qpos[:] = m.qpos0
            d.qpos[scene.qpos_adr] = q
            mujoco.mj_kinematics(m, d)
            pos.append(d.xpos[hand].copy())
        out.append(np.linalg.norm(pos[0] - pos[1]))
    return np.array(out)


PANDA_VIEW = dict(lookat=(0.25, 0.0, 0.35), distance=2.0, azimuth=60.0, elevation=-25.0)


def picture(scene, path, target, base, ours, base_col, ours_col, camera=None):
    """MuJoCo renders (with the scene's obstacles) of target | baseline | ours, collisions framed red."""
    from profrobot.optim.pictures import trajectory_frames
    from profrobot.render.image import write_png

    frames = trajectory_frames(scene, np.stack([target, base, ours]), np.array([False, base_col, ours_col]),
                               (320, 240), camera or PANDA_VIEW)
    write_png(path, np.concatenate([np.asarray(f.convert("RGB")) for f in frames], axis=1))


def t7_cameras(n: int = 4):
    """The pose benchmarks' ring: ``n`` cameras at 128^2, 1.5 m from the Panda's middle."""
    return ring_cameras(n, size=128, distance=1.5, elevation=-25.0, azimuth0=45.0, lookat=(0.0, 0.0, 0.45))


_MODELS: dict = {}


def _t7_models():
    """The image robot, the Gaussian Panda and the Panda-blocks field, loaded once per process
    (a plain dict, not functools.lru_cache: Ray pickles this script's functions by value, and an
    lru_cache wrapper would be looked up by name on the worker, where it does not exist)."""
    if "m" not in _MODELS:
        robot_img = profrobot.Robot.from_menagerie("franka_emika_panda")
        _MODELS["m"] = robot_img, gaussian_panda(robot_img), _bench("fields").field("panda_blocks")
    return _MODELS["m"]


def t7_group(scene, group: str, gi: int, o: dict):
    """One row of Table 7 (runs here, or on a Ray actor that holds ``scene``): the row and the
    poses for its picture."""
    t0 = time.perf_counter()
    robot_img, model, sdf = _t7_models()
    cams = t7_cameras()
    arm = np.array([t == "hinge" for t in scene.joint_types])
    lim = scene.joint_limits
    target, ncon = group_targets(scene, group, o["instances"], o["seed"] + gi)
    views = make_views(robot_img, target, cams, progress=False)
    rng = np.random.default_rng(o["seed"] + gi)
    start = np.clip(target + 0.1 * rng.random(target.shape), lim[:, 0], lim[:, 1])
    tg = dict(rgb=views.rgb, depth=views.depth, mask=views.mask)
    base = pose_from_images(model, tg, cams, init=start, robot=scene, image_iterations=o["refine_iters"], lr=0.005, w_depth=10.0,
                            coarse=dict(iterations=o["iters"], lr=0.02, w_depth=1.0), background=views.background)
    ours = pose_from_images(model, tg, cams, init=base.poses, sdf=sdf, image_iterations=0, beta=o["beta"], l_thres=o["l_thres"],
                            field_iterations=o["field_iters"], background=views.background)
    mj = lambda q: mujoco_labels(scene, q).ncon > 0
    err = lambda q: np.median(np.abs(q - target)[:, arm])
    r = dict(group=group, n=len(target), target_ncon_mean=float(ncon.mean()),
             baseline_mujoco_collide_pct=100 * float(mj(base.poses).mean()),
             baseline_ours_collide_pct=100 * float((~base.certified).mean()),
             field_before_certify_pct=100 * float((~ours.certified_before_continue).mean()),
             field_before_certify_mujoco_pct=100 * float(mj(ours.poses_before_continue).mean()),
             field_after_certify_pct=100 * float((~ours.certified).mean()),
             field_after_certify_mujoco_pct=100 * float(mj(ours.poses).mean()),
             paper_dr_robot_pct=PAPER_T7[group][0], paper_ours_pct=PAPER_T7[group][1],
             baseline_median_joint_err_rad=float(err(base.poses)), field_median_joint_err_rad=float(err(ours.poses)),
             baseline_ee_err_m=float(np.median(ee_error(scene, base.poses, target))),
             field_ee_err_m=float(np.median(ee_error(scene, ours.poses, target))),
             field_mean_steps=float(ours.iterations.mean()), refinement_rounds=ours.rounds,
             seconds=time.perf_counter() - t0)
    k = int(np.argmax(~base.certified)) if (~base.certified).any() else 0
    return r, (target[k], base.poses[k], ours.poses[k], bool(not base.certified[k]), bool(not ours.certified[k]))


def t7(a):
    out = os.path.join(a.out, "t7")
    os.makedirs(out, exist_ok=True)
    scene = scenes.panda_blocks()
    _t7_models()                                   # fit / train what is missing, once, here
    o = dict(instances=a.instances, seed=a.seed, iters=a.iters, refine_iters=a.refine_iters, beta=a.beta,
             l_thres=a.l_thres, field_iters=a.field_iters)
    res = dict(instances=a.instances, loadavg_start=os.getloadavg(), executor=a.executor)
    items = [(group, gi, o) for gi, group in enumerate(GROUPS)]
    if a.executor == "ray":
        # one row per task on long-lived actors holding the scene; the cached models are read
        # from benches/out on the worker's machine (copy them there on a real cluster)
        from profrobot.executors import RayExecutor

        ex = RayExecutor(a.address, workers=a.workers)
        _MODELS.clear()          # t7_group travels by value with this dict: empty, not holding MjSpecs
        try:
            done = ex.map(t7_group, items, robot=scene, desc="Table 7 rows")
        finally:
            ex.shutdown()
    else:
        from profrobot.executors import LocalExecutor

        done = LocalExecutor().map(t7_group, items, robot=scene, desc="Table 7 rows")   # here, in order
    rows = []
    for (group, _, _), (r, pic) in zip(items, done):
        rows.append(r)
        print(json.dumps(r), flush=True)
        picture(scene, os.path.join(out, f"t7_{group}.png"), *pic)
    res["rows"], res["loadavg_end"] = rows, os.getloadavg()
    json.dump(res, open(os.path.join(out, "t7.json"), "w"), indent=1)
    lines = ["| targets (MuJoCo contacts) | n | Dr. Robot, paper | baseline (ours, MuJoCo) | field, paper | field before certify (MuJoCo / labeller with clearance) | field after certify (labeller / MuJoCo) | median |Δθ| base / field (rad) | EE error base / field (mm) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['group']} (mean {r['target_ncon_mean']:.2f}) | {r['n']} | {r['paper_dr_robot_pct']} % | "
                     f"{r['baseline_mujoco_collide_pct']:.0f} % | {r['paper_ours_pct']} % | "
                     f"{r['field_before_certify_mujoco_pct']:.0f} % / {r['field_before_certify_pct']:.0f} % | "
                     f"{r['field_after_certify_pct']:.0f} % / {r['field_after_certify_mujoco_pct']:.0f} % | "
                     f"{r['baseline_median_joint_err_rad']:.4f} / {r['field_median_joint_err_rad']:.4f} | "
                     f"{1e3 * r['baseline_ee_err_m']:.1f} / {1e3 * r['field_ee_err_m']:.1f} |")
    with open(os.path.join(out, "t7.md"), "w") as f:
        f.write(f"# Table 7: pose from 4 views, Panda with blocks ({a.instances} instances per row; the paper: 100)\n\n"
                + "\n".join(lines) + f"\n\nload average {res['loadavg_start']} -> {res['loadavg_end']}\n")
    print("\n".join(lines))


def t8(a):
    """Table 8: trajectories from images, baseline vs the field at each --l-thres."""
    from profrobot.inverse import trajectory_from_images

    out = os.path.join(a.out, "t8")
    os.makedirs(out, exist_ok=True)
    scene = scenes.panda_blocks()
    robot_img, model, sdf = _t7_models()
    cams = t7_cameras()
    ends, _ = group_targets(scene, "0", 2 * a.instances, a.seed + 100)          # ncon == 0, as the paper
    starts, goals = ends[: a.instances], ends[a.instances:]
    views = make_views(robot_img, goals, cams, progress=False)
    settings = [("baseline (no field)", None, None)] + [(f"field, l_thres {t}", sdf, t) for t in a.l_thres_list]
    rows, res = [], dict(instances=a.instances, steps=a.steps, loadavg_start=os.getloadavg())
    for label, field, thr in settings:
        t0 = time.perf_counter()
        bad_frames = bad_any = 0
        for i in range(a.instances):
            tg = dict(rgb=views.rgb[i], depth=views.depth[i], mask=views.mask[i])
            kw = dict(robot=scene) if field is None else dict(sdf=field, l_thres=thr, beta=5.0)
            r = trajectory_from_images(model, tg, cams, start=starts[i], goal=goals[i], steps=a.steps, lr=0.05, w_pull=10.0,
                                       background=views.background, **kw)
            bad_frames += int(r.waypoint_uncertified.any())
            bad_any += int(not r.certified)
            if i == 0:
                from profrobot.optim.pictures import render_trajectory

                render_trajectory(scene, r.path, os.path.join(out, f"t8_{label.split(',')[0].split(' ')[0]}"
                                                                   f"{'' if thr is None else thr}.gif"),
                                  collides=r.waypoint_uncertified, camera=PANDA_VIEW, size=(320, 240))
        row = dict(setting=label, trajectories=a.instances, with_colliding_frame_pct=100 * bad_frames / a.instances,
                   with_colliding_frame_or_segment_pct=100 * bad_any / a.instances,
                   seconds_per_trajectory=(time.perf_counter() - t0) / a.instances)
        rows.append(row)
        print(json.dumps(row), flush=True)
    res["rows"], res["loadavg_end"] = rows, os.getloadavg()
    json.dump(res, open(os.path.join(out, "t8.json"), "w"), indent=1)
    lines = [f"# Table 8: trajectories from images, Panda with blocks ({a.instances} trajectories of {a.steps} frames "
             "per row; every frame and a 10x denser sampling of every segment scored)", "",
             "| setting | with a colliding frame | with a colliding frame or segment | s / trajectory |", "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['setting']} | {r['with_colliding_frame_pct']:.0f} % | "
                     f"{r['with_colliding_frame_or_segment_pct']:.0f} % | {r['seconds_per_trajectory']:.1f} |")
    lines.append("\nPaper: 10.64 % -> 0 % for l_thres <= -0.01 (scored on the last iterate only).")
    open(os.path.join(out, "t8.md"), "w").write("\n".join(lines) + "\n")
    print("\n".join(lines))


def video(a):
    """Actions from a 3-camera MuJoCo video of a certified-free trajectory."""
    from profrobot.inverse import actions_from_video
    from profrobot.exact.planning import plan_path, resample_path

    out = os.path.join(a.out, "video")
    os.makedirs(out, exist_ok=True)
    scene = scenes.panda_blocks()
    robot_img, model, sdf = _t7_models()
    ends, _ = group_targets(scene, "0", 2, a.seed + 200)
    plan = plan_path(scene, ends[0], ends[1], seed=a.seed)
    truth = resample_path(scene, plan.path, a.frames)
    cams = t7_cameras(3)
    views = make_views(robot_img, truth, cams, progress=False)
    arm = np.array([t == "hinge" for t in scene.joint_types])
    rng = np.random.default_rng(a.seed)
    init = truth[0] + np.where(arm, 0.05 * rng.standard_normal(len(arm)), 0.0)
    res = dict(frames=a.frames, cameras=3, truth_free=bool(profrobot.exact.certification.check_path(scene, truth).certified),
               loadavg_start=os.getloadavg())
    rows = []
    for label, field in (("without field", None), ("with field", sdf)):
        t0 = time.perf_counter()
        kw = dict(robot=scene) if field is None else dict(sdf=field)
        r = actions_from_video(model, dict(rgb=views.rgb, depth=views.depth, mask=views.mask), cams, init=init,
                               iterations_per_frame=a.steps_per_frame, joint_iterations=a.joint_iters, lr=a.lr,
                               background=views.background, **kw)
        err = np.abs(r.path - truth)[:, arm]
        row = dict(setting=label, median_joint_err_rad=float(np.median(err)), p90_joint_err_rad=float(np.percentile(err, 90)),
                   colliding_frames=int(r.waypoint_uncertified.sum()), uncertified_segments=int(r.segment_uncertified.sum()),
                   free=bool(r.certified), seconds_per_frame=(time.perf_counter() - t0) / a.frames)
        rows.append(row)
        print(json.dumps(row), flush=True)
        if field is not None:
            from profrobot.optim.pictures import render_trajectory

            render_trajectory(scene, r.path, os.path.join(out, "recovered.gif"), collides=r.waypoint_uncertified,
                              camera=PANDA_VIEW, size=(320, 240))
    res["rows"], res["loadavg_end"] = rows, os.getloadavg()
    json.dump(res, open(os.path.join(out, "video.json"), "w"), indent=1)


def keyframe(name):
    """The Shadow Hand's Menagerie keyframe ``name`` as (K,) joints of ``scenes.shadow_hand()``."""
    import xml.etree.ElementTree as ET

    root = ET.parse(os.path.join(os.environ.get("MENAGERIE_ROOT", ""), "shadow_hand", "keyframes.xml")).getroot()
    keys = {k.get("name"): np.array(k.get("qpos").split(), dtype=float) for k in root.iter("key")}
    if name not in keys:
        raise SystemExit(f"no keyframe {name!r}; the Menagerie has {sorted(keys)}")
    return keys[name]


def gaussian_hand(hand, out):
    from profrobot.render import fit_gaussians, sphere_cameras

    path = os.path.join(out, "shadow_hand_gs.safetensors")
    if os.path.exists(path):
        return GaussianRobot.load(path, hand)
    cams = sphere_cameras(8, size=96, distance=0.45, lookat=(0.15, 0.0, 0.0), jitter=0.02, seed=1,
                          elevation_range=(-89.0, -20.0))
    views = make_views(hand, profrobot.exact.problems.free_poses(hand, 40, 1), cams, processes=2)
    model = GaussianRobot.from_robot(hand, 8000, seed=0)
    t = time.perf_counter()
    fit_gaussians(model, views, iterations=500, max_gaussians=16000)
    print(f"Shadow Hand Gaussians fitted in {time.perf_counter() - t:.0f} s ({model.n} Gaussians)", flush=True)
    model.save(path)
    return model


def t9(a):
    from profrobot.inverse import pose_from_text
    from profrobot.inverse.scorers import CLIPScorer, ImageGoalScorer

    out = os.path.join(a.out, "t9")
    os.makedirs(out, exist_ok=True)
    hand = scenes.shadow_hand()
    model = gaussian_hand(hand, out)
    sdf = _bench("fields").field("shadow_hand")
    cam = ring_cameras(1, size=a.size, distance=0.4, elevation=-89.0, lookat=(0.15, 0.0, 0.0))
    goal_q = np.clip(keyframe(a.keyframe), hand.joint_limits[:, 0], hand.joint_limits[:, 1])
    goal_view = make_views(hand, goal_q[None], cam, progress=False)
    bg = goal_view.background
    if a.scorer == "clip":
        scorer, prompt, name = CLIPScorer.from_pretrained(a.clip), a.prompt, f"CLIP ({a.clip}), raw dot product"
    else:
        scorer, prompt = ImageGoalScorer(goal_view.rgb[0, 0], size=64), a.keyframe
        name = f"image goal: MuJoCo render of keyframe {a.keyframe!r}, score = -MSE at 64^2"
    res, rows = dict(scorer=name, runs=a.runs, steps=a.steps, loadavg_start=os.getloadavg()), []
    for label, field in (("without field", None), ("with field", sdf)):
        t0 = time.perf_counter()
        r = pose_from_text(model, prompt, scorer, camera=cam, sdf=field, runs=a.runs, iterations=a.steps, lr=a.lr,
                           beta=10.0, l_thres=-0.1, noise=0.05, seed=a.seed, robot=hand, background=bg)
        mj_before = mujoco_labels(hand, r.poses if field is None else r.poses).ncon > 0
        row = dict(setting=label, score_mean=float(r.score_before_repair.mean()), score_std=float(r.score_before_repair.std()),
                   collide_pct_labeller=100 * float((~r.certified_before_repair).mean()),
                   collide_pct_mujoco_returned=100 * float(mj_before.mean()),
                   certified_pct_returned=100 * float(r.certified.mean()),
                   score_after_repair_mean=float(r.score.mean()), seconds=time.perf_counter() - t0)
        rows.append(row)
        print(json.dumps(row), flush=True)
        np.save(os.path.join(out, f"poses_{label.replace(' ', '_')}.npy"), r.poses)
        picture(hand, os.path.join(out, f"t9_{label.replace(' ', '_')}.png"), goal_q, r.poses[0], r.poses[-1],
                not bool(r.certified_before_repair[0]), not bool(r.certified[-1]),
                camera=dict(lookat=(0.15, 0.0, 0.0), distance=0.45, azimuth=90.0, elevation=-60.0))
    res["rows"], res["loadavg_end"] = rows, os.getloadavg()
    json.dump(res, open(os.path.join(out, "t9.json"), "w"), indent=1)
    lines = [f"# Table 9 on the Shadow Hand ({a.runs} runs of {a.steps} steps; scorer: {name})", "",
             "| setting | score (mean ± std) | results colliding (labeller) | returned poses colliding (MuJoCo) | returned certified free |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['setting']} | {r['score_mean']:.4f} ± {r['score_std']:.4f} | {r['collide_pct_labeller']:.0f} % | "
                     f"{r['collide_pct_mujoco_returned']:.0f} % | {r['certified_pct_returned']:.0f} % |")
    lines.append("\nPaper (CLIP ViT-B/32, 10 runs): collision rate without the field reported beside with it; "
                 "the image-goal scorer's scores are not comparable to CLIP dot products.")
    open(os.path.join(out, "t9.md"), "w").write("\n".join(lines) + "\n")
    print("\n".join(lines))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sp = sub.add_parser("t7", help="Table 7: pose from images, four contact groups")
    sp.add_argument("--instances", type=int, default=10, help="targets per group (the paper: 100)")
    sp.add_argument("--iters", type=int, default=45, help="coarse image-phase iterations (64^2)")
    sp.add_argument("--refine-iters", type=int, default=60, help="full-resolution image-phase iterations")
    sp.add_argument("--field-iters", type=int, default=300)
    sp.add_argument("--beta", type=float, default=10.0)
    sp.add_argument("--l-thres", type=float, default=-0.1)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--out", default=os.path.join(HERE, "out", "inverse"))
    sp.add_argument("--executor", choices=["local", "ray"], default="local", help="run the four rows on Ray actors")
    sp.add_argument("--address", default=None, help="Ray address (default: start a local cluster)")
    sp.add_argument("--workers", type=int, default=None)
    sp.set_defaults(fn=t7)
    sp = sub.add_parser("t8", help="Table 8: trajectories from images")
    sp.add_argument("--instances", type=int, default=10)
    sp.add_argument("--steps", type=int, default=100)
    sp.add_argument("--l-thres-list", type=float, nargs="+", default=[-0.01, -0.1])
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--out", default=os.path.join(HERE, "out", "inverse"))
    sp.set_defaults(fn=t8)
    sp = sub.add_parser("video", help="actions from a 3-camera MuJoCo video of a certified-free trajectory")
    sp.add_argument("--frames", type=int, default=60)
    sp.add_argument("--steps-per-frame", type=int, default=15)
    sp.add_argument("--lr", type=float, default=0.01)
    sp.add_argument("--joint-iters", type=int, default=50)
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--out", default=os.path.join(HERE, "out", "inverse"))
    sp.set_defaults(fn=video)
    sp = sub.add_parser("t9", help="Table 9: a Shadow Hand pose from a goal (image goal or CLIP)")
    sp.add_argument("--runs", type=int, default=10)
    sp.add_argument("--steps", type=int, default=200)
    sp.add_argument("--lr", type=float, default=0.02)
    sp.add_argument("--size", type=int, default=128)
    sp.add_argument("--scorer", choices=["image-goal", "clip"], default="image-goal")
    sp.add_argument("--clip", help="local CLIP checkpoint (with --scorer clip)")
    sp.add_argument("--prompt", default="A black robotic hand do OK gestures with white background")
    sp.add_argument("--keyframe", default="two finger pinch")
    sp.add_argument("--seed", type=int, default=0)
    sp.add_argument("--out", default=os.path.join(HERE, "out", "inverse"))
    sp.set_defaults(fn=t9)
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    return a.fn(a)


if __name__ == "__main__":
    sys.exit(main())
