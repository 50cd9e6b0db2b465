"""Image helpers with no imaging library: PSNR, mask IoU, depth error, and a minimal PNG writer."""

from __future__ import annotations

import os
import struct
import zlib

import numpy as np

from ..files import atomic_path
from ..errors import InputError

__all__ = ["psnr", "mask_iou", "write_png", "to_uint8", "depth_to_rgb"]


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio (dB) of two images in [0, 1] (any shape, same shape)."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else -10.0 * np.log10(mse)


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    union = (a | b).sum()
    return 1.0 if union == 0 else float((a & b).sum() / union)


def to_uint8(img: np.ndarray) -> np.ndarray:
    """[0, 1] floats → uint8 (clipped)."""
    return np.clip(np.round(np.asarray(img, np.float64) * 255.0), 0, 255).astype(np.uint8)


def depth_to_rgb(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Depth (H, W) metres → grey (H, W, 3) in [0, 1], near bright; 0 (no depth) stays black."""
    g = np.where(depth > 0, 1.0 - (np.clip(depth, lo, hi) - lo) / max(hi - lo, 1e-9) * 0.8, 0.0)
    return np.repeat(g[..., None], 3, axis=-1)


def write_png(path: str | os.PathLike, img: np.ndarray) -> None:
    """Write an (H, W, 3) or (H, W) uint8 image as an 8-bit PNG (written atomically)."""
    img = np.asarray(img)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise InputError(f"write_png needs a uint8 (H, W) or (H, W, 3) array; got {img.dtype} {img.shape}")
    h, w = img.shape[:2]
    colour = 2 if img.ndim == 3 else 0
    raw = b"".join(b"\x00" + img[y].tobytes() for y in range(h))      # filter type 0 per row

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, colour, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(png)
