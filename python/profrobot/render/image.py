"""Image helpers with no imaging library: PSNR, mask IoU, depth error, a minimal PNG writer and
the picture of a pose fit (:func:`fit_picture`)."""

from __future__ import annotations

import os
import struct
from pathlib import Path
import zlib

import numpy as np
import numpy.typing as npt

from ..files import atomic_path
from ..errors import InputError

__all__ = ["psnr", "mask_iou", "write_png", "to_uint8", "depth_to_rgb", "fit_mosaic", "fit_picture"]


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


_RENDER_TINT = np.array([0, 255, 0], np.float64)      # the render's silhouette in the overlay: green
_MASK_EDGE = np.array([255, 0, 255], np.uint8)        # the target mask's outline: magenta


def _as_rgb8(img: npt.ArrayLike, name: str) -> np.ndarray:
    a = np.asarray(img)
    if a.dtype == np.uint8:
        return a
    if not np.issubdtype(a.dtype, np.floating) or not np.isfinite(a).all():
        raise InputError(f"fit_picture: {name} must be uint8 or finite floats in [0, 1]; got {a.dtype}")
    return to_uint8(a)


def _edge(m: np.ndarray) -> np.ndarray:
    """The boundary pixels of boolean masks (..., H, W): in the mask, with a 4-neighbour outside."""
    p = np.pad(m, [(0, 0)] * (m.ndim - 2) + [(1, 1), (1, 1)])
    inner = p[..., :-2, 1:-1] & p[..., 2:, 1:-1] & p[..., 1:-1, :-2] & p[..., 1:-1, 2:]
    return m & ~inner


def fit_mosaic(target: npt.ArrayLike, render: npt.ArrayLike, alpha: npt.ArrayLike, *, mask: npt.ArrayLike | None = None,
               gap: int = 2) -> np.ndarray:
    """The picture of a fit as an (V·H + (V-1)·gap, 3·W + 2·gap, 3) uint8 array: one row per
    view, ``target | render | overlay``, white gaps of ``gap`` pixels.

    ``target`` (V, H, W, 3) the images fitted (uint8, or floats in [0, 1]); ``render`` (V, H, W, 3)
    the model drawn at the found pose from the same cameras (uint8 or [0, 1]); ``alpha`` (V, H, W)
    the render's opacity in [0, 1]; ``mask`` (V, H, W) bool, the target's robot mask, or None.
    The overlay is the target with the render's silhouette (``alpha > 1/2``) tinted green and
    outlined, and the target mask outlined in magenta: where the outlines part, the fit is off.
    """
    tgt, ren = _as_rgb8(target, "target"), _as_rgb8(render, "render")
    al = np.asarray(alpha, dtype=np.float64)
    if tgt.ndim != 4 or tgt.shape[-1] != 3 or ren.shape != tgt.shape or al.shape != tgt.shape[:3]:
        raise InputError(f"fit_picture: target and render must be (V, H, W, 3) and alpha (V, H, W), alike; got "
                         f"{tgt.shape}, {ren.shape} and {al.shape}")
    if not np.isfinite(al).all():
        raise InputError("fit_picture: alpha contains NaN or inf")
    gap = int(gap)
    if gap < 0:
        raise InputError(f"fit_picture: gap must be >= 0 pixels; got {gap}")
    V, H, W = al.shape
    drawn = al > 0.5
    a = 0.45 * np.clip(al, 0.0, 1.0)[..., None]
    over = (tgt * (1.0 - a) + _RENDER_TINT * a).round().astype(np.uint8)
    over[_edge(drawn)] = _RENDER_TINT.astype(np.uint8)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != al.shape:
            raise InputError(f"fit_picture: mask must have shape {al.shape}; got {m.shape}")
        over[_edge(m)] = _MASK_EDGE
    out = np.full((V * H + (V - 1) * gap, 3 * W + 2 * gap, 3), 255, np.uint8)
    for v in range(V):
        y = v * (H + gap)
        for col, img in enumerate((tgt[v], ren[v], over[v])):
            x = col * (W + gap)
            out[y:y + H, x:x + W] = img
    return out


def fit_picture(path: str | os.PathLike, target: npt.ArrayLike, render: npt.ArrayLike, alpha: npt.ArrayLike, *,
                mask: npt.ArrayLike | None = None, gap: int = 2) -> Path:
    """Write :func:`fit_mosaic` (one row per view: target | render | overlay) as a PNG to
    ``path``, atomically; returns the path."""
    write_png(path, fit_mosaic(target, render, alpha, mask=mask, gap=gap))
    return Path(path)
