"""Lens distortion: undistort target images once, so everything after sees a pinhole camera.

A camera with OpenCV's 5-coefficient ("plumb bob") distortion ``(k1, k2, p1, p2, k3)`` takes a
point ``q`` in camera coordinates (metres; x right, y down, z forward) to its normalised pinhole
coordinates ``x = q_x / q_z``, ``y = q_y / q_z`` (unitless), then *distorts* them

    r2     = x^2 + y^2
    radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
    x_d    = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d    = y radial + p1 (r2 + 2 y^2) + 2 p2 x y

and only then applies ``K`` (3, 3): ``u_d = fx x_d + cx``, ``v_d = fy y_d + cy`` (pixels, pixel
*centres* at integer coordinates, as in :mod:`profrobot.render.cameras`; ``K`` has no skew).

To turn a distorted image into the image a pinhole camera with the *same* ``K`` would take, each
pixel ``(u, v)`` of the undistorted image is unprojected with ``K^-1`` to ``(x, y)``, distorted to
``(x_d, y_d)`` with the forward model above, and projected with ``K`` to ``(u_d, v_d)``: the
undistorted pixel takes the distorted image's value there (:func:`undistort_map`, which is what
``cv2.initUndistortRectifyMap(K, dist, None, K, (W, H), cv2.CV_32FC1)`` computes; no inversion of
the distortion is needed). Sampling (:func:`undistort_images`):

- ``rgb``: bilinear (as ``scipy.ndimage.map_coordinates(order=1)``), the weights computed once per
  camera and reused over every leading axis;
- ``mask``: bilinear on the 0/1 mask, then ``>= 0.5``;
- ``depth``: nearest, so that the depth of the robot and of the background behind it are never
  blended into a depth that lies on neither.

The source image covers ``[-1/2, W - 1/2] x [-1/2, H - 1/2]`` (pixel edges); a sample within it
but beyond the outermost pixel centres takes the edge pixel's value, and a sample outside it gets
0 (``False`` for masks). With pincushion distortion (``k1 > 0``) the corners of the undistorted
image sample outside the source and are 0; with barrel distortion (``k1 < 0``) the rim of the
distorted image is cropped away instead.

The forward model is only monotonic out to some radius: far beyond the calibrated field of view a
polynomial with strong coefficients folds back, and the map (OpenCV's as well) then samples the
distorted image at a wrong, nearer place. Real calibrations fold, if at all, outside the image.

Only ``k1, k2, p1, p2, k3`` are supported: OpenCV's rational (``k4, k5, k6``), thin-prism
(``s1..s4``) and tilted (``tauX, tauY``) models, vectors of 8, 12 or 14 coefficients, are refused
unless every coefficient beyond the fifth is 0 (:func:`check_distortion`).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt

from ..errors import InputError

__all__ = ["check_distortion", "check_K", "check_image_size", "distort_points", "undistort_map", "undistort_images"]

_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tauX", "tauY")
_KINDS = ("rgb", "mask", "depth")


def check_distortion(dist: npt.ArrayLike | None, C: int, who: str = "cameras") -> np.ndarray | None:
    """Distortion coefficients of ``C`` cameras as a new (C, 5) float64 array ``(k1, k2, p1, p2,
    k3)`` (unitless), or None when ``dist`` is None or all zeros (pinhole cameras).

    ``dist``: None, one vector (4,) or (5,) shared by all cameras, or one per camera (C, 4) or
    (C, 5); a 4-vector ``(k1, k2, p1, p2)`` gets ``k3 = 0``. OpenCV's longer vectors (8, 12, 14
    coefficients) are accepted only when the coefficients beyond the fifth are all 0 (they are
    dropped). Errors (:class:`~profrobot.errors.InputError`) start with ``who`` and name the entry,
    e.g. ``"cameras: distortion[1, 2] (p1) is nan"``.
    """
    if dist is None:
        return None
    try:
        d = np.array(dist, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{who}: distortion must be numbers (k1, k2, p1, p2[, k3]) of shape (5,) or ({C}, 5); {e}") from None
    if d.ndim not in (1, 2) or (d.ndim == 2 and d.shape[0] != C):
        raise InputError(f"{who}: distortion must have shape (4,), (5,), ({C}, 4) or ({C}, 5) for {C} "
                         f"camera{'s' * (C != 1)} (OpenCV's k1, k2, p1, p2[, k3]); got {d.shape}")
    L = d.shape[-1]
    if L not in (4, 5, 8, 12, 14):
        raise InputError(f"{who}: distortion has {L} coefficients; expected OpenCV's k1, k2, p1, p2[, k3] "
                         f"(4 or 5 per camera), shape {d.shape}")
    where = (lambda idx: f"distortion[{', '.join(map(str, idx))}] ({_NAMES[idx[-1]]})")
    bad = np.argwhere(~np.isfinite(d))
    if len(bad):
        idx = tuple(int(i) for i in bad[0])
        raise InputError(f"{who}: {where(idx)} is {d[idx]}")
    if L > 5:
        extra = np.argwhere(d[..., 5:] != 0)
        if len(extra):
            idx = tuple(int(i) for i in extra[0])
            idx = idx[:-1] + (idx[-1] + 5,)
            raise InputError(f"{who}: distortion has {L} coefficients (OpenCV's rational / thin-prism / tilted model) "
                             f"and {where(idx)} = {d[idx]} is not 0; only k1, k2, p1, p2, k3 are supported (a longer "
                             f"vector whose coefficients beyond the 5th are all 0 may be given: they are dropped)")
        d = d[..., :5]
    if L == 4:
        d = np.concatenate([d, np.zeros(d.shape[:-1] + (1,))], axis=-1)
    if not d.any():
        return None
    return np.broadcast_to(d, (C, 5)).copy()


def _one_dist(dist, who: str) -> np.ndarray:
    """One camera's coefficients (5,) float64 (zeros for None)."""
    if dist is not None and np.ndim(dist) != 1:
        raise InputError(f"{who}: dist must have shape (5,) (k1, k2, p1, p2, k3) or (4,); got {np.shape(dist)}")
    d = check_distortion(dist, 1, who)
    return np.zeros(5) if d is None else d[0]


