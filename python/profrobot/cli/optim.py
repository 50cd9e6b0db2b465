"""``profrobot resolve`` and ``profrobot plan``: the optimisers and the exact planner on the command
line (registered by :mod:`profrobot.cli.main`). Exit status 0 only when every result is certified
free. ``plan`` needs no field: without ``--field`` it plans on the exact labeller alone
(``plan_path``, or ``plan_to_pose`` with ``--frame`` and ``--target``); torch loads only for a
field."""

from __future__ import annotations

import numpy as np

from ..files import atomic_path
from ..errors import InputError
from .robots import layout_of, numbers, pose_arg, robot_of


def _field(args):
    """(robot, field): the robot as named (``--robot FILE``, ``--scene``, or the one the field
    names) and its field; for a family of scenes, the robot pinned at ``--layout`` (its scene
    joints at 0, the obstacles where the model puts them, by default), where answers are
    certified."""
    from ..field import PoseSDF

    robot = robot_of(args, field=args.field)
    sdf = PoseSDF.load(args.field, robot)
    delta = layout_of(args, robot)
    return (robot, sdf) if delta is None else (robot.at(delta), sdf)


def _save_npz(out: str, /, **arrays) -> None:
    with atomic_path(out, suffix=".npz") as tmp:
        np.savez(tmp, **arrays)


def cmd_resolve(args) -> int:
    from ..exact.problems import colliding_poses
    from ..optim.resolution import resolve

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


def _target(text: str):
    """``--target``: x,y,z (metres: a position) or x,y,z,qw,qx,qy,qz (and the frame's orientation,
    a unit quaternion) → (3,) or (4, 4)."""
    v = numbers(text, "target")
    if len(v) == 3:
        return v
    if len(v) != 7:
        raise InputError(f"--target must be x,y,z or x,y,z,qw,qx,qy,qz (metres, a unit quaternion); got {len(v)} numbers")
    import mujoco

    q = v[3:] / np.linalg.norm(v[3:]) if np.linalg.norm(v[3:]) > 0 else v[3:]
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, q)
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot.reshape(3, 3), v[:3]
    return t


def cmd_plan(args) -> int:
    """A certified motion: on the exact labeller alone (no ``--field``: ``plan_path`` to
    ``--goal``, or ``plan_to_pose`` to ``--frame`` at ``--target``), or the field's trajectory
    (``--field``: ``plan_trajectory``), certified by the labeller either way."""
    from ..exact.problems import hard_pairs

    if args.target is not None and args.goal is not None:
        raise InputError("give --goal (a joint pose) or --target (a pose of --frame), not both")
    if (args.target is None) != (args.frame is None):
        raise InputError("--target needs --frame (the site, body or geom to place) and --frame needs --target")
    if args.field is None:
        robot = robot_of(args)
        delta = layout_of(args, robot)
        robot = robot if delta is None else robot.at(delta)
        sdf = None
    else:
        if args.target is not None:
            raise InputError("--target plans on the exact labeller: leave --field out")
        robot, sdf = _field(args)
    if args.target is not None:
        if args.start is None:
            raise InputError("--target needs --start, the joint pose to move from")
        return _plan_to_pose(args, robot, pose_arg(args.start, "start", robot), _target(args.target))
    if (args.start is None) != (args.goal is None):
        raise InputError("give both --start and --goal, or neither (a random hard problem)")
    if args.start is not None:
        start, goal = pose_arg(args.start, "start", robot), pose_arg(args.goal, "goal", robot)
    else:  # two free poses whose straight interpolation collides
        (start,), (goal,) = hard_pairs(robot, 1, args.seed, steps=args.steps)
    if sdf is None:
        from ..exact.planning import plan_path

        plan = plan_path(robot, start, goal, seed=args.seed, max_time=args.max_time)
        print(plan.summary())
        path, certified = plan.path, bool(plan.found and plan.certified)
        if args.out:
            _save_npz(args.out, path=path, certified=certified)
            print(f"saved {args.out}")
    else:
        from ..optim.paths import PenaltyOptions, TangentOptions
        from ..optim.trajectory import plan_trajectory

        res = plan_trajectory(sdf, start, goal, steps=args.steps, method=args.method, robot=robot, init=args.init,
                              penalty=PenaltyOptions(iterations=args.iterations),
                              tangent=TangentOptions(iterations=6 * args.iterations))
        print(res.summary())
        path, certified = res.path, bool(res.certified)
        if args.out:
            _save_npz(args.out, path=path, certified=certified, segment_uncertified=res.segment_uncertified, g=res.g)
            print(f"saved {args.out}")
        if args.plot:
            from ..optim.pictures import plot_trajectory

            print(f"saved {plot_trajectory(res, args.plot, joint_names=robot.joint_names)}")
    if args.gif and len(path):
        from ..optim.pictures import render_trajectory

        print(f"saved {render_trajectory(robot, path, args.gif, size=(320, 240))}")
    return 0 if certified else 1


def _plan_to_pose(args, robot, start, target) -> int:
    from ..exact.ik import plan_to_pose

    motion = plan_to_pose(robot, start, target, frame=args.frame, max_time=args.max_time, seed=args.seed)
    path = motion.path if motion.certified else None   # a motion is written only when it is certified
    reached = "" if path is None or motion.goal is None else (
        f" ({len(path)} waypoints, goal {np.array2string(motion.goal, precision=4, separator=',')})")
    print(f"motion to {args.frame}: {motion.outcome}{reached}")
    if motion.outcome == "no candidate reached" and motion.ik is not None:
        print(f"  why: {motion.ik.reasons[0]}")
    if args.out and path is not None:
        _save_npz(args.out, path=path, certified=True, goal=motion.goal)
        print(f"saved {args.out}")
    if args.gif and path is not None:
        from ..optim.pictures import render_trajectory

        print(f"saved {render_trajectory(robot, path, args.gif, size=(320, 240))}")
    return 0 if motion.certified else 1
