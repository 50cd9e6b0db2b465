"""``profrobot pose``: a certified pose from a folder of photos, a calibration file and masks
(registered by :mod:`profrobot.cli`).

Input, on disk::

    DIR/                      --images: one target, its C views sorted by file name in the
      cam0.png  cam1.jpg ...    cameras' order (png, jpg, bmp, tif; EXIF orientation applied)
      masks/cam0.png ...      the robot masks (--masks, default DIR/masks): the same stems,
                                any image format, nonzero = robot
      depth/cam0.npy ...      optional metric depth (--depth, default DIR/depth if it exists):
                                (H, W) float metres, 0 off the robot
    cams.json                 --cameras: Cameras.save / Cameras.to_dict (K, world_to_cam, size,
                                optional OpenCV distortion); the images may be at any
                                resolution with the calibration's aspect ratio
    FIELD/                    --field: a PoseSDF checkpoint; its robot is the one it stores
                                (or --robot / --scene); --model is a GaussianRobot for that robot

Several targets: ``DIR/<target>/cam*.png`` (one subfolder per target, each with C images, in
name order), masks and depth mirrored (``DIR/masks/<target>/cam0.png``).

Output (``--out``, default ``./pose_out``), written atomically: ``poses.json`` (per target: the
pose by joint name in radians / metres, the exact labeller's verdict, the image loss; refined
cameras with ``--refine-cameras``) and ``fit.png`` (one row per view: target | render at the
found pose | overlay). Exit status 0 when every pose is certified collision-free, 1 when one is
not (the files are written all the same), 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError, RobotMismatchError
from ..files import atomic_path, format_tag
from .robots import numbers, robot_of

if TYPE_CHECKING:   # the torch side loads in the command that needs it
    from ..render.cameras import Cameras
    from ..render.gaussians import GaussianRobot

__all__ = ["cmd_pose", "read_folder", "read_image", "read_mask", "write_fit_picture", "IMAGE_SUFFIXES", "POSE_FORMAT"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
POSE_FORMAT = format_tag("pose", 1)
_PICTURE_SIDE = 480      # fit.png panels are at most this many pixels on a side


def _images_in(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                  key=lambda p: p.name)


def _open(path: Path):
    from PIL import Image, ImageOps, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.load()
            return ImageOps.exif_transpose(im)
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as e:
        raise InputError(f"{path}: not a readable image ({type(e).__name__}: {e})") from None


def read_image(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of the image at ``path`` (EXIF orientation applied)."""
    return np.asarray(_open(path).convert("RGB"))


def read_mask(path: Path) -> np.ndarray:
    """(H, W) bool robot mask of the image at ``path``: a pixel is robot where any colour channel
    (or a palette / grey value) is nonzero and, with an alpha channel, it is not transparent."""
    im = _open(path)
    a = np.asarray(im)
    if a.ndim == 2:
        return a != 0
    colour, alpha = (a[..., :-1], a[..., -1]) if im.mode in ("LA", "RGBA", "PA") else (a, None)
    m = (colour != 0).any(-1)
    return m if alpha is None else m & (alpha != 0)


def _companion(root: Path, rel: Path, suffixes: tuple) -> Path | None:
    """``root/rel`` with the first of ``suffixes`` that exists (``rel``'s own suffix first)."""
    for s in dict.fromkeys((rel.suffix, rel.suffix.lower(), *suffixes)):
        p = root / rel.with_suffix(s)
        if p.is_file():
            return p
    return None