def check_image_size(width: int, height: int, who: str) -> tuple[int, int]:
    """``(width, height)`` as positive integers (pixels), else :class:`InputError` naming ``who``."""
    try:
        w, h = int(width), int(height)
    except (TypeError, ValueError):
        raise InputError(f"{who}: width and height must be integers (pixels); got {width!r}, {height!r}") from None
    if w < 1 or h < 1 or w != width or h != height:
        raise InputError(f"{who}: image size must be positive integers; got {width}x{height}")
    return w, h


def check_K(K: npt.ArrayLike, shape: tuple, who: str) -> np.ndarray:
    """``K`` as float64 of ``shape`` (…, 3, 3), each [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], fx, fy > 0."""
    try:
        k = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{who}: K must be numbers of shape {shape}; {e}") from None
    if k.shape != shape:
        raise InputError(f"{who}: K must have shape {shape}; got {k.shape}")
    flat = k.reshape(-1, 3, 3)
    for c, m in enumerate(flat):
        name = "K" if k.ndim == 2 else f"K[{c}]"
        if not np.isfinite(m).all():
            raise InputError(f"{who}: {name} contains NaN or inf")
        if m[0, 1] != 0 or m[1, 0] != 0 or (m[2] != [0, 0, 1]).any():
            raise InputError(f"{who}: {name} must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew); got {m.tolist()}")
        if m[0, 0] <= 0 or m[1, 1] <= 0:
            raise InputError(f"{who}: {name} has focal lengths fx={m[0, 0]}, fy={m[1, 1]}; both must be positive (pixels)")
    return k


