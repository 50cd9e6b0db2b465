"""mplib's side of benches/pick_place_peers.py: the same pick-and-place stages with mplib's
planner (OMPL RRT-Connect + FCL, screw motions for the straight moves) and its TOPP-RA, on
pybullet_data's Panda. Runs in mplib's own venv (numpy < 2); imports no profrobot; writes JSON.

    <mplib venv>/bin/python benches/mplib_stages.py PANDA.urdf OUT.json

(PANDA.urdf: pybullet_data's Panda with its collision meshes re-exported, as the driver writes
it: mplib's loader refuses the original .obj files, faces of two vertices.)
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np
from mplib import Planner, Pose
from mplib.collision_detection import fcl

sys.path.insert(0, os.path.dirname(__file__))
from pick_place_scene import (ARM_A, ARM_V, DOWN_QUAT, HOME, MUG, PICK, PLACE, STAGES, TABLE, WALL,  # noqa: E402
                              grasp_z)


def box(name, centre, half):
    return fcl.FCLObject(name, Pose(p=np.array(centre)), [fcl.CollisionObject(fcl.Box(2 * np.array(half)))], [Pose()])


def main(urdf: str, out: str) -> int:
    planner = Planner(urdf=urdf, move_group="panda_grasptarget", joint_vel_limits=ARM_V, joint_acc_limits=ARM_A)
    planner.planning_world.add_object(box("table", *TABLE))
    planner.planning_world.add_object(box("wall", *WALL))
    centre, radius, half = MUG
    mug = fcl.FCLObject("mug", Pose(p=np.array(centre)), [fcl.CollisionObject(fcl.Cylinder(radius, 2 * half))], [Pose()])
    planner.planning_world.add_object(mug)
    q = np.array(HOME, dtype=float)
    stages = []
    z = grasp_z()

    def run(name, result, t0):
        ok = result["status"] == "Success"
        stages.append(dict(name=name, success=ok, seconds=time.perf_counter() - t0,
                           duration=float(result.get("duration", 0.0)) if ok else None,
                           time=np.asarray(result.get("time", [])).tolist() if ok else [],
                           position=np.asarray(result.get("position", [])).tolist() if ok else [],
                           fingers=float(q[7]), status=str(result["status"])))
        if ok:
            q[:7] = np.asarray(result["position"])[-1]
        return ok

    def pose(xy, zz):
        return Pose(p=np.array([xy[0], xy[1], zz]), q=np.array(DOWN_QUAT))

    for name in STAGES:
        t0 = time.perf_counter()
        if name == "pre-grasp":
            ok = run(name, planner.plan_pose(pose(PICK, z + 0.08), q, planning_time=10.0), t0)
        elif name == "approach":
            ok = run(name, planner.plan_screw(pose(PICK, z), q), t0)
        elif name == "close":
            planner.planning_world.remove_object("mug")
            # the mug in the grasp target's frame (its z points down): its centre 2 cm further
            planner.update_attached_object(fcl.Cylinder(radius, 2 * half), Pose(p=np.array([0.0, 0.0, 0.02])),
                                           name="mug")
            # (mplib gives an attached object no links it may touch: the fingers stop 1 mm short)
            q[7:] = radius + 0.001
            stages.append(dict(name=name, success=True, seconds=time.perf_counter() - t0, duration=0.0, time=[],
                               position=[], fingers=float(q[7]), status="Success"))
            ok = True
        elif name == "lift":
            ok = run(name, planner.plan_screw(pose(PICK, z + 0.10), q), t0)
        elif name == "carry":
            ok = run(name, planner.plan_pose(pose(PLACE, z + 0.10), q, planning_time=10.0), t0)
        elif name == "place":
            ok = run(name, planner.plan_screw(pose(PLACE, z), q), t0)
        elif name == "open":
            planner.detach_object("mug", also_remove=False)
            q[7:] = 0.04
            stages.append(dict(name=name, success=True, seconds=time.perf_counter() - t0, duration=0.0, time=[],
                               position=[], fingers=float(q[7]), status="Success"))
            ok = True
        else:   # retreat
            ok = run(name, planner.plan_screw(pose(PLACE, z + 0.08), q), t0)
        if not ok:
            break
    with open(out, "w") as f:
        json.dump(stages, f)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
