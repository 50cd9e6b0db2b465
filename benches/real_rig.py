"""A real rig's camera model, checked independently (issue 20, acceptance 1-3).

    MUJOCO_GL=osmesa python benches/real_rig.py [--targets 20] [--quick]

Targets are MuJoCo renders from its own *free* cameras (square pixels, centred principal point, no
roll), then **cropped off-centre, stretched 2x horizontally and rotated by 90 degrees**. The
cameras of the transformed images are written down by hand (:func:`transform`): K gets fx != fy,
an off-centre principal point and the camera is rolled; they reach the fit only through
``Cameras.from_opencv``. The fit must then recover the poses as well as from the untouched
renders. Rows (median joint error over the arm joints of >= 20 collision-free Panda targets, starts
0.1 rad away on every arm joint):

1. untouched renders, free cameras;                          (reference)
2. cropped / stretched / rotated, ``Cameras.from_opencv``;      target <= 0.02 rad
3. (2) over a textured background, with the mask;              target <= 0.02 rad
4. (3) without depth (RGB + mask);                             target <= 0.03 rad
5. (4) with every camera 2 deg / 2 cm off, refinement off;     (reference)
6. (4) with every camera 2 deg / 2 cm off, refinement on;      target <= 0.03 rad

(``pose_from_images`` with a field on such targets, every pose certified: tests/test_real_rig.py.)

The Gaussian Panda is the one ``benches/render.py`` fits (cached under benches/out/render).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

import profrobot  # noqa: E402
from profrobot.exact.problems import free_poses  # noqa: E402
from profrobot.render import Cameras, GaussianRobot, fit_pose, make_views, ring_cameras  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


# --------------------------------------------------------------------------------------------
# The hand-made transform: crop (r0, c0, h, w), stretch columns 2x, rotate 90 deg counter-clockwise
# --------------------------------------------------------------------------------------------

def transform_images(a: np.ndarray, crop: tuple[int, int, int, int], rgb: bool = False) -> np.ndarray:
    """Images (..., H, W), or (..., H, W, 3) if ``rgb``: crop rows r0:r0+h and columns c0:c0+w,
    repeat every column twice, rotate by 90 degrees counter-clockwise (``np.rot90``:
    out[i, j] = in[j, W' - 1 - i])."""
    r0, c0, h, w = crop
    ax = (-3, -2) if rgb else (-2, -1)
    sl = [slice(None)] * a.ndim
    sl[ax[0]], sl[ax[1]] = slice(r0, r0 + h), slice(c0, c0 + w)
    a = np.repeat(a[tuple(sl)], 2, axis=ax[1])
    return np.ascontiguousarray(np.rot90(a, 1, axes=ax))


def transform_cameras(cams: Cameras, crop: tuple[int, int, int, int]) -> Cameras:
    """The OpenCV cameras of :func:`transform_images`, by hand from the free cameras' K and pose:

    - crop:    cx -= c0, cy -= r0;
    - stretch: pixel i becomes pixels 2i, 2i+1 (centre 2i + 1/2): fx -> 2 fx, cx -> 2 cx + 1/2;
    - rotate:  u' = v, v' = (W - 1) - u for the stretched width W = 2w: the camera's new axes are
      x' = y, y' = -x (rows of R: R1, -R0, R2; t likewise) and K' = [[fy, 0, cy], [0, fx, W-1-cx]];
      the new image is h wide and W tall.
    """
    r0, c0, h, w = crop
    K, T = cams.K, cams.world_to_cam
    fx, fy, cx, cy = K[:, 0, 0], K[:, 1, 1], K[:, 0, 2] - c0, K[:, 1, 2] - r0
    fx, cx = 2 * fx, 2 * cx + 0.5
    W = 2 * w
    K2 = np.zeros_like(K)
    K2[:, 0, 0], K2[:, 0, 2], K2[:, 1, 1], K2[:, 1, 2], K2[:, 2, 2] = fy, cy, fx, (W - 1) - cx, 1.0
    T2 = T.copy()
    T2[:, 0], T2[:, 1] = T[:, 1], -T[:, 0]
    return Cameras.from_opencv(K2, T2, h, W)


def texture(shape: tuple, seed: int) -> np.ndarray:
    """A cluttered background (..., H, W, 3) uint8: smooth colour noise plus stripes."""
    rng = np.random.default_rng(seed)
    *lead, H, W, _ = shape
    coarse = rng.uniform(0, 255, (*lead, H // 8 + 2, W // 8 + 2, 3))
    img = np.repeat(np.repeat(coarse, 8, -3), 8, -2)[..., :H, :W, :]
    stripes = 60 * (np.sin(np.arange(W) / 3.0)[None, :, None] > 0)
    return np.clip(0.7 * img + stripes, 0, 255).astype(np.uint8)


def miscalibrate(cams: Cameras, degrees: float, metres: float, seed: int) -> Cameras:
    """Every camera moved by a rotation of ``degrees`` about a random axis and a translation of
    ``metres`` in a random direction (in its own frame)."""
    rng = np.random.default_rng(seed)
    C = len(cams)
    motion = np.tile(np.eye(4), (C, 1, 1))
    for c in range(C):
        k = rng.normal(size=3)
        k /= np.linalg.norm(k)
        a = np.deg2rad(degrees)
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        motion[c, :3, :3] = np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx
        d = rng.normal(size=3)
        motion[c, :3, 3] = metres * d / np.linalg.norm(d)
    return cams.moved(motion)


def camera_error(a: Cameras, b: Cameras) -> tuple[np.ndarray, np.ndarray]:
    """Per camera: rotation angle (degrees) and centre distance (metres) between ``a`` and ``b``."""
    Ra, Rb = a.world_to_cam[:, :3, :3], b.world_to_cam[:, :3, :3]
    cos = (np.einsum("cij,cij->c", Ra, Rb) - 1) / 2
    return np.rad2deg(np.arccos(np.clip(cos, -1, 1))), np.linalg.norm(a.centres() - b.centres(), axis=1)


def reprojection_error(model, poses: np.ndarray, a: Cameras, b: Cameras) -> np.ndarray:
    """Per camera, the median distance (pixels) between where ``a`` and ``b`` put the model's
    Gaussian centres at ``poses``: the part of a calibration error that images can show."""
    with torch.no_grad():
        mu = model._world_frames(torch.as_tensor(poses, dtype=torch.float32))[0].reshape(-1, 3).double().numpy()
    return np.median(np.linalg.norm(a.project(mu) - b.project(mu), axis=-1), axis=1)


# --------------------------------------------------------------------------------------------
# The experiment
# --------------------------------------------------------------------------------------------

SOURCE = dict(n=4, size=160, distance=1.5, elevation=-25.0, azimuth0=45.0, lookat=(0.0, 0.0, 0.45))
CROP = (22, 14, 128, 112)      # rows 22:150, columns 14:126 of 160 x 160: off-centre both ways


def make_targets(robot, n: int, seed: int, source: dict = SOURCE, crop=CROP):
    """Untouched renders (free cameras) and their transformed twin (hand-made OpenCV cameras)."""
    cams = ring_cameras(**source)
    poses = free_poses(robot, n, seed)
    v = make_views(robot, poses, cams, progress=False)
    plain = dict(rgb=v.rgb, depth=v.depth, mask=v.mask)
    moved = dict(rgb=transform_images(v.rgb, crop, rgb=True), depth=transform_images(v.depth, crop),
                 mask=transform_images(v.mask, crop))
    return poses, cams, plain, transform_cameras(cams, crop), moved


def starts_near(robot, poses: np.ndarray, rad: float, seed: int) -> np.ndarray:
    """``poses`` moved by ``rad`` on every hinge (sign random; reflected at a limit), 1 cm on slides."""
    rng = np.random.default_rng(seed)
    arm = np.array([t == "hinge" for t in robot.joint_types])
    step = np.where(arm, rad, 0.01) * rng.choice([-1.0, 1.0], size=poses.shape)
    lim = robot.joint_limits
    s = poses + step
    out = (s > lim[:, 1]) | (s < lim[:, 0])
    s[out] = (poses - step)[out]
    return np.clip(s, lim[:, 0], lim[:, 1])


def arm_error(robot, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    arm = np.array([t == "hinge" for t in robot.joint_types])
    return np.abs(a - b)[:, arm]


FIT = dict(iterations=60, lr=0.005, w_depth=10.0, coarse=dict(iterations=45, lr=0.02, w_depth=1.0))
FIT_NO_DEPTH = dict(iterations=60, lr=0.005, coarse=dict(iterations=45, lr=0.02))


ROWS = ("untouched", "crop_stretch_rotate", "textured_background_mask", "rgb_mask_no_depth", "miscalibrated_2deg_2cm",
        "miscalibrated_2deg_2cm_refined")


def run(robot, model, n: int, seed: int = 3, batch: int = 10, fit: dict = FIT, fit_no_depth: dict = FIT_NO_DEPTH,
        refine: dict | None = None, source: dict = SOURCE, crop=CROP, log=print, rows_wanted=ROWS) -> dict:
    poses, cams, plain, cams2, moved = make_targets(robot, n, seed, source, crop)
    start = starts_near(robot, poses, 0.1, seed)
    H, W = moved["mask"].shape[-2:]
    bg = texture((n, len(cams), H, W, 3), seed)
    textured = dict(rgb=np.where(moved["mask"][..., None], moved["rgb"], bg), mask=moved["mask"], depth=moved["depth"])
    rows = {}

    def fit_all(name, targets, cameras, kw):
        t0, out, cam_fits = time.perf_counter(), [], []
        for i in range(0, n, batch):
            sl = slice(i, min(n, i + batch))
            f = fit_pose(model, {k: v[sl] for k, v in targets.items()}, cameras, start[sl], **kw)
            out.append(f.poses)
            cam_fits.append(f.cameras)
        err = arm_error(robot, np.concatenate(out), poses)
        rows[name] = dict(median_joint_err_rad=float(np.median(err)), p90_joint_err_rad=float(np.quantile(err, 0.9)),
                          seconds=time.perf_counter() - t0)
        log(f"  {name}: median {rows[name]['median_joint_err_rad']:.4f} rad, p90 {rows[name]['p90_joint_err_rad']:.4f} "
            f"({rows[name]['seconds']:.0f} s)")
        return cam_fits

    log(f"{n} free targets, {len(cams)} views: untouched {cams.width}x{cams.height} free cameras; transformed "
        f"{cams2.width}x{cams2.height}, K[0] = {np.round(cams2.K[0], 2).tolist()}")
    no_depth = dict(rgb=textured["rgb"], mask=textured["mask"])
    for name, targets, cameras, kw in (("untouched", plain, cams, fit), ("crop_stretch_rotate", moved, cams2, fit),
                                       ("textured_background_mask", textured, cams2, fit),
                                       ("rgb_mask_no_depth", no_depth, cams2, fit_no_depth)):
        if name in rows_wanted:
            fit_all(name, targets, cameras, kw)
    wrong = miscalibrate(cams2, 2.0, 0.02, seed)
    if "miscalibrated_2deg_2cm" in rows_wanted:
        fit_all("miscalibrated_2deg_2cm", no_depth, wrong, fit_no_depth)
    if "miscalibrated_2deg_2cm_refined" not in rows_wanted:
        return dict(rows=rows, targets=n, views=len(cams), source=source, crop=crop, size=[cams2.width, cams2.height])
    deg0, m0 = camera_error(wrong, cams2)
    refine_kw = dict(fit_no_depth, refine_cameras=refine or True)
    fitted = fit_all("miscalibrated_2deg_2cm_refined", no_depth, wrong, refine_kw)
    deg1, m1 = zip(*(camera_error(c, cams2) for c in fitted))
    px0 = reprojection_error(model, poses, wrong, cams2)
    px1 = np.mean([reprojection_error(model, poses, c, cams2) for c in fitted], 0)
    rows["miscalibrated_2deg_2cm_refined"] |= dict(camera_err_before_deg=deg0.tolist(), camera_err_before_m=m0.tolist(),
                                                   camera_err_after_deg=np.mean(deg1, 0).tolist(),
                                                   camera_err_after_m=np.mean(m1, 0).tolist(),
                                                   reprojection_before_px=px0.tolist(), reprojection_after_px=px1.tolist())
    log(f"    cameras before: {np.round(deg0, 2)} deg, {np.round(100 * m0, 2)} cm, robot reprojected {np.round(px0, 2)} px "
        f"off; after refinement (mean over batches): {np.round(np.mean(deg1, 0), 2)} deg, "
        f"{np.round(100 * np.mean(m1, 0), 2)} cm, {np.round(px1, 2)} px")
    return dict(rows=rows, targets=n, views=len(cams), source=source, crop=crop, size=[cams2.width, cams2.height])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=20)
    ap.add_argument("--batch", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=os.path.join(HERE, "out", "real_rig"))
    ap.add_argument("--rows", default=",".join(ROWS), help=f"comma-separated subset of {', '.join(ROWS)}")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    os.makedirs(a.out, exist_ok=True)
    robot = profrobot.Robot.from_menagerie("franka_emika_panda")
    path = os.path.join(HERE, "out", "render", "panda_10000_600.safetensors")
    if not os.path.exists(path):
        print("fitting the Gaussian Panda (benches/render.py) ...", flush=True)
        import importlib.util
        spec = importlib.util.spec_from_file_location("render_bench", os.path.join(HERE, "render.py"))
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        mod.main(["--skip-pose", "--skip-speed"])
    model = GaussianRobot.load(path, robot)
    print(f"load average {os.getloadavg()}, torch threads {a.threads}", flush=True)
    res = run(robot, model, a.targets, batch=a.batch, log=lambda s: print(s, flush=True), rows_wanted=a.rows.split(","))
    res["loadavg_end"] = os.getloadavg()
    with open(os.path.join(a.out, f"results_{len(res['rows'])}rows.json"), "w") as f:
        json.dump(res, f, indent=1)
    print(json.dumps(res["rows"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
