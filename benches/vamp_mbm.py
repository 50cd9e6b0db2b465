"""VAMP on MotionBenchMaker, run by ``benches/mbm.py`` inside VAMP's own venv (built by
``../shared/peers/vamp/build.sh DIR``; never imported by profrobot). Prints one JSON object: per
class, per problem, whether it is valid, solved, and VAMP's planning and simplification times in
nanoseconds, exactly as its ``scripts/evaluate_mbm.py`` runs them (RRT-Connect, the Halton
sampler, default settings, one thread).

    DIR/venv/bin/python benches/vamp_mbm.py DIR/vamp/resources/panda/problems.pkl box,bookshelf_small N
"""

import json
import pickle
import sys
import time

import vamp


def main() -> None:
    dataset, classes, n = sys.argv[1], sys.argv[2].split(","), int(sys.argv[3])
    with open(dataset, "rb") as f:
        problems = pickle.load(f)["problems"]
    module, planner, plan_settings, simp_settings = vamp.configure_robot_and_planner_with_kwargs("panda", "rrtc")
    sampler = module.halton()
    out = {}
    for name in classes:
        rows = []
        for data in problems[name][:n]:
            if not data["valid"]:
                rows.append(dict(index=data["index"], valid=False))
                continue
            t = time.perf_counter_ns()
            env = vamp.problem_dict_to_vamp(data)
            scene_ns = time.perf_counter_ns() - t
            sampler.reset()
            result = planner(data["start"], data["goals"], env, plan_settings, sampler)
            row = dict(index=data["index"], valid=True, solved=bool(result.solved), scene_ns=scene_ns,
                       planning_ns=int(result.nanoseconds), simplification_ns=0)
            if result.solved:
                simple = module.simplify(result.path, env, simp_settings, sampler)
                row["simplification_ns"] = int(simple.nanoseconds)
            rows.append(row)
        out[name] = rows
    print(json.dumps(out))


if __name__ == "__main__":
    main()
