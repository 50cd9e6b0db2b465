"""One vocabulary (issue 19): versioned files refuse a newer version with a message naming both; a
backend asked for by name fails loudly instead of falling back; results share their names."""

import json

import numpy as np
import pytest
import torch

import profrobot
from profrobot.errors import BackendUnavailableError, CorruptFileError, ProfrobotError
from profrobot.field import PoseSDF


def test_a_newer_file_is_refused_with_both_versions(panda, tmp_path):
    PoseSDF(panda, hidden=(8,)).save(tmp_path / "f")
    cfg = tmp_path / "f" / "config.json"
    config = json.loads(cfg.read_text())
    config["format"] = "profrobot.PoseSDF/7"
    cfg.write_text(json.dumps(config))
    with pytest.raises(CorruptFileError, match=r"version 7.*newer profrobot.*up to 1"):
        PoseSDF.load(tmp_path / "f", panda)
    config["format"] = "profrobot.views/1"
    cfg.write_text(json.dumps(config))
    with pytest.raises(CorruptFileError, match="not a profrobot PoseSDF file"):
        PoseSDF.load(tmp_path / "f", panda)


def test_dataset_files_carry_a_version(panda, tmp_path):
    ds = profrobot.make_dataset(panda, 200, seed=0, progress=False)
    ds.save(tmp_path / "d.npz")
    with np.load(tmp_path / "d.npz") as z:
        meta = json.loads(str(z["metadata"]))
    assert meta["format"] == "profrobot.dataset/1"
    meta["format"] = "profrobot.dataset/2"
    with np.load(tmp_path / "d.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["metadata"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "new.npz", **arrays)
    with pytest.raises(CorruptFileError, match="version 2"):
        profrobot.Dataset.load(tmp_path / "new.npz")


def test_gsplat_by_name_fails_loudly_on_a_cpu():
    from profrobot.render import rasterize

    means = torch.zeros(1, 3) + torch.tensor([0.0, 0.0, 1.0])
    covs = torch.eye(3)[None] * 1e-3
    args = (means, covs, torch.ones(1) * 0.5, torch.ones(1, 3), torch.eye(4)[None],
            torch.tensor([[[20.0, 0, 8], [0, 20.0, 8], [0, 0, 1]]]), 16, 16)
    with pytest.raises(BackendUnavailableError, match="gsplat") as e:
        rasterize(*args, backend="gsplat")
    assert isinstance(e.value, RuntimeError) and not isinstance(e.value, ValueError)
    assert isinstance(e.value, ProfrobotError)
    out = rasterize(*args, backend="auto")                   # auto picks what runs here
    assert float(out.alpha.max()) > 0


def test_result_names_are_shared(panda):
    """``poses``/``path``, ``certified``, ``iterations``, ``seconds`` on every result."""
    torch.manual_seed(0)
    sdf = PoseSDF(panda, hidden=(8,))
    q = profrobot.exact.problems.colliding_poses(panda, 2, seed=0)
    r = profrobot.resolve(sdf, q, iterations=1, refine=False)
    s, g = profrobot.exact.problems.free_poses(panda, 2, seed=4)
    t = profrobot.plan_trajectory(None, s, g, robot=panda, steps=5)
    p = profrobot.plan_path(panda, s, g, max_time=5.0)
    for res, answer in ((r, "poses"), (t, "path"), (p, "path")):
        for name in (answer, "certified", "iterations", "seconds"):
            assert hasattr(res, name), (type(res).__name__, name)


def test_gaussian_robot_files_of_the_previous_release_load(tmp_path):
    """The joint-limits buffer was called ``limits``: such files (and state dicts) still load."""
    from safetensors import safe_open
    from safetensors.torch import save_file

    from profrobot.render import GaussianRobot

    arm = profrobot.scenes.load("panda_blocks")
    model = GaussianRobot.from_robot(arm, 200, seed=0)
    model.save(tmp_path / "new.safetensors")
    with safe_open(str(tmp_path / "new.safetensors"), framework="pt") as f:
        meta, tensors = f.metadata(), {k: f.get_tensor(k) for k in f.keys()}
    tensors["limits"] = tensors.pop("joint_limits")
    save_file(tensors, str(tmp_path / "old.safetensors"), metadata=meta)
    old = GaussianRobot.load(tmp_path / "old.safetensors", arm)
    assert torch.equal(old.joint_limits, model.joint_limits) and torch.equal(old.means, model.means)
    state = {("limits" if k == "joint_limits" else k): v for k, v in model.state_dict().items()}
    twin = GaussianRobot.from_robot(arm, 200, seed=0)
    twin.load_state_dict(state)
    assert torch.equal(twin.joint_limits, model.joint_limits)
