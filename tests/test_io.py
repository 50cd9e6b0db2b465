"""Atomic writes keep the user's umask, leave the old file on failure and no temporary behind;
the robot check and the error family are one."""

import os
import stat

import numpy as np
import pytest
import torch

import profrobot
from conftest import scene
from profrobot.files import atomic_dir, atomic_path, check_robot
from profrobot.errors import CorruptFileError, ModelError, ProfrobotError, RobotMismatchError


@pytest.fixture
def umask022():
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


def mode(p) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


def only(tmp_path, *names):
    assert sorted(os.listdir(tmp_path)) == sorted(names)


def test_error_family():
    """Issue 19: one root, not a ValueError; bad input stays a ValueError, environment failures
    (a missing renderer, a dead cluster, a backend asked for by name) are RuntimeErrors."""
    from profrobot.errors import (BackendUnavailableError, ClusterError, InputError, InputTypeError,
                                  RendererUnavailableError)

    for e in (ModelError, RobotMismatchError, CorruptFileError, InputError, InputTypeError, ClusterError,
              RendererUnavailableError, BackendUnavailableError):
        assert issubclass(e, ProfrobotError)
    assert not issubclass(ProfrobotError, ValueError)
    for e in (ModelError, RobotMismatchError, CorruptFileError, InputError):
        assert issubclass(e, ValueError)
    assert issubclass(InputTypeError, TypeError)
    for e in (ClusterError, RendererUnavailableError, BackendUnavailableError):
        assert issubclass(e, RuntimeError) and not issubclass(e, ValueError)
    assert ProfrobotError is profrobot._core.ProfrobotError and ModelError is profrobot._core.ModelError
    assert InputError is profrobot._core.InputError


def test_atomic_path_keeps_umask_and_suffix(tmp_path, umask022):
    target = tmp_path / "a.npz"
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.name.endswith(".npz")
        np.savez(tmp, x=np.arange(3))               # would append .npz to any other name
    assert mode(target) == 0o644
    with np.load(target) as z:
        assert z["x"].tolist() == [0, 1, 2]
    with atomic_path(tmp_path / "b.txt", suffix=".pt2") as tmp:
        assert tmp.name.endswith(".pt2")
        tmp.write_text("x")
    only(tmp_path, "a.npz", "b.txt")
    os.umask(0o077)
    with atomic_path(tmp_path / "c.txt") as tmp:
        tmp.write_text("x")
    assert mode(tmp_path / "c.txt") == 0o600


def test_failure_mid_write_keeps_old_file(tmp_path):
    target = tmp_path / "f.bin"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("boom")
    assert target.read_bytes() == b"old"
    only(tmp_path, "f.bin")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target):
            raise KeyboardInterrupt
    only(tmp_path, "f.bin")


def test_atomic_dir_replaces_and_keeps_umask(tmp_path, umask022):
    d = tmp_path / "ck"
    with atomic_dir(d) as tmp:
        (tmp / "a").write_text("1")
    assert mode(d) == 0o755 and (d / "a").read_text() == "1"
    with atomic_dir(d) as tmp:
        (tmp / "b").write_text("2")
    assert sorted(os.listdir(d)) == ["b"]
    with pytest.raises(RuntimeError):
        with atomic_dir(d) as tmp:
            (tmp / "c").write_text("3")
            raise RuntimeError
    assert sorted(os.listdir(d)) == ["b"]
    only(tmp_path, "ck")


def test_check_robot():
    panda, ur5e = scene("panda_blocks"), scene("ur5e_wall_box")
    check_robot({"robot_fingerprint": panda.fingerprint}, panda, "x")
    check_robot(panda.fingerprint, panda, "x")
    check_robot({}, panda, "x", missing_ok=True)
    with pytest.raises(RobotMismatchError) as e:
        check_robot({"robot": "panda_blocks", "robot_fingerprint": panda.fingerprint}, ur5e, "checkpoint panda_sdf")
    msg = str(e.value)
    assert "checkpoint panda_sdf" in msg and "'panda_blocks'" in msg and "'ur5e_wall_box'" in msg
    with pytest.raises(RobotMismatchError):
        check_robot({}, panda, "x")


def test_dataset_save_mode_and_failure(tmp_path, umask022, monkeypatch):
    panda = scene("panda_blocks")
    ds = profrobot.make_dataset(panda, 50, seed=1, batch=500, progress=False)
    path = tmp_path / "d.npz"
    ds.save(path)
    assert mode(path) == 0o644
    before = path.read_bytes()

    def broken(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", broken)
    with pytest.raises(OSError, match="disk full"):
        ds.save(path)
    assert path.read_bytes() == before
    only(tmp_path, "d.npz")


def test_corrupt_files_raise_corrupt_file_error(tmp_path):
    from profrobot.field import PoseSDF

    panda = scene("panda_blocks")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(CorruptFileError):
        profrobot.Dataset.load(bad)
    ck = tmp_path / "ck"
    PoseSDF(panda, hidden=(8,)).save(ck)
    (ck / "config.json").write_text("{not json")
    with pytest.raises(CorruptFileError):
        profrobot.PoseSDF.load(ck, panda)


def test_checkpoint_and_export_modes(tmp_path, umask022):
    from profrobot.field import PoseSDF
    from profrobot.field.checkpoint import export_sdf

    panda = scene("panda_blocks")
    sdf = PoseSDF(panda, hidden=(8,))
    ck = tmp_path / "ck"
    sdf.save(ck)
    assert mode(ck) == 0o755
    for f in ck.iterdir():
        assert mode(f) == 0o644, f
    sdf.save(ck)                       # replacing leaves nothing beside it
    only(tmp_path, "ck")
    pt2 = tmp_path / "g.pt2"
    export_sdf(sdf, pt2, batch=4)
    assert mode(pt2) == 0o644
    only(tmp_path, "ck", "g.pt2")
    m = torch.export.load(str(pt2)).module()
    assert m(torch.zeros(3, sdf.njoint)).shape == (3,)


def test_png_gif_and_figure_modes(tmp_path, umask022, monkeypatch):
    from PIL import Image

    from profrobot.optim import pictures
    from profrobot.render.image import write_png
    from profrobot.viz import save_figure

    write_png(tmp_path / "a.png", np.zeros((4, 5, 3), np.uint8))
    assert mode(tmp_path / "a.png") == 0o644
    assert Image.open(tmp_path / "a.png").size == (5, 4)

    # the GIF writer without a GL renderer: frames drawn by a stand-in
    monkeypatch.setattr(pictures, "trajectory_frames", lambda robot, path, collides, size, cam:
                        [Image.new("RGB", (8, 6), (i * 40, 0, 0)) for i in range(len(path))])
    panda = scene("panda_blocks")
    poses = np.zeros((3, panda.njoint))
    pictures.render_trajectory(panda, poses, tmp_path / "t.gif", collides=np.zeros(3, bool))
    assert mode(tmp_path / "t.gif") == 0o644
    assert Image.open(tmp_path / "t.gif").n_frames == 3

    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig = plt.figure()
    save_figure(fig, tmp_path / "f.png")
    save_figure(fig, tmp_path / "f.pdf")
    plt.close(fig)
    assert mode(tmp_path / "f.png") == 0o644 and (tmp_path / "f.pdf").read_bytes()[:4] == b"%PDF"
    only(tmp_path, "a.png", "t.gif", "f.png", "f.pdf")
