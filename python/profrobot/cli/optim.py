"""``profrobot resolve`` and ``profrobot plan``: the optimisers on the command line (registered
by :mod:`profrobot.cli`). Exit status 0 only when every result is certified free."""

from __future__ import annotations

import numpy as np

from ..files import atomic_path
from ..errors import InputError
from .robots import numbers


def _field(args):
    """(robot, field): the robot as named (``--robot FILE``, ``--scene``, or the one the field
    names) and its field; for a family of scenes, the robot pinned at ``--layout`` (its scene
    joints at 0, the obstacles where the model puts them, by default), where answers are
    certified."""
    from ..field import PoseSDF
    from .robots import robot_of

    robot = robot_of(args, field=args.field)
    sdf = PoseSDF.load(args.field, robot)
    layout = getattr(args, "layout", None)
    if not robot.is_family:
        if layout is not None:
            raise InputError(f"--layout is for a family of scenes; {robot.name} has no scene joints")
        return robot, sdf
    if layout is None:
        delta = np.zeros(len(robot.scene_index))
    else:
        delta = numbers(layout, "layout")
        if len(delta) != len(robot.scene_index):
            raise InputError(f"--layout needs {len(robot.scene_index)} values, one per scene joint "
                             f"({', '.join(robot.scene_joints)}); got {len(delta)}")
    return robot.at(delta), sdf


def _save_npz(out: str, /, **arrays) -> None:
    with atomic_path(out, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


def cmd_resolve(args) -> int:
    from ..exact.problems import colliding_poses
    from ..optim.resolve import resolve

    robot, sdf = _field(args)
    if args.poses:
        poses = np.load(args.poses)
    else:  # colliding poses drawn uniformly
        poses = colliding_poses(robot, args.n, args.seed)
    res = resolve(sdf, poses, l_thres=args.l_thres, lr=args.lr, iterations=args.iterations, robot=robot,
                  refine=not args.no_refine, method=args.method, shrink=not args.no_shrink)
    print(res.summary())
    if len(res.failures):
        print(f"still colliding (exact labeller): poses {res.failures[:20].tolist()}{' ...' if len(res.failures) > 20 else ''}")
    if args.out:
        _save_npz(args.out, poses=res.poses, certified=res.certified, iterations=res.iterations, delta=res.delta,
                  initial=np.asarray(poses, dtype=np.float64))
        print(f"saved {args.out}")
    return 0 if res.certified.all() else 1


def cmd_plan(args) -> int:
    from ..exact.problems import hard_pairs
    from ..optim.paths import PenaltyOptions, TangentOptions
    from ..optim.trajectory import plan_trajectory

    robot, sdf = _field(args)
    if (args.start is None) != (args.goal is None):
        raise InputError("give both --start and --goal, or neither (a random hard problem)")
    if args.start is not None:
        start, goal = numbers(args.start, "start"), numbers(args.goal, "goal")
    else:  # two free poses whose straight interpolation collides
        (start,), (goal,) = hard_pairs(robot, 1, args.seed, steps=args.steps)
    res = plan_trajectory(sdf, start, goal, steps=args.steps, method=args.method, robot=robot, init=args.init,
                          penalty=PenaltyOptions(iterations=args.iterations),
                          tangent=TangentOptions(iterations=6 * args.iterations))
    print(res.summary())
    if args.out:
        _save_npz(args.out, path=res.path, certified=res.certified, segment_collides=res.segment_collides, g=res.g)
        print(f"saved {args.out}")
    if args.gif:
        from ..optim.pictures import render_trajectory

        print(f"saved {render_trajectory(robot, res.path, args.gif, size=(320, 240))}")
    if args.plot:
        from ..optim.pictures import plot_trajectory

        print(f"saved {plot_trajectory(res, args.plot, joint_names=robot.joint_names)}")
    return 0 if res.certified else 1
