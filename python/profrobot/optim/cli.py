"""``profrobot resolve`` and ``profrobot plan``: the optimisers on the command line (registered
by :mod:`profrobot.cli`). Exit status 0 only when every result is certified free."""

from __future__ import annotations

import numpy as np

from .._io import atomic_path


def _field(args):
    from .. import scenes
    from ..field.checkpoint import load_sdf

    robot = scenes.load(args.scene)
    return robot, load_sdf(args.field, robot)


def _pose(text: str, name: str) -> np.ndarray:
    try:
        return np.array([float(v) for v in text.split(",")])
    except ValueError as e:
        raise ValueError(f"--{name} must be comma-separated numbers (radians / metres); got {text!r}") from e


def _save_npz(path: str, **arrays) -> None:
    with atomic_path(path, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


def cmd_resolve(args) -> int:
    from ..labels import label_poses, sample_poses
    from .resolve import resolve

    robot, sdf = _field(args)
    if args.poses:
        poses = np.load(args.poses)
    else:  # colliding poses drawn uniformly
        q = sample_poses(robot, 20 * args.n, args.seed)
        poses = q[label_poses(robot, q).collides][: args.n]
    res = resolve(sdf, poses, l_thres=args.l_thres, lr=args.lr, max_iters=args.max_iters, robot=robot,
                  refine=not args.no_refine)
    print(res.summary())
    if len(res.failures):
        print(f"still colliding (exact labeller): poses {res.failures[:20].tolist()}{' ...' if len(res.failures) > 20 else ''}")
    if args.out:
        _save_npz(args.out, poses=res.poses, certified=res.certified, iterations=res.iterations, delta=res.delta,
                  initial=np.asarray(poses, dtype=np.float64))
        print(f"saved {args.out}")
    return 0 if res.certified.all() else 1


def cmd_plan(args) -> int:
    from ..labels import interpolate, label_poses, sample_poses
    from .certify import check_path
    from .trajectory import plan_trajectory

    robot, sdf = _field(args)
    if (args.start is None) != (args.goal is None):
        raise ValueError("give both --start and --goal, or neither (a random hard problem)")
    if args.start is not None:
        start, goal = _pose(args.start, "start"), _pose(args.goal, "goal")
    else:  # two free poses whose straight interpolation collides
        q = sample_poses(robot, 4000, args.seed)
        free = q[~label_poses(robot, q).collides]
        pairs = ((a, b) for a, b in zip(free[0::2], free[1::2])
                 if not check_path(robot, interpolate(robot, a, b, args.steps)).free)
        start, goal = next(pairs, (None, None))
        if start is None:
            raise ValueError("no free start/goal pair with a colliding straight path found; pass --start/--goal")
    res = plan_trajectory(sdf, start, goal, steps=args.steps, method=args.method, robot=robot,
                          iterations=args.iterations, tangent_iters=6 * args.iterations)
    print(res.summary())
    if args.out:
        _save_npz(args.out, path=res.path, free=res.free, segment_collides=res.segment_collides, g=res.g)
        print(f"saved {args.out}")
    if args.gif:
        from .pictures import render_trajectory

        print(f"saved {render_trajectory(robot, res.path, args.gif, size=(320, 240))}")
    if args.plot:
        from .pictures import plot_trajectory

        print(f"saved {plot_trajectory(res, args.plot, joint_names=robot.joint_names)}")
    return 0 if res.free else 1


def add_commands(sub, common) -> None:
    """Register ``resolve`` and ``plan`` on an argparse sub-parser set."""
    sp = sub.add_parser("resolve", help="push colliding poses out of collision with a trained field")
    common(sp, 100)
    sp.add_argument("--field", required=True, help="PoseSDF checkpoint directory (profrobot train --out)")
    sp.add_argument("--poses", help=".npy file of (B, K) poses (default: -n colliding poses drawn at random)")
    sp.add_argument("--l-thres", dest="l_thres", type=float, default=-0.1)
    sp.add_argument("--lr", type=float, default=0.01)
    sp.add_argument("--max-iters", dest="max_iters", type=int, default=1000)
    sp.add_argument("--no-refine", dest="no_refine", action="store_true",
                    help="do not retry poses the exact labeller still finds colliding")
    sp.add_argument("--out", help="save poses, certified, iterations, delta to this .npz")
    sp.set_defaults(fn=cmd_resolve)
    sp = sub.add_parser("plan", help="a collision-aware trajectory between two poses")
    common(sp, 0)
    sp.add_argument("--field", required=True, help="PoseSDF checkpoint directory")
    sp.add_argument("--start", help="comma-separated start pose (default: a random hard problem)")
    sp.add_argument("--goal", help="comma-separated goal pose")
    sp.add_argument("--steps", type=int, default=100)
    sp.add_argument("--method", choices=("penalty", "tangent"), default="penalty")
    sp.add_argument("--iterations", type=int, default=500, help="Adam steps (tangent: 6x as many walk steps)")
    sp.add_argument("--out", help="save the path and its check to this .npz")
    sp.add_argument("--gif", help="render the path with MuJoCo to this .gif (MUJOCO_GL=osmesa headless)")
    sp.add_argument("--plot", help="joint curves and g along the path to this image")
    sp.set_defaults(fn=cmd_plan)