def read_folder(images: str | Path, n_cameras: int, *, masks: str | Path | None = None,
                depth: str | Path | None = None) -> tuple[dict, list[str], list[list[str]]]:
    """The targets in the folder ``images`` (module docs) for ``n_cameras`` cameras →
    ``(targets, names, files)``: ``targets`` a dict of ``rgb`` (B, C, H, W, 3) uint8, ``mask``
    (B, C, H, W) bool and/or ``depth`` (B, C, H, W) float32 metres, as
    :func:`profrobot.pose_from_images` takes them; ``names`` (B,) the targets' names; ``files``
    (B, C) the image files used. ``masks`` (default ``images/masks`` if it exists) and ``depth``
    (default ``images/depth`` if it exists) mirror the images' layout with the same stems.

    Raises :class:`~profrobot.errors.InputError` naming the file or folder for: no images, a
    count of images other than ``n_cameras``, images of different sizes, a missing or unreadable
    image, mask or depth file, a mask or depth map of another size than its image, no masks and
    no depth.
    """
    root = Path(images)
    if not root.is_dir():
        raise InputError(f"--images {root}: no such folder")
    companions = {"masks", "depth"}
    files = _images_in(root)
    if files:
        groups = [(root.name, files)]
    else:
        groups = [(d.name, _images_in(d)) for d in sorted(p for p in root.iterdir() if p.is_dir())
                  if d.name not in companions]
        groups = [(name, fs) for name, fs in groups if fs]
        if not groups:
            raise InputError(f"--images {root}: no images ({', '.join(IMAGE_SUFFIXES)}) in it or in its subfolders "
                             "(one subfolder per target)")
    for name, fs in groups:
        if len(fs) != n_cameras:
            where = root if len(groups) == 1 else root / name
            raise InputError(f"--images {where}: {len(fs)} image{'s' * (len(fs) != 1)} ({', '.join(p.name for p in fs)}) "
                             f"but the calibration has {n_cameras} camera{'s' * (n_cameras != 1)}: one image per camera, "
                             "in the cameras' order (sorted by file name)")
    mask_root = Path(masks) if masks is not None else (root / "masks" if (root / "masks").is_dir() else None)
    depth_root = Path(depth) if depth is not None else (root / "depth" if (root / "depth").is_dir() else None)
    for flag, r in (("--masks", mask_root), ("--depth", depth_root)):
        if r is not None and not r.is_dir():
            raise InputError(f"{flag} {r}: no such folder")
    if mask_root is None and depth_root is None:
        raise InputError(f"--images {root}: no robot masks: put them in {root / 'masks'} (the images' names, nonzero = "
                         "robot) or pass --masks DIR (or --depth DIR: metric depth, 0 off the robot)")
    rgb: list[list] = []
    mask: list[list] = []
    dep: list[list] = []
    size, first = None, None
    for _, fs in groups:
        for rows in (rgb, mask, dep):
            rows.append([])
        for p in fs:
            img = read_image(p)
            if size is None:
                size, first = img.shape[:2], p
            elif img.shape[:2] != size:
                raise InputError(f"{p} is {img.shape[1]}x{img.shape[0]} pixels but {first} is {size[1]}x{size[0]}: every "
                                 "view must have the same size (resize them alike; the cameras follow)")
            rgb[-1].append(img)
            rel = p.relative_to(root)
            if mask_root is not None:
                mp = _companion(mask_root, rel, IMAGE_SUFFIXES)
                if mp is None:
                    raise InputError(f"{p}: no mask for it in {mask_root / rel.parent} (looked for {rel.stem}.* with "
                                     f"{', '.join(IMAGE_SUFFIXES)})")
                m = read_mask(mp)
                if m.shape != size:
                    raise InputError(f"{mp}: the mask is {m.shape[1]}x{m.shape[0]} pixels but its image {p} is "
                                     f"{size[1]}x{size[0]}")
                mask[-1].append(m)
            if depth_root is not None:
                dp = depth_root / rel.with_suffix(".npy")
                if not dp.is_file():
                    raise InputError(f"{p}: no depth map for it ({dp}: (H, W) metres, .npy)")
                try:
                    d = np.load(dp, allow_pickle=False)
                except (OSError, ValueError) as e:
                    raise InputError(f"{dp}: not a readable .npy depth map ({e})") from None
                if d.shape != size or not np.issubdtype(d.dtype, np.number):
                    raise InputError(f"{dp}: the depth map must be ({size[0]}, {size[1]}) numbers (metres), like its "
                                     f"image {p}; got {d.dtype} {d.shape}")
                if not np.isfinite(d).all() or (d < 0).any():
                    raise InputError(f"{dp}: depth must be finite and >= 0 metres (0 where there is no robot)")
                dep[-1].append(d.astype(np.float32))
    targets = dict(rgb=np.asarray(rgb, dtype=np.uint8))
    if mask_root is not None:
        targets["mask"] = np.asarray(mask, dtype=bool)
    if depth_root is not None:
        targets["depth"] = np.asarray(dep, dtype=np.float32)
    return targets, [n for n, _ in groups], [[p.name for p in fs] for _, fs in groups]


def _init(text: str | None, robot) -> np.ndarray:
    """``--init`` (K comma-separated radians / metres), else the middle of the joint limits."""
    lim = np.asarray(robot.joint_limits, dtype=np.float64)
    if text is None:
        return lim.mean(1)
    q = numbers(text, "init")
    if q.shape != (robot.njoint,) or not np.isfinite(q).all():
        raise InputError(f"--init needs {robot.njoint} finite values for {robot.name!r} "
                         f"({', '.join(robot.joint_names)}); got {len(q)}")
    return q


def _resize(img: np.ndarray, w: int, h: int, nearest: bool) -> np.ndarray:
    from PIL import Image

    if img.shape[1] == w and img.shape[0] == h:
        return img
    if img.dtype == np.bool_:
        return np.asarray(Image.fromarray(img.astype(np.uint8) * 255).resize((w, h), Image.Resampling.NEAREST)) > 127
    return np.asarray(Image.fromarray(img).resize((w, h), Image.Resampling.NEAREST if nearest else Image.Resampling.BILINEAR))