def distort_points(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's forward distortion (module docs) of normalised pinhole coordinates ``xy`` (..., 2)
    (``(x/z, y/z)``, unitless) with ``dist`` (5,) ``(k1, k2, p1, p2, k3)`` (or (4,)): the distorted
    normalised coordinates ``(x_d, y_d)`` (..., 2) float64, to which ``K`` is then applied."""
    who = "distort_points"
    try:
        p = np.asarray(xy, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"{who}: xy must be numbers of shape (..., 2); {e}") from None
    if p.ndim < 1 or p.shape[-1] != 2:
        raise InputError(f"{who}: xy must have shape (..., 2) (normalised x/z, y/z); got {p.shape}")
    k1, k2, p1, p2, k3 = _one_dist(dist, who)
    x, y = p[..., 0], p[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort_map(K: np.ndarray, dist: np.ndarray, width: int, height: int) -> np.ndarray:
    """For each pixel ``(u, v)`` of the undistorted ``width`` x ``height`` image (pinhole ``K``,
    pixel centres at integers), the position ``(u_d, v_d)`` (pixels) to sample in the distorted
    image taken with ``K`` (3, 3) and ``dist`` (5,) ``(k1, k2, p1, p2, k3)``: an (H, W, 2) float64
    array, ``[..., 0]`` the column ``u_d`` and ``[..., 1]`` the row ``v_d``. The same values as
    ``cv2.initUndistortRectifyMap(K, dist, None, K, (W, H), cv2.CV_32FC1)`` (in float64); all-zero
    ``dist`` gives the pixel grid exactly."""
    who = "undistort_map"
    k = check_K(K, (3, 3), who)
    d = _one_dist(dist, who)
    W, H = check_image_size(width, height, who)
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    out = np.stack([u, v], axis=-1)
    if not d.any():
        return out
    xy = np.stack([(u - cx) / fx, (v - cy) / fy], axis=-1)
    xyd = distort_points(xy, d)
    out[..., 0] = fx * xyd[..., 0] + cx
    out[..., 1] = fy * xyd[..., 1] + cy
    return out


def _bilinear(m: np.ndarray, W: int, H: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices (4, H·W) into an (H·W)-flattened image and their weights (4, H·W) for
    bilinear samples at ``m`` (H, W, 2) with the edge pixel extended to the image edge
    ``[-1/2, W - 1/2]``; weights are 0 for samples outside it (or non-finite)."""
    u, v = m[..., 0].ravel(), m[..., 1].ravel()
    inside = (u >= -0.5) & (u <= W - 0.5) & (v >= -0.5) & (v <= H - 0.5)   # False for NaN
    uc, vc = np.clip(np.where(inside, u, 0), 0, W - 1), np.clip(np.where(inside, v, 0), 0, H - 1)
    u0 = np.clip(np.floor(uc), 0, max(W - 2, 0)).astype(np.intp)
    v0 = np.clip(np.floor(vc), 0, max(H - 2, 0)).astype(np.intp)
    fu, fv = uc - u0, vc - v0                     # in [0, 1]; 0 when W (or H) is 1
    u1, v1 = np.minimum(u0 + 1, W - 1), np.minimum(v0 + 1, H - 1)
    idx = np.stack([v0 * W + u0, v0 * W + u1, v1 * W + u0, v1 * W + u1])
    w = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv]) * inside
    return idx, w


