"""The command line runs end to end and writes what it says."""

import numpy as np

from profrobot import Dataset
from profrobot.cli.main import main


def test_label_and_dataset_commands(tmp_path, capsys):
    out = tmp_path / "labels.npz"
    assert main(["label", "--scene", "ur5e_wall_box", "-n", "3000", "--out", str(out)]) == 0
    assert "poses/s" in capsys.readouterr().out
    assert len(Dataset.load(out).poses) == 3000
    ds = tmp_path / "ds.npz"
    assert main(["dataset", "--scene", "panda_blocks", "-n", "400", "--out", str(ds)]) == 0
    assert np.mean(Dataset.load(ds).collides) == 0.5


def test_crosscheck_and_demo(capsys):
    assert main(["crosscheck", "--scene", "vx300s_clutter", "-n", "1000"]) == 0
    assert "label agreement 100" in capsys.readouterr().out
    assert main(["demo", "-n", "2000", "--check", "500"]) == 0


def test_errors_are_reported_not_raised(capsys):
    assert main(["label", "--scene", "nope", "-n", "10"]) == 2
    assert "unknown scene" in capsys.readouterr().err


def test_train_command_saves_a_loadable_checkpoint(tmp_path, capsys):
    import profrobot

    ckpt = tmp_path / "ur5e_sdf"
    assert main(["train", "--scene", "ur5e_wall_box", "--n-poses", "3000", "--iterations", "3",
                 "--batch-size", "256", "--out", str(ckpt), "--plot", str(tmp_path / "slice.png")]) == 0
    out = capsys.readouterr().out
    assert "accuracy" in out and "false_free_rate" in out
    sdf = profrobot.PoseSDF.load(ckpt, profrobot.scenes.load("ur5e_wall_box"))
    assert sdf.metrics["iterations"] == 3
    assert (tmp_path / "slice.png").is_file()
