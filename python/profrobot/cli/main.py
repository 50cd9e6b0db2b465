"""The ``profrobot`` command line: ``demo``, ``label``, ``crosscheck``, ``dataset``, ``train``, ``resolve``, ``plan``,
``render``, ``pose``, ``ik``, ``layout``, ``view``, ``scenes``."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from .. import scenes
from .._core import __version__
from ..exact.crosscheck import crosscheck
from ..exact.dataset import Dataset, make_dataset
from ..errors import InputError, ProfrobotError
from ..exact.labels import Labels, label_poses, sample_poses
from ..executors.progress import progress_bar
from .robots import (DefaultsFormatter, add_robot_arguments, layout_of, negative_values, numbers, pose_arg,
                     robot_of)

_CHUNK = 50_000


def _robot(args):
    return robot_of(args)


def _optim(name: str):
    """``profrobot.cli.optim.<name>``, imported when the command runs (the optimisers need torch;
    ``label``, ``crosscheck``, ``dataset`` and ``scenes`` never load it)."""
    def run(args) -> int:
        from . import optim

        return getattr(optim, name)(args)

    return run


def _layouts(name: str):
    """``profrobot.cli.layouts.<name>``, imported when the command runs."""
    def run(args) -> int:
        from . import layouts

        return getattr(layouts, name)(args)

    return run


def _inverse(name: str):
    """``profrobot.cli.inverse.<name>``, imported when the command runs (torch, like ``_optim``)."""
    def run(args) -> int:
        from . import inverse

        return getattr(inverse, name)(args)

    return run


def _label_with_progress(robot, poses, threads) -> Labels:
    parts = []
    with progress_bar(len(poses), desc=f"label {robot.name}", unit="pose") as bar:
        for start in range(0, len(poses), _CHUNK):
            parts.append(label_poses(robot, poses[start:start + _CHUNK], threads=threads))
            bar.update(len(parts[-1]))
    return Labels(*(np.concatenate([getattr(p, k) for p in parts])
                    for k in ("collides", "self_collides", "scene_collides", "n_pairs")))


def cmd_label(args) -> int:
    robot = _robot(args)
    poses = sample_poses(robot, args.n, args.seed, threads=args.threads)
    t = time.perf_counter()
    labels = _label_with_progress(robot, poses, args.threads)
    dt = time.perf_counter() - t
    print(f"{robot}\n{labels.summary()}\nlabelled in {dt:.2f} s ({len(poses) / dt:,.0f} poses/s)")
    if args.out:
        Dataset(poses, labels.collides, labels.self_collides, labels.scene_collides, labels.n_pairs,
                metadata=dict(robot=robot.name, robot_fingerprint=robot.fingerprint, joint_names=robot.joint_names,
                              seed=args.seed, uniform=True)).save(args.out)
        print(f"saved {args.out}")
    return 0


def _executor(args):
    """``--ray ADDRESS``: a RayExecutor (``local`` starts a local cluster), else None (here)."""
    if not getattr(args, "ray", None):
        return None
    from ..executors import RayExecutor

    return RayExecutor(None if args.ray == "local" else args.ray, workers=args.workers)


def cmd_crosscheck(args) -> int:
    robot = _robot(args)
    poses = sample_poses(robot, args.n, args.seed, threads=args.threads)
    ex = _executor(args)
    try:
        report = crosscheck(robot, poses, threads=args.threads, progress=True, executor=ex)
    finally:
        if ex is not None:
            ex.shutdown()
    print(f"{robot}\n{report.summary()}")
    for d in report.disagreements[: args.show]:
        print(f"  pose {d.pose_index}: ours {d.ours}, MuJoCo {d.mujoco}, pairs {d.pairs}, "
              f"MuJoCo distance {d.signed_distance:+.2e} m, ours {d.ours_min_distance:+.2e} m")
    return 0


def cmd_dataset(args) -> int:
    robot = _robot(args)
    ex = _executor(args)
    try:
        ds = make_dataset(robot, args.n, args.collided_fraction, args.seed, threads=args.threads, executor=ex)
    finally:
        if ex is not None:
            ex.shutdown()
    ds.save(args.out)
    print(f"saved {len(ds)} poses ({ds.collided_fraction:.1%} colliding) to {args.out}")
    return 0


def cmd_train(args) -> int:
    """Train a PoseSDF on a scene, print the held-out metrics, save a checkpoint (atomically)."""
    from ..field import format_metrics, train_sdf
    from ..field.checkpoint import export_sdf

    robot = _robot(args)
    opts = dict(seed=args.seed, threads=args.threads)
    for key in ("n_poses", "iterations", "batch_size", "lr", "encoder", "eikonal_weight", "device"):
        if getattr(args, key) is not None:
            opts[key] = getattr(args, key)
    if args.minutes is not None:
        opts["time_budget"] = args.minutes * 60
    sdf = train_sdf(robot, preset=args.preset, **opts)
    print(f"{sdf}\n{format_metrics(sdf.metrics)}")
    sdf.save(args.out)
    print(f"saved checkpoint {args.out}")
    if args.plot:
        from ..viz import sdf_slice

        sdf_slice(sdf, robot, path=args.plot)
        print(f"saved SDF slice {args.plot}")
    if args.export:
        print(f"exported {args.export} ({export_sdf(sdf, args.export) / 1e6:.1f} MB)")
    return 0


def cmd_ik(args) -> int:
    """Certified IK of a frame for the targets in a .npy file: (N, 4, 4) transforms or (N, 3)
    positions; writes the poses and their report (atomic .npz). Exit 0: every target certified."""
    from ..files import atomic_path
    from ..exact.ik import ik

    robot = _robot(args)
    try:
        targets = np.load(args.targets, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise InputError(f"--targets {args.targets}: not a readable .npy array ({e})") from None
    start = pose_arg(args.start, "start", robot) if args.start else None
    res = ik(robot, targets, frame=args.frame, start=start, seeds=args.seeds, seed=args.seed, threads=args.threads)
    print(res.summary())
    for i in res.failures[:10]:
        print(f"  target {i}: {res.reasons[i]} (position error {res.position_error[i]:.3g} m, rotation error "
              f"{res.rotation_error[i]:.3g} rad)")
    if args.out:
        with atomic_path(args.out, suffix=".npz") as tmp:
            np.savez(tmp, poses=res.poses, certified=res.certified, reached=res.reached, outcome=res.outcome,
                     position_error=res.position_error, rotation_error=res.rotation_error,
                     joint_names=np.array(robot.joint_names if not robot.is_family
                                          else [robot.joint_names[j] for j in robot.robot_index]))
        print(f"saved {args.out}")
    return 0 if res.certified.all() else 1


def cmd_demo(args) -> int:
    """The main job on a bundled default: build a scene, label poses, cross-check with MuJoCo."""
    robot = _robot(args)
    print(robot)
    poses = sample_poses(robot, args.n, args.seed)
    t = time.perf_counter()
    labels = label_poses(robot, poses)
    dt = time.perf_counter() - t
    print(f"labels: {labels.summary()}\n        {len(poses) / dt:,.0f} poses/s on all cores")
    check = min(args.n, args.check)
    report = crosscheck(robot, poses[:check], progress=True)
    print(f"MuJoCo cross-check on the first {check} poses:\n{report.summary()}")
    return 0 if report.agreement >= 0.999 else 1


def cmd_render(args) -> int:
    """Fit a Gaussian-splat robot to MuJoCo renders of a scene's robot, report held-out
    fidelity (PSNR, mask IoU, depth error), save the model (safetensors + JSON, atomic)."""
    import torch

    from ..render import GaussianRobot, fit_gaussians, make_views, ring_cameras, sphere_cameras
    from ..render.image import mask_iou, psnr

    torch.set_num_threads(args.torch_threads)
    robot = _robot(args)
    lookat = tuple(float(x) for x in args.lookat.split(","))
    train_cams = sphere_cameras(args.cameras, size=args.size, distance=args.distance, lookat=lookat, jitter=0.05,
                                seed=args.seed, elevation_range=(-50.0, 20.0))
    test_cams = ring_cameras(4, size=args.size, distance=args.distance, elevation=-15.0, azimuth0=22.5, lookat=lookat)
    train = make_views(robot, sample_poses(robot, args.n, args.seed), train_cams, processes=args.processes)
    test = make_views(robot, sample_poses(robot, 4, args.seed + 1), test_cams, processes=args.processes)
    model = GaussianRobot.from_robot(robot, args.gaussians, seed=args.seed)
    fit_gaussians(model, train, iterations=args.iterations, seed=args.seed, backend=args.backend)
    model.save(args.out)
    with torch.no_grad():
        out = model.render_views(torch.tensor(test.poses, dtype=torch.float32), test_cams,
                                 background=torch.tensor(test.background, dtype=torch.float32), backend=args.backend)
    shape = test.mask.shape
    rgb, alpha, depth = out.rgb.reshape(*shape, 3).numpy(), out.alpha.reshape(shape).numpy(), out.depth.reshape(shape).numpy()
    print(f"{model.n} Gaussians saved to {args.out}\nheld-out poses and views: PSNR {psnr(rgb, test.rgb / 255.0):.2f} dB, "
          f"mask IoU {mask_iou(alpha > 0.5, test.mask):.3f}, median depth error "
          f"{1e3 * np.median(np.abs(depth - test.depth)[test.mask]):.1f} mm")
    return 0


class _Parser(argparse.ArgumentParser):
    """Every subcommand's help shows the defaults."""

    def __init__(self, *a, **kw):
        kw.setdefault("formatter_class", DefaultsFormatter)
        super().__init__(*a, **kw)


