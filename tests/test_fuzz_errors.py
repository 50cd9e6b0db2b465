"""A fuzz table of bad calls across the public API (issue 33): each raises a ProfrobotError
subclass whose message names the argument; none escapes the family, and none aborts the process,
absurd sizes included (those run in a child process first: an abort there cannot take the test
run down, and the child's exit status says whether one happened)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import torch

import profrobot
from profrobot.exact import problems
from profrobot.errors import ProfrobotError

from conftest import scene

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _panda():
    return scene("panda_blocks")


def _mid():
    return _panda().joint_limits.mean(1)


def _free():
    return problems.free_poses(_panda(), 2, seed=0)


def _sdf():
    torch.manual_seed(0)
    return profrobot.PoseSDF(_panda(), hidden=(8,))


def _degrees():
    q = _free()[:1].copy()
    q[0, :7] = np.degrees(q[0, :7])
    return q


def _nan_pose():
    q = _mid()[None].copy()
    q[0, 4] = np.nan
    return q


def _garbage_file(tmp):
    path = os.path.join(tmp, "garbage.npz")
    with open(path, "wb") as f:
        f.write(b"\x93NUMPY this is not a dataset at all")
    return path


# (name, call(tmp) -> anything, regex the message must match: it names the argument)
CASES = [
    # poses: dtypes, shapes, values
    ("label_poses str dtype", lambda t: profrobot.label_poses(_panda(), np.array([["a"] * 9])), r"poses.*floating-point"),
    ("label_poses complex", lambda t: profrobot.label_poses(_panda(), np.zeros((2, 9), complex)), r"poses.*floating-point"),
    ("label_poses ragged list", lambda t: profrobot.label_poses(_panda(), [[0.0] * 9, [0.0] * 3]), r"poses"),
    ("label_poses wrong width", lambda t: profrobot.label_poses(_panda(), np.zeros((2, 5))), r"poses.*shape \(B, 9\)"),
    ("label_poses empty", lambda t: profrobot.label_poses(_panda(), np.zeros((0, 9))), r"poses.*empty"),
    ("label_poses NaN", lambda t: profrobot.label_poses(_panda(), _nan_pose()), r"poses\[0, 4\] \(joint5\)"),
    ("label_poses in degrees", lambda t: profrobot.label_poses(_panda(), _degrees()), r"poses\[0, \d\].*outside the limits"),
    ("collides in degrees", lambda t: profrobot.collides(_panda(), _degrees()), r"poses\[0, \d\].*outside the limits"),
    ("collides not a robot", lambda t: profrobot.collides("panda", _mid()[None]), r"profrobot.Robot"),
    ("label_poses threads 0", lambda t: profrobot.label_poses(_panda(), _mid()[None], threads=0), r"threads"),
    ("certify_poses NaN", lambda t: profrobot.certify_poses(_panda(), _nan_pose()), r"poses\[0, 4\]"),
    ("certify_motions shapes", lambda t: profrobot.certify_motions(_panda(), _free(), _free()[:1]), r"starts and goals"),
    ("check_path one waypoint", lambda t: profrobot.check_path(_panda(), _free()[:1]), r"path"),
    ("check_path density 0", lambda t: profrobot.check_path(_panda(), _free(), density=0), r"density"),
    ("check_path method", lambda t: profrobot.check_path(_panda(), _free(), method="fast"), r"method"),
    ("nearest_free in degrees", lambda t: profrobot.nearest_free(_panda(), _degrees()), r"outside the limits"),
    ("nearest_free directions 0", lambda t: profrobot.nearest_free(_panda(), _free(), directions=0), r"directions"),
    ("plan_path ints outside limits", lambda t: profrobot.plan_path(_panda(), [0] * 9, [1] * 9), r"start.*outside"),
    ("plan_path wrong width", lambda t: profrobot.plan_path(_panda(), _mid()[:5], _mid()), r"start"),
    ("plan_path off the coupling", lambda t: profrobot.plan_path(_panda(), _free()[0] + np.r_[np.zeros(8), 1e-3],
                                                                 _free()[1]), r"start.*couplings"),
    ("interpolate steps 1", lambda t: profrobot.interpolate(_panda(), _mid(), _mid(), 1), r"steps"),
    ("sample_poses n 0", lambda t: profrobot.sample_poses(_panda(), 0), r"\bn\b"),
    ("sample_poses n float", lambda t: profrobot.sample_poses(_panda(), 2.5), r"\bn\b"),
    ("sample_poses seed -1", lambda t: profrobot.sample_poses(_panda(), 3, seed=-1), r"seed"),
    ("sample_poses equalities", lambda t: profrobot.sample_poses(_panda(), 3, equalities="sometimes"), r"equalities"),
    ("label_poses layout on a plain robot", lambda t: profrobot.label_poses(_panda(), _mid()[None], layout=[0.1]),
     r"layout="),
    ("family theta without scene", lambda t: profrobot.label_poses(scene("panda_blocks_moving"), _free()),
     r"poses.*layout="),
    ("family scene wrong size", lambda t: profrobot.collides(scene("panda_blocks_moving"), _free(), layout=[0.0]),
     r"scene"),
    # obstacles
    ("with_obstacles one Sphere", lambda t: _panda().with_obstacles(profrobot.Sphere(pos=(0, 0, 1))), r"obstacles.*list"),
    ("with_obstacles a string", lambda t: _panda().with_obstacles(["box"]), r"obstacles\[0\]"),
    ("with_obstacles repeated name", lambda t: _panda().with_obstacles(
        [profrobot.Sphere(pos=(0, 0, 1.5), name="s"), profrobot.Sphere(pos=(0, 1, 1.5), name="s")]), r"obstacles\[1\].*'s'"),
    ("with_obstacles a scene geom's name", lambda t: _panda().with_obstacles(
        [profrobot.Box(pos=(0, 0, 2), name=_panda().body_names[1])]), r"obstacles\[0\].*taken"),
    ("Box negative half size", lambda t: _panda().with_obstacles([profrobot.Box(pos=(0, 0, 1), half_size=(-0.1, 0.1, 0.1))]),
     r"Box at \(0, 0, 1\): half_size x must be a positive length"),
    ("Box two half sizes", lambda t: _panda().with_obstacles([profrobot.Box(pos=(0, 0, 1), half_size=(0.1, 0.1))]),
     r"half_size"),
    ("Sphere NaN radius", lambda t: _panda().with_obstacles([profrobot.Sphere(pos=(0, 0, 1), radius=np.nan, name="b")]),
     r"Sphere 'b': radius"),
    ("Capsule pos of 2", lambda t: _panda().with_obstacles([profrobot.Capsule(pos=(0, 0))]), r"pos"),
    # files
    ("Dataset.load garbage", lambda t: profrobot.Dataset.load(_garbage_file(t)), r"garbage.npz.*not an .npz"),
    ("Dataset.load missing", lambda t: profrobot.Dataset.load(os.path.join(t, "none.npz")), r"none.npz"),
    ("PoseSDF.load missing dir", lambda t: profrobot.PoseSDF.load(os.path.join(t, "nofield"), _panda()), r"nofield"),
    ("from_mjcf missing", lambda t: profrobot.Robot.from_mjcf(os.path.join(t, "none.xml")), r"none.xml"),
    ("from_mjcf collision_matrix", lambda t: profrobot.Robot.from_mjcf(os.path.join(t, "none.xml"),
                                                                      collision_matrix="all"), r"collision_matrix"),
    ("from_urdf missing", lambda t: profrobot.Robot.from_urdf(os.path.join(t, "none.urdf")), r"none.urdf"),
    # the field
    ("sdf of an ndarray", lambda t: _sdf()(np.zeros((2, 9))), r"theta must be a torch.Tensor"),
    ("sdf of NaN", lambda t: _sdf()(torch.as_tensor(_nan_pose(), dtype=torch.float32)), r"theta\[0, 4\] \(joint5\)"),
    ("sdf wrong width", lambda t: _sdf()(torch.zeros(2, 4)), r"theta.*shape"),
    ("train_sdf tiny n_poses", lambda t: profrobot.train_sdf(_panda(), n_poses=10, iterations=1, progress=False),
     r"n_poses"),
    ("resolve NaN", lambda t: profrobot.resolve(_sdf(), _nan_pose(), robot=_panda()), r"poses\[0, 4\]"),
    ("resolve method", lambda t: profrobot.resolve(_sdf(), _free(), robot=_panda(), method="newton"), r"method"),
    ("plan_trajectory steps 1", lambda t: profrobot.plan_trajectory(_sdf(), _free()[0], _free()[1], steps=1,
                                                                    robot=_panda()), r"steps"),
    # sizes the machine cannot hold: refused before anything is allocated
    ("sample_poses 2**40", lambda t: profrobot.sample_poses(_panda(), 2**40), r"\bn\b.*too large"),
    ("sample_poses 10**9 (72 GB of poses)", lambda t: profrobot.sample_poses(_panda(), 10**9), r"\bn\b.*too large"),
    ("interpolate 2**40", lambda t: profrobot.interpolate(_panda(), _mid(), _mid(), 2**40), r"steps.*too large"),
    ("core.sample 2**40", lambda t: _panda().core.sample(2**40, 0), r"\bn\b.*too large"),
    ("core interpolate 2**40", lambda t: profrobot._core.interpolate(_mid()[None], _mid()[None], 2**40,
                                                                   np.zeros(9, bool)), r"steps.*too large"),
    ("make_dataset 10**12", lambda t: profrobot.make_dataset(_panda(), 10**12, progress=False), r"\bn\b.*too large"),
    ("plan_path resolution 1e-300", lambda t: profrobot.plan_path(_panda(), _free()[0], _free()[1], check="sampled",
                                                                  resolution=1e-300), r"resolution"),
]

ABSURD = [c for c in CASES if "2**40" in c[0] or "10**" in c[0] or "1e-300" in c[0]]


def test_the_table_is_large():
    assert len(CASES) >= 40, len(CASES)


@pytest.mark.parametrize("name, call, match", CASES, ids=[c[0] for c in CASES])
def test_bad_call_raises_a_profrobot_error_naming_the_argument(name, call, match, tmp_path, request):
    if (name, call, match) in ABSURD:
        survived = request.getfixturevalue("absurd_sizes_survive")   # the child runs for these cases only
        assert name in survived, (name, survived)
    with pytest.raises(ProfrobotError, match=match) as info:
        call(str(tmp_path))
    assert type(info.value).__module__.startswith("profrobot"), type(info.value)


@pytest.fixture(scope="module")
def absurd_sizes_survive() -> list[str]:
    """Every absurd-size call, one after the other in one fresh interpreter (one import of torch,
    not one per case): it must exit normally (an abort would be a negative status), having refused
    each of them; the cases it refused are returned, in order, so that an abort names the case it
    happened in (the first one missing)."""
    code = textwrap.dedent(f"""
        import sys, tempfile
        sys.path.insert(0, {os.path.join(ROOT, 'tests')!r})
        import test_fuzz_errors as t
        for name, call, _ in t.ABSURD:
            try:
                call(tempfile.mkdtemp())
            except t.ProfrobotError as e:
                print("refused:", name, "|", e, flush=True)
        """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT,
                          env=dict(os.environ, OMP_NUM_THREADS="1"))
    refused = [line.split(" | ")[0].removeprefix("refused: ") for line in done.stdout.splitlines()
               if line.startswith("refused: ")]
    assert done.returncode == 0, (done.returncode, refused, done.stderr[-2000:])
    return refused