def _nearest(m: np.ndarray, W: int, H: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat index (H·W,) of the nearest pixel to each sample ``m`` (H, W, 2) and whether the
    sample lies in the image ``[-1/2, W - 1/2) x [-1/2, H - 1/2)`` (H·W,) bool."""
    with np.errstate(invalid="ignore"):
        iu, iv = np.floor(m[..., 0].ravel() + 0.5), np.floor(m[..., 1].ravel() + 0.5)
        inside = (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
    iu, iv = np.where(inside, iu, 0).astype(np.intp), np.where(inside, iv, 0).astype(np.intp)
    return iv * W + iu, inside


def undistort_images(images: np.ndarray, K: npt.ArrayLike, dist: npt.ArrayLike | None, *,
                     kind: Literal["rgb", "mask", "depth"]) -> np.ndarray:
    """Images taken by C distorted cameras resampled to the pinhole cameras with the same ``K``.

    ``images``: (..., C, H, W, 3) for ``kind="rgb"`` (any integer or float dtype: integers are
    rounded and stay in their dtype, floats stay floats), (..., C, H, W) for ``"mask"`` (bool or
    0/1; nonzero is True) and ``"depth"`` (metres, any dtype); ``K`` (C, 3, 3) pixels; ``dist``
    (C, 5) ``(k1, k2, p1, p2, k3)`` (or anything :func:`check_distortion` accepts), or None.
    Camera ``c`` uses ``K[c]`` and ``dist[c]``; its map (:func:`undistort_map`) is computed once
    and reused over the leading axes. Sampling (module docs): bilinear for rgb, bilinear then
    ``>= 0.5`` for mask (bool out), nearest for depth; samples outside the source image are 0.
    A new array of the input's shape; ``images`` itself, unchanged, when ``dist`` is None or all
    zeros.
    """
    who = "undistort_images"
    if kind not in _KINDS:
        raise InputError(f"{who}: kind must be one of {_KINDS}; got {kind!r}")
    if dist is None:
        return images
    if np.ndim(K) != 3:
        raise InputError(f"{who}: K must have shape (C, 3, 3) (one per camera); got {np.shape(K)}")
    C = int(np.shape(K)[0])
    k = check_K(K, (C, 3, 3), who)
    d = check_distortion(dist, C, who)
    img = np.asarray(images)
    tail = 3 if kind == "rgb" else 2
    expect = f"(..., {C}, H, W, 3)" if kind == "rgb" else f"(..., {C}, H, W)"
    if img.ndim < tail + 1 or img.shape[-tail - 1] != C or (kind == "rgb" and img.shape[-1] != 3):
        raise InputError(f"{who}: images must have shape {expect} for kind={kind!r} with {C} camera{'s' * (C != 1)} "
                         f"(K is {k.shape}); got {img.shape}")
    if d is None:
        return images
    if kind == "rgb" and not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)):
        raise InputError(f"{who}: rgb images must be integers (e.g. uint8) or floats; got dtype {img.dtype}")
    if kind == "mask" and not (img.dtype == np.bool_ or np.issubdtype(img.dtype, np.number)):
        raise InputError(f"{who}: masks must be bool or numbers (0/1); got dtype {img.dtype}")
    H, W = img.shape[-tail:][:2]
    lead = img.shape[:-tail - 1]
    out = np.empty(img.shape, dtype=np.bool_ if kind == "mask" else img.dtype)
    chan = (3,) if kind == "rgb" else ()
    for c in range(C):
        at = (Ellipsis, c) + (slice(None),) * tail          # camera c: (..., H, W[, 3])
        src = img[at]
        if not d[c].any():
            out[at] = src != 0 if kind == "mask" else src
            continue
        m = undistort_map(k[c], d[c], W, H)
        flat = src.reshape(lead + (H * W,) + chan)
        axis = len(lead)
        if kind == "depth":
            idx, inside = _nearest(m, W, H)
            res = np.where(inside, np.take(flat, idx, axis=axis), np.zeros((), flat.dtype))
        else:
            idx, w = _bilinear(m, W, H)
            if kind == "mask":
                flat = flat != 0
            wb = w[..., None] if kind == "rgb" else w
            res = sum(np.take(flat, idx[j], axis=axis) * wb[j] for j in range(4))
            if kind == "mask":
                res = res >= 0.5
            elif np.issubdtype(img.dtype, np.integer):
                info = np.iinfo(img.dtype)
                res = np.clip(np.rint(res), info.min, info.max)
        out[at] = res.reshape(lead + (H, W) + chan)
    return out