def cmd_view(args) -> int:
    from ..viz import Viewer

    robot = robot_of(args, field=args.field)
    layout = layout_of(args, robot)
    pose = None if args.pose is None else numbers(args.pose, "pose")
    viewer = Viewer(robot, pose, layout=layout, frame=args.frame, host=args.host, port=args.port)
    try:
        print(f"profrobot view: {viewer.url}  ({viewer.robot.name}: {viewer.verdict})", flush=True)
        if args.path:
            with np.load(args.path, allow_pickle=False) as z:
                if "path" not in z.files:
                    raise InputError(f"--path {args.path}: no 'path' array (profrobot plan --out writes one)")
                path = z["path"]
            out = viewer.show_path(path)
            print(f"path: {out['verdicts'].count('certified')}/{len(out['verdicts'])} segments certified", flush=True)
        if args.field:
            from ..field import PoseSDF

            sdf = PoseSDF.load(args.field, robot)
            viewer.show_field_slice(sdf.at(layout) if layout is not None else sdf)   # a layout: a family
        deadline = None if args.seconds is None else time.monotonic() + args.seconds
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.1 if deadline is not None else 1.0)
    finally:
        viewer.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="profrobot", description=__doc__, formatter_class=DefaultsFormatter)
    p.add_argument("--version", action="version", version=f"profrobot {__version__}")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)

    def common(sp, n: int | None = None, *, threads: bool = True, scene_default: str | None = "panda_blocks"):
        """The robot (--scene / --robot), -n where the command draws poses, --seed, --threads."""
        add_robot_arguments(sp, scene_default=scene_default)
        if n is not None:
            sp.add_argument("-n", type=int, default=n, help="number of poses")
        sp.add_argument("--seed", type=int, default=0, help="seed of every random draw")
        if threads:
            sp.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")

    def layout(sp):
        sp.add_argument("--layout", default=None, metavar="D1,D2,...",
                        help="for a family of scenes: the layout δ to work at, one value per scene joint (metres, "
                             "radians; default: every scene joint at 0, the obstacles where the model puts them)")

    def cluster(sp):
        sp.add_argument("--ray", metavar="ADDRESS", help="run on a Ray cluster: local (start one here), auto, "
                                                         "host:6379 or ray://host:10001 (pip install 'profrobot[ray]')")
        sp.add_argument("--workers", type=int, default=None, help="Ray workers (default: the cluster's CPUs)")

    sp = sub.add_parser("demo", help="label a bundled scene and cross-check with MuJoCo")
    common(sp, 100_000)
    sp.add_argument("--check", type=int, default=5_000, help="poses cross-checked with MuJoCo")
    sp.set_defaults(fn=cmd_demo)
    sp = sub.add_parser("label", help="label uniform poses of a scene")
    common(sp, 1_000_000)
    sp.add_argument("--out", help="save poses and labels to this .npz (atomic)")
    sp.set_defaults(fn=cmd_label)
    sp = sub.add_parser("crosscheck", help="compare our labels with MuJoCo's")
    common(sp, 10_000)
    sp.add_argument("--show", type=int, default=10, help="disagreements to print")
    cluster(sp)
    sp.set_defaults(fn=cmd_crosscheck)
    sp = sub.add_parser("dataset", help="make a balanced dataset (.npz)")
    common(sp, 100_000)
    sp.add_argument("--collided-fraction", type=float, default=0.5, help="share of colliding poses")
    sp.add_argument("--out", required=True, help="the dataset file to write (.npz, atomic)")
    cluster(sp)
    sp.set_defaults(fn=cmd_dataset)
    sp = sub.add_parser("train", help="train the pose collision field (PoseSDF) on a scene")
    common(sp)
    sp.add_argument("--preset", default="pairs", choices=["cpu", "pairs", "paper"],
                    help="pairs (default: one MLP per body pair, ~9 min on 2 cores for a 7-DoF arm), cpu (one MLP: "
                         "cheaper, less sharp) or paper")
    sp.add_argument("--n-poses", dest="n_poses", type=int, default=None, help="balanced poses to generate")
    sp.add_argument("--iterations", type=int, default=None, help="training iterations (default: the preset's)")
    sp.add_argument("--batch-size", dest="batch_size", type=int, default=None, help="poses per step (default: the preset's)")
    sp.add_argument("--lr", type=float, default=None, help="Adam's learning rate (default: the preset's)")
    sp.add_argument("--encoder", choices=("kinematic", "hierarchical", "flat", "pairs"), default=None,
                    help="pose features (default: the preset's)")
    sp.add_argument("--device", default=None, help="torch device to train on, e.g. cuda (default: cpu)")
    sp.add_argument("--eikonal-weight", dest="eikonal_weight", type=float, default=None,
                    help="weight of the Eikonal term (default: the preset's)")
    sp.add_argument("--minutes", type=float, default=None, help="stop after this much training time")
    sp.add_argument("--out", required=True, help="checkpoint directory (safetensors + JSON)")
    sp.add_argument("--plot", help="also save an SDF slice PNG here")
    sp.add_argument("--export", help="also export a torch.export .pt2 file here")
    sp.set_defaults(fn=cmd_train)
    sp = sub.add_parser("resolve", help="push colliding poses out of collision with a trained field")
    common(sp, 100, threads=False, scene_default=None)
    sp.add_argument("--field", required=True, help="PoseSDF checkpoint directory (profrobot train --out)")
    layout(sp)
    sp.add_argument("--poses", help=".npy file of (B, K) poses (default: -n colliding poses drawn at random)")
    sp.add_argument("--l-thres", dest="l_thres", type=float, default=-0.1, help="the field's threshold l_thres")
    sp.add_argument("--method", choices=("project", "adam"), default="project",
                    help="the field step: project (the nearest pose to first order) or adam (the paper's)")
    sp.add_argument("--lr", type=float, default=None, help="Adam's step size (--method adam; default 0.01)")
    sp.add_argument("--iterations", dest="iterations", type=int, default=None,
                    help="field steps per pose at most (default 5 for project, 1000 for adam)")
    sp.add_argument("--no-shrink", dest="no_shrink", action="store_true",
                    help="keep the field's answer (its margin) instead of the first certified pose on its ray")
    sp.add_argument("--no-refine", dest="no_refine", action="store_true",
                    help="do not retry poses the exact labeller still finds colliding")
    sp.add_argument("--out", help="save poses, certified, iterations, delta to this .npz")
    sp.set_defaults(fn=_optim("cmd_resolve"))
    sp = sub.add_parser("plan", help="a certified motion between two poses, or to a pose of a frame (no field "
                                     "needed; with --field, the field's trajectory)")
    common(sp, threads=False, scene_default="panda_blocks")
    sp.add_argument("--field", default=None, help="PoseSDF checkpoint directory: plan the field's trajectory "
                                                  "(default: none, the exact planner alone)")
    layout(sp)
    sp.add_argument("--start", help="start pose: comma-separated (radians / metres), or a .npy / .npz file the "
                                    "commands write (ik's poses, plan's path), FILE:i for row i "
                                    "(default: a random hard problem)")
    sp.add_argument("--goal", help="goal pose, as --start")
    sp.add_argument("--frame", help="with --target: the site, body or geom to bring to the target")
    sp.add_argument("--target", metavar="X,Y,Z[,QW,QX,QY,QZ]",
                    help="plan to a pose of --frame (metres; with a unit quaternion, its orientation too): IK "
                         "candidates, each certified, then the exact planner")
    sp.add_argument("--max-time", dest="max_time", type=float, default=10.0,
                    help="seconds the exact planner may take")
    sp.add_argument("--steps", type=int, default=100, help="waypoints of the trajectory")
    sp.add_argument("--method", choices=("penalty", "tangent"), default="penalty",
                    help="penalty: Adam on the path's field penalty; tangent: the paper's Algorithm 1")
    sp.add_argument("--init", choices=("auto", "straight", "planner"), default="auto",
                    help="auto: the straight path if free, else the exact planner then field smoothing")
    sp.add_argument("--iterations", type=int, default=500, help="with --field: Adam steps (tangent: 6x as many "
                                                                "walk steps)")
    sp.add_argument("--out", help="save the path and its check to this .npz")
    sp.add_argument("--gif", help="render the path with MuJoCo to this .gif (in a worker process: EGL or OSMesa "
                                  "headless)")
    sp.add_argument("--plot", help="with --field: joint curves and g along the path to this image")
    sp.set_defaults(fn=_optim("cmd_plan"))
    sp = sub.add_parser("render", help="fit a Gaussian-splat robot to MuJoCo renders (robot only)")
    common(sp, 40)
    sp.add_argument("--cameras", type=int, default=8, help="training cameras per pose")
    sp.add_argument("--size", type=int, default=128, help="image size (pixels)")
    sp.add_argument("--gaussians", type=int, default=10_000, help="Gaussians on the robot's surface")
    sp.add_argument("--iterations", dest="iterations", type=int, default=600, help="appearance-fit steps")
    sp.add_argument("--distance", type=float, default=1.5, help="camera distance (metres)")
    sp.add_argument("--lookat", default="0,0,0.45", help="x,y,z the cameras look at (metres)")
    sp.add_argument("--processes", type=int, default=2, help="MuJoCo rendering processes")
    sp.add_argument("--torch-threads", dest="torch_threads", type=int, default=1, help="torch's intra-op threads")
    sp.add_argument("--backend", choices=["auto", "rust", "torch", "gsplat"], default="auto",
                    help="rasterizer: auto = the Rust kernel on a CPU, gsplat on CUDA (default: auto)")
    sp.add_argument("--out", required=True, help="model file (.safetensors)")
    sp.set_defaults(fn=cmd_render)
    sp = sub.add_parser("pose", help="a certified pose from a folder of photos, a calibration and masks",
                        description="Fit the joint angles seen in the images (one per camera, sorted by file name, in "
                                    "the cameras' order) with a Gaussian robot and the field, certify the pose with "
                                    "the exact labeller, write poses.json and fit.png. Exit 0: every pose certified "
                                    "collision-free; 1: one is not; 2: bad input.")
    sp.add_argument("--images", required=True, help="folder of the views of one target (png/jpg, sorted by name = the "
                                                    "cameras' order), or of one subfolder per target")
    sp.add_argument("--cameras", required=True, help="calibration JSON (Cameras.save: K, world_to_cam, width, height, "
                                                     "optional OpenCV distortion)")
    sp.add_argument("--field", required=True, help="PoseSDF checkpoint directory (profrobot train --out)")
    sp.add_argument("--model", required=True, help="Gaussian robot file for the same robot (profrobot render --out)")
    sp.add_argument("--masks", help="robot masks, the images' names, nonzero = robot (default: IMAGES/masks)")
    sp.add_argument("--depth", help="metric depth maps, the images' stems + .npy (default: IMAGES/depth if it exists)")
    add_robot_arguments(sp, scene_default=None)
    sp.add_argument("--init", help="comma-separated start pose, radians / metres (default: the middle of the joint "
                                   "limits)")
    sp.add_argument("--iterations", type=int, default=100, help="image-phase Adam steps")
    sp.add_argument("--field-iterations", dest="field_iterations", type=int, default=300,
                    help="field-phase steps at most (image loss + collision penalty)")
    sp.add_argument("--restarts", type=int, default=0, help="perturbed restarts in a half-resolution first stage "
                                                            "(helps from far starts)")
    sp.add_argument("--lr", type=float, default=0.02, help="image-phase learning rate")
    sp.add_argument("--refine-cameras", dest="refine_cameras", action="store_true",
                    help="also refine the cameras' poses (written to poses.json)")
    sp.add_argument("--seed", type=int, default=0, help="seed of the restarts")
    sp.add_argument("--out", default="pose_out", help="output folder: poses.json, fit.png (default: ./pose_out)")
    sp.set_defaults(fn=_inverse("cmd_pose"))
    sp = sub.add_parser("ik", help="certified collision-free joint poses that put a frame at target poses")
    common(sp)
    sp.add_argument("--frame", required=True, help="the site, body or geom to place (e.g. the gripper's site)")
    sp.add_argument("--targets", required=True, help=".npy file: (N, 4, 4) world transforms or (N, 3) positions, "
                                                     "metres")
    sp.add_argument("--start", help="joint pose the answers stay near: comma-separated, or a .npy / .npz file "
                                    "(FILE:i for row i) (default: the middle of the limits)")
    sp.add_argument("--seeds", type=int, default=128, help="seeds per target at most")
    sp.add_argument("--out", help="save poses, certified, reached, outcome and errors to this .npz (atomic)")
    sp.set_defaults(fn=cmd_ik)
    sp = sub.add_parser("layout", help="a family's layout (where its obstacles are) from depth images")
    add_robot_arguments(sp, scene_default=None)
    sp.add_argument("--depth", required=True, help=".npy: (C, H, W) depth in metres along each camera's z axis, "
                                                   "0 or NaN where missing")
    sp.add_argument("--cameras", required=True, help="the cameras' calibration (JSON written by Cameras.save)")
    sp.add_argument("--pose", required=True, help="the robot's joint pose, comma-separated (radians / metres; "
                                                                     "--pose=-0.1,... when it starts with a minus)")
    sp.add_argument("--mask", help=".npy: (C, H, W) bool, True on the robot's pixels (default: cast at --pose)")
    sp.add_argument("--noise-a", dest="noise_a", type=float, default=0.002, help="depth noise σ = a + b·z: a, metres")
    sp.add_argument("--noise-b", dest="noise_b", type=float, default=0.005, help="depth noise σ = a + b·z: b")
    sp.add_argument("--calibration", type=float, default=0.0,
                    help="metres added to the suggested margin for the cameras' calibration error")
    sp.add_argument("--out", default="layout.json", help="the estimate as JSON (atomic)")
    sp.add_argument("--picture", default=None, help="a PNG of the points and the fitted obstacles")
    sp.set_defaults(fn=_layouts("cmd_layout"))
    sp = sub.add_parser("view", help="a live 3-D view in the browser (viser): the robot, its obstacles, a path, "
                                     "joint sliders and an ik gizmo, with the exact verdict")
    add_robot_arguments(sp, scene_default=None)
    sp.add_argument("--field", default=None, help="a PoseSDF checkpoint directory: its robot (the one it stores, "
                                                  "unless --robot / --scene) and a field slice in the panel")
    layout(sp)
    sp.add_argument("--pose", help="comma-separated pose to show (default: the middle of the joint limits)")
    sp.add_argument("--path", help="a .npz with a 'path' (S, K) (profrobot plan --out) to animate, each segment "
                                   "coloured by its certificate")
    sp.add_argument("--frame", help="the site, body or geom the gizmo moves (default: the body the leaves hang from)")
    sp.add_argument("--host", default="127.0.0.1", help="0.0.0.0 to be seen from other machines")
    sp.add_argument("--port", type=int, default=8080)
    sp.add_argument("--for", dest="seconds", type=float, default=None,
                    help="serve this many seconds, then exit (default: until Ctrl-C)")
    sp.set_defaults(fn=cmd_view)
    sp = sub.add_parser("scenes", help="list the bundled scenes and families of scenes")
    sp.set_defaults(fn=lambda a: print("\n".join(scenes.names() + scenes.family_names())) or 0)

    args = p.parse_args(negative_values(sys.argv[1:] if argv is None else list(argv)))
    try:
        return args.fn(args)
    except KeyboardInterrupt:
        print("interrupted; nothing was written", file=sys.stderr)
        return 130
    except (ProfrobotError, OSError) as e:  # ours, by type (and the file system's): one line, exit 2
        print(f"profrobot: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
