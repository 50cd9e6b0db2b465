"""``profrobot pose``: from a folder of photos, a calibration file and masks on disk to a
certified pose, poses.json and fit.png; bad folders are refused naming the file."""

from __future__ import annotations

import json
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest

from profrobot.cli.main import main

W, H = 64, 48


def png_size(path) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR (and that it is a PNG)."""
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, panda, renderer):
    """A folder on disk: two MuJoCo views of a free Panda pose through OpenCV cameras (fx != fy,
    off-centre principal point), their masks, cams.json, a small Gaussian robot and a field."""
    import profrobot
    from profrobot import render
    from profrobot.render.image import write_png

    root = tmp_path_factory.mktemp("pose_cli")
    lim = panda.joint_limits
    truth = lim.mean(1) + np.array([0.3, 0.2, -0.2, 0.3, 0.1, 0.4, -0.3, 0.0, 0.0])
    assert profrobot.certify_poses(panda, truth[None])[0]
    look = render.Cameras.look_at([[1.5, 0.4, 0.9], [0.3, -1.5, 0.7]], [[0.0, 0.0, 0.45]] * 2, width=W, height=H)
    K = np.array([[60.0, 0, 29.0], [0, 54.0, 21.5], [0, 0, 1]])
    cams = render.Cameras.from_opencv(K, look.world_to_cam, W, H)
    views = render.make_views(panda, truth[None], cams, progress=False)
    (root / "photos" / "masks").mkdir(parents=True)
    for c in range(len(cams)):
        write_png(root / "photos" / f"view{c}.png", views.rgb[0, c])
        write_png(root / "photos" / "masks" / f"view{c}.png", views.mask[0, c].astype(np.uint8) * 255)
    cams.save(root / "cams.json")
    render.GaussianRobot.from_robot(panda, n=1500, seed=0).save(root / "panda_gs.safetensors")
    profrobot.PoseSDF(panda, hidden=(16,)).save(root / "field")
    return root, truth


def args(root, *extra) -> list[str]:
    return ["pose", "--images", str(root / "photos"), "--cameras", str(root / "cams.json"), "--field",
            str(root / "field"), "--model", str(root / "panda_gs.safetensors"), *extra]


def test_pose_from_a_folder_is_certified_and_pictured(inputs, panda, tmp_path, capsys):
    import profrobot

    root, truth = inputs
    init = ",".join(f"{v:.4f}" for v in truth + 0.03)
    out = tmp_path / "out"
    code = main(args(root, "--init", init, "--iterations", "4", "--field-iterations", "3", "--out", str(out)))
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "certified" in printed.out and "view0.png" in printed.out
    doc = json.loads((out / "poses.json").read_text())
    assert doc["format"] == "profrobot.pose/1" and doc["robot_fingerprint"] == panda.fingerprint
    assert doc["certified"] is True and doc["cameras"] is None
    (t,) = doc["targets"]
    assert t["images"] == ["view0.png", "view1.png"] and list(t["pose"]) == panda.joint_names
    pose = np.array([t["pose"][j] for j in panda.joint_names])
    assert t["certified"] is True and profrobot.certify_poses(panda, pose[None])[0]
    assert np.isfinite(t["image_loss"]) and np.abs(pose - truth).max() < 0.3
    assert png_size(out / "fit.png") == (3 * W + 4, 2 * H + 2)     # per view: target | render | overlay
    from PIL import Image

    with Image.open(out / "fit.png") as im:
        im.verify()


def test_default_init_restarts_and_refined_cameras(inputs, panda, tmp_path, capsys):
    from profrobot.render import Cameras

    root, _ = inputs
    out = tmp_path / "out"
    code = main(args(root, "--iterations", "2", "--field-iterations", "2", "--restarts", "1", "--refine-cameras",
                     "--out", str(out)))
    printed = capsys.readouterr()
    doc = json.loads((out / "poses.json").read_text())
    assert code == (0 if doc["certified"] else 1), printed.err
    assert code == 0 or "not certified" in printed.err
    refined = Cameras.from_dict(doc["cameras"])
    assert len(refined) == 2 and (refined.width, refined.height) == (W, H)
    assert png_size(out / "fit.png") == (3 * W + 4, 2 * H + 2)


def copy_folder(root, tmp_path):
    photos = tmp_path / "photos"
    shutil.copytree(root / "photos", photos)
    for name in ("cams.json", "panda_gs.safetensors"):
        shutil.copy(root / name, tmp_path / name)
    shutil.copytree(root / "field", tmp_path / "field")
    return photos


def refused(tmp_path, capsys, *extra) -> str:
    assert main(args(tmp_path, *extra, "--out", str(tmp_path / "out"))) == 2
    assert not (tmp_path / "out" / "poses.json").exists()
    return capsys.readouterr().err


def test_bad_folders_are_refused_naming_the_file(inputs, tmp_path, capsys):
    from profrobot.render.image import write_png

    root, _ = inputs
    photos = copy_folder(root, tmp_path)
    (photos / "view1.png").rename(photos / "view1.bak")              # one image, two cameras
    err = refused(tmp_path, capsys)
    assert "1 image (view0.png)" in err and "2 cameras" in err
    (photos / "view1.bak").rename(photos / "view1.png")

    (photos / "masks" / "view1.png").unlink()                           # a missing mask
    assert "view1.png: no mask" in refused(tmp_path, capsys)
    shutil.copy(root / "photos" / "masks" / "view1.png", photos / "masks" / "view1.png")

    (photos / "view1.png").write_bytes(b"not a png")                    # an unreadable image
    err = refused(tmp_path, capsys)
    assert "view1.png: not a readable image" in err
    write_png(photos / "view1.png", np.zeros((H // 2, W // 2, 3), np.uint8))   # sizes differ between views
    err = refused(tmp_path, capsys)
    assert "view1.png is 32x24 pixels" in err and "view0.png is 64x48" in err
    shutil.copy(root / "photos" / "view1.png", photos / "view1.png")

    write_png(photos / "masks" / "view0.png", np.zeros((H, W + 2), np.uint8))  # a mask of another size
    assert "the mask is 66x48 pixels" in refused(tmp_path, capsys)
    shutil.rmtree(photos / "masks")                                     # no masks at all
    assert "no robot masks" in refused(tmp_path, capsys)
    shutil.copytree(root / "photos" / "masks", photos / "masks")

    for c in range(2):                                                  # square photos, a 4:3 calibration
        write_png(photos / f"view{c}.png", np.zeros((H, H, 3), np.uint8))
        write_png(photos / "masks" / f"view{c}.png", np.zeros((H, H), np.uint8))
    assert "another aspect ratio" in refused(tmp_path, capsys)
    shutil.rmtree(photos)
    shutil.copytree(root / "photos", photos)

    assert "--init needs 9 finite values" in refused(tmp_path, capsys, "--init", "0,0")
    err = refused(tmp_path, capsys, "--scene", "ur5e_wall_box")       # not the field's robot
    assert "made for robot 'panda_blocks'" in err and "--scene" in err
    (tmp_path / "cams.json").write_text("{}")
    assert "cams.json" in refused(tmp_path, capsys)


def test_read_folder_targets_in_subfolders_with_depth_and_any_mask_format(tmp_path):
    from PIL import Image

    from profrobot.cli.inverse import read_folder
    from profrobot.render.image import write_png

    rng = np.random.default_rng(0)
    for t in ("t0", "t1"):
        (tmp_path / t).mkdir()
        (tmp_path / "masks" / t).mkdir(parents=True)
        (tmp_path / "depth" / t).mkdir(parents=True)
        for c in range(2):
            Image.fromarray(rng.integers(0, 255, (6, 8, 3), dtype=np.uint8)).save(tmp_path / t / f"c{c}.jpg")
            np.save(tmp_path / "depth" / t / f"c{c}.npy", np.full((6, 8), 1.5))
    m = np.zeros((6, 8), np.uint8)
    m[2:4, 3:6] = 1
    Image.fromarray(m, mode="L").convert("P").save(tmp_path / "masks" / "t0" / "c0.png")          # palette index
    write_png(tmp_path / "masks" / "t0" / "c1.png", np.stack([m * 200] * 3, -1))                   # RGB
    rgba = np.zeros((6, 8, 4), np.uint8)
    rgba[..., :3] = 255
    rgba[..., 3] = m * 255                                                                         # alpha
    Image.fromarray(rgba, mode="RGBA").save(tmp_path / "masks" / "t1" / "c0.png")
    Image.fromarray(m.astype(bool)).save(tmp_path / "masks" / "t1" / "c1.bmp")                     # 1-bit, another format
    targets, names, files = read_folder(tmp_path, 2)
    assert names == ["t0", "t1"] and files == [["c0.jpg", "c1.jpg"]] * 2
    assert targets["rgb"].shape == (2, 2, 6, 8, 3) and targets["rgb"].dtype == np.uint8
    assert targets["depth"].shape == (2, 2, 6, 8) and (targets["depth"] == 1.5).all()
    assert (targets["mask"] == m.astype(bool)).all()


def test_fit_mosaic_rows_of_target_render_overlay(tmp_path):
    from profrobot.render.image import fit_mosaic, fit_picture

    target = np.zeros((2, 5, 7, 3), np.uint8)
    render = np.ones((2, 5, 7, 3))
    alpha = np.zeros((2, 5, 7))
    alpha[:, 1:4, 2:5] = 1.0
    mask = alpha > 0.5
    pic = fit_mosaic(target, render, alpha, mask=mask, gap=1)
    assert pic.shape == (2 * 5 + 1, 3 * 7 + 2, 3) and pic.dtype == np.uint8
    assert (pic[5] == 255).all() and (pic[:, 7] == 255).all()           # white gaps
    assert (pic[6:11, 8:15] == 255).all()                                # view 1's render
    assert tuple(pic[2, 16 + 3]) == (0, 115, 0)                          # overlay: the render's inside tinted green
    assert tuple(pic[1, 16 + 2]) == (255, 0, 255)                        # the target mask's outline on top
    assert png_size(fit_picture(tmp_path / "fit.png", target, render, alpha)) == (25, 12)   # gap 2
    with pytest.raises(ValueError, match="alpha"):
        fit_mosaic(target, render, alpha[:1])


def test_a_urdf_robot_with_package_meshes_from_the_command_line(tmp_path, renderer, capsys):
    """A URDF arm (package:// and relative meshes, a continuous and a mimic joint): its field and
    Gaussian model made in Python, the pose found from photos by `profrobot pose --robot
    arm.urdf --package-dir ws`, certified by the labeller of the same compiled robot."""
    import importlib.util

    import profrobot
    from profrobot import render
    from profrobot.render.image import write_png

    spec = importlib.util.spec_from_file_location("test_urdf", Path(__file__).with_name("test_urdf.py"))
    tu = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tu)
    tu.write_stl(tmp_path / "ws" / "mypkg" / "meshes" / "link.stl", *tu.box_mesh((-0.03, -0.03, 0.03), (0.03, 0.03, 0.28)))
    tu.write_obj(tmp_path / "robot" / "meshes" / "bar.obj", *tu.box_mesh((-0.035, -0.03, 0.0), (0.035, 0.03, 0.3)))
    urdf = tmp_path / "robot" / "arm.urdf"
    urdf.write_text(tu.arm_urdf())
    arm = profrobot.Robot.from_urdf(urdf, package_dirs=[tmp_path / "ws"])
    truth = np.array([0.4, 0.5, 1.0, 0.2, -0.1])
    assert profrobot.certify_poses(arm, truth[None])[0]
    cams = render.Cameras.look_at([[1.2, 0.4, 0.8], [0.2, -1.2, 0.7]], [0, 0, 0.4], width=48, height=40)
    views = render.make_views(arm, truth[None], cams, progress=False)
    (tmp_path / "photos" / "masks").mkdir(parents=True)
    for c in range(2):
        write_png(tmp_path / "photos" / f"c{c}.png", views.rgb[0, c])
        write_png(tmp_path / "photos" / "masks" / f"c{c}.png", views.mask[0, c].astype(np.uint8) * 255)
    cams.save(tmp_path / "cams.json")
    render.GaussianRobot.from_robot(arm, n=400, seed=0).save(tmp_path / "gs.safetensors")
    profrobot.PoseSDF(arm, hidden=(16,)).save(tmp_path / "field")
    base = ["pose", "--images", str(tmp_path / "photos"), "--cameras", str(tmp_path / "cams.json"), "--field",
            str(tmp_path / "field"), "--model", str(tmp_path / "gs.safetensors"), "--iterations", "3",
            "--field-iterations", "2", "--init", ",".join(map(str, truth + 0.05)), "--out", str(tmp_path / "out")]
    # the field directory stores its robot (issue 37): the URDF arm needs naming no more
    assert main(base) == 0, capsys.readouterr().err
    assert json.loads((tmp_path / "out" / "poses.json").read_text())["robot_fingerprint"] == arm.fingerprint
    assert main(base + ["--robot", str(urdf), "--package-dir", str(tmp_path / "ws")]) == 0, capsys.readouterr().err
    doc = json.loads((tmp_path / "out" / "poses.json").read_text())
    assert doc["certified"] is True and doc["robot_fingerprint"] == arm.fingerprint
    assert list(doc["targets"][0]["pose"]) == arm.joint_names
