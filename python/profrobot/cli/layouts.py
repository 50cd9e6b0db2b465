"""``profrobot layout``: a family's layout from depth images, a calibration and the robot's pose."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError, MissingFileError
from .robots import numbers, robot_of
from ..render.cameras import Cameras
from ..perception.layouts.estimate import estimate_layout


def _array(path: str, option: str) -> np.ndarray:
    p = Path(path)
    if not p.is_file():
        raise MissingFileError(f"--{option} {path}: no such file")
    try:
        a = np.load(p, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise InputError(f"--{option} {path}: not a readable .npy array ({e})") from None
    if not isinstance(a, np.ndarray):
        raise InputError(f"--{option} {path}: a .npy array, not an .npz archive")
    return a


def cmd_layout(args) -> int:
    """Estimate, print the summary, write the JSON (``--out``) and the picture (``--picture``).
    Exit 0 when every obstacle was estimated, 1 when some could not be (named)."""
    family = robot_of(args)
    depth = _array(args.depth, "depth")
    if depth.ndim == 2:  # one camera
        depth = depth[None]
    if not Path(args.cameras).is_file():
        raise MissingFileError(f"--cameras {args.cameras}: no such file (Cameras.save writes one)")
    cameras = Cameras.load(args.cameras)
    mask = None if args.mask is None else _array(args.mask, "mask")
    if mask is not None and mask.ndim == 2:
        mask = mask[None]
    est = estimate_layout(family, depth, cameras, pose=numbers(args.pose, "pose"), mask=mask,
                          depth_noise=(args.noise_a, args.noise_b), calibration=args.calibration)
    print(est.summary())
    for name, value in zip(est.scene_joints, est.layout):
        print(f"  {name} = {value:.6g}")
    print(f"pass margin={est.margin:.4g} (metres) to certification, planning and resolve; "
          f"--layout {','.join(f'{v:.6g}' for v in est.layout)}")
    if args.out:
        est.save(args.out)
        print(f"saved {args.out}")
    if args.picture:
        est.picture(family, args.picture)
        print(f"saved {args.picture}")
    return 0 if est.ok else 1
