"""The README's pictures of the browser viewer (issue 37): a certified path and an uncertified one
on panda_blocks, as headless Chromium draws ``profrobot.viz.Viewer``'s page. Writes
benches/shots/viewer_certified.png and viewer_uncertified.png.

    python benches/viewer_shots.py        (needs the viewer extra, playwright and chromium)
"""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np

import profrobot
from profrobot.viz import Viewer

OUT = Path(__file__).parent / "shots"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    robot = profrobot.scenes.load("panda_blocks")
    # a hard problem: the straight motion between its ends is not certified; the planner's path is
    starts, goals = profrobot.exact.problems.hard_pairs(robot, 1, seed=3)
    start, goal = starts[0], goals[0]
    planned = profrobot.plan_path(robot, start, goal)
    assert planned.certified
    straight = np.stack([start, goal])
    for name, path in (("certified", planned.path), ("uncertified", straight)):
        with Viewer(robot, start, port=free_port(), gizmo=False) as v:
            v.look((1.9, -1.3, 1.3), (0.25, 0.0, 0.4), 45.0)
            out = v.show_path(path, name=name)
            info = v._paths[name]
            info["slider"].value = len(info["poses"]) // 2   # the robot half way along
            shot = v.screenshot(OUT / f"viewer_{name}.png")
            print(f"{name}: {out['verdicts']} -> {shot} ({v.verdict})")


if __name__ == "__main__":
    main()