def write_fit_picture(path: Path, model: GaussianRobot, targets: dict, cameras: Cameras, poses: np.ndarray) -> Path:
    """fit.png (:func:`profrobot.render.image.fit_picture`): every target's views, undistorted as
    the fit saw them, the model drawn at ``poses`` (B, K) from the same pinhole cameras, and the
    overlay; panels scaled to at most 480 pixels on a side."""
    import torch

    from ..render.image import fit_picture, to_uint8
    from ..render.targets import as_pinhole_targets

    B = len(poses)
    t, pin = as_pinhole_targets(targets, cameras, B, "profrobot pose")
    C, H, W = len(pin), pin.height, pin.width
    s = min(1.0, _PICTURE_SIDE / max(H, W))
    w, h = max(1, round(W * s)), max(1, round(H * s))
    rgb = t["rgb"] if t["rgb"].dtype == np.uint8 else to_uint8(t["rgb"])
    rgb = np.stack([_resize(im, w, h, False) for im in rgb.reshape(B * C, H, W, 3)])
    mask = np.stack([_resize(m, w, h, True) for m in t["mask"].reshape(B * C, H, W)])
    small = pin.resized(w, h)
    with torch.no_grad():
        out = model.render_views(torch.as_tensor(poses, dtype=model.means.dtype, device=model.means.device), small)
    ren = out.rgb.reshape(B * C, h, w, 3).clamp(0, 1).cpu().numpy()
    alpha = out.alpha.reshape(B * C, h, w).cpu().numpy()
    return fit_picture(path, rgb, ren, alpha, mask=mask)


def _number(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def cmd_pose(args: argparse.Namespace) -> int:
    """``profrobot pose``: read the folder, fit with :func:`profrobot.pose_from_images` and the
    field, certify with the exact labeller, write ``poses.json`` and ``fit.png`` (module docs)."""
    from ..field import PoseSDF
    from ..render import Cameras, GaussianRobot
    from ..inverse.images import pose_from_images

    field = Path(args.field)
    cameras = Cameras.load(args.cameras)
    targets, names, files = read_folder(args.images, len(cameras), masks=args.masks, depth=args.depth)
    B, C, H, W = targets["rgb"].shape[:4]
    if abs(W / H - cameras.width / cameras.height) > 0.01 * cameras.width / cameras.height:
        raise InputError(f"--images {args.images}: the images are {W}x{H} pixels but {args.cameras} was calibrated at "
                         f"{cameras.width}x{cameras.height}, another aspect ratio (a rotated or cropped photo?): "
                         "images may be scaled, not cropped")
    robot = robot_of(args, field=field)   # --robot FILE, --scene NAME, or the robot the field stores
    try:
        sdf = PoseSDF.load(field, robot)
    except RobotMismatchError as e:
        raise RobotMismatchError(f"{e}; pass --robot FILE or --scene NAME for the robot the field was trained on") from None
    model = GaussianRobot.load(args.model, robot)
    init = _init(args.init, robot)
    print(f"profrobot pose: {B} target{'s' * (B != 1)} x {C} view{'s' * (C != 1)} of {W}x{H} pixels "
          f"({', '.join(files[0])}); robot {robot.name} ({robot.njoint} joints); field {field}; "
          f"model {args.model} ({model.n} Gaussians); {'depth, ' if 'depth' in targets else ''}"
          f"{'masks' if 'mask' in targets else 'no masks'}", flush=True)
    coarse = dict(iterations=max(1, args.iterations // 2), restarts=args.restarts) if args.restarts else None
    res = pose_from_images(model, targets, cameras, init=np.tile(init, (B, 1)), sdf=sdf, robot=robot,
                           image_iterations=args.iterations, field_iterations=args.field_iterations, lr=args.lr,
                           coarse=coarse, refine_cameras=bool(args.refine_cameras), seed=args.seed, progress=True)
    print(res.summary())
    assert res.certified is not None   # a field was given: every answer is certified
    out = Path(args.out)
    doc = dict(format=POSE_FORMAT, robot=robot.name, robot_fingerprint=robot.fingerprint,
               joint_names=list(robot.joint_names), certified=bool(res.certified.all()),
               targets=[dict(name=names[b], images=files[b],
                             pose={j: float(v) for j, v in zip(robot.joint_names, res.poses[b])},
                             certified=bool(res.certified[b]), image_loss=_number(res.image_loss[b]),
                             field=_number(res.g[b])) for b in range(B)],
               cameras=None if res.cameras is None else res.cameras.to_dict(), seconds=float(res.seconds))
    with atomic_path(out / "poses.json") as tmp:
        tmp.write_text(json.dumps(doc, indent=2))
    picture = write_fit_picture(out / "fit.png", model, targets, res.cameras or cameras, res.poses)
    for b in range(B):
        q = ", ".join(f"{v:+.3f}" for v in res.poses[b])
        print(f"  {names[b]}: [{q}] {'certified free' if res.certified[b] else 'NOT certified (collides)'}, "
              f"image loss {res.image_loss[b]:.4f}")
    print(f"saved {out / 'poses.json'} and {picture}")
    if not res.certified.all():
        bad = [names[b] for b in np.flatnonzero(~res.certified)]
        print(f"profrobot pose: {len(bad)} of {B} poses collide by the exact labeller ({', '.join(bad[:10])}): not "
              "certified; try more --field-iterations, --restarts or another --init", file=sys.stderr)
        return 1
    return 0
