"""profrobot.render.distortion: OpenCV's 5-coefficient lens model and undistorting images once."""

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from profrobot.errors import InputError
from profrobot.render.distortion import check_distortion, distort_points, undistort_images, undistort_map

W, H = 160, 120
K0 = np.array([[150.0, 0, 83.7], [0, 138.0, 56.2], [0, 0, 1]])
K1 = np.array([[131.0, 0, 77.4], [0, 142.0, 61.9], [0, 0, 1]])
BARREL = np.array([-0.25, 0.08, 1e-3, -2e-3, 0.0])
PINCUSHION = np.array([0.3, 0.05, -1.5e-3, 1e-3, 0.01])


def _distort_ref(x, y, k1, k2, p1, p2, k3):
    """OpenCV's model written out term by term, one point at a time."""
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def _undistort_ref(xd, yd, k1, k2, p1, p2, k3, iters=200):
    """OpenCV's undistortPoints fixed-point iteration: the inverse of the model, independently."""
    x, y = xd.copy(), yd.copy()
    for _ in range(iters):
        r2 = x * x + y * y
        icdist = 1 / (1 + ((k3 * r2 + k2) * r2 + k1) * r2)
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) * icdist, (yd - dy) * icdist
    return x, y


# ---- distort_points -------------------------------------------------------------------------------
def test_distort_points_hand_computed_values():
    z = np.zeros(5)
    # pure k1 / k2 / k3 on the x axis: x_d = x (1 + k1 x^2 + k2 x^4 + k3 x^6), y stays 0
    assert np.allclose(distort_points([0.5, 0.0], z + [-0.2, 0, 0, 0, 0]), [0.475, 0.0], atol=1e-15)
    assert np.allclose(distort_points([0.5, 0.0], [0, 0.1, 0, 0, 0]), [0.503125, 0.0], atol=1e-15)
    assert np.allclose(distort_points([0.0, -0.5], [0, 0, 0, 0, 0.2]), [0.0, -0.5 * (1 + 0.2 / 64)], atol=1e-15)
    # tangential at (0.3, 0.4), r2 = 0.25: p1 adds (2 p1 x y, p1 (r2 + 2 y^2)), p2 adds (p2 (r2 + 2 x^2), 2 p2 x y)
    assert np.allclose(distort_points([0.3, 0.4], [0, 0, 0.01, 0, 0]), [0.3024, 0.4057], atol=1e-15)
    assert np.allclose(distort_points([0.3, 0.4], [0, 0, 0, 0.01, 0]), [0.3043, 0.4024], atol=1e-15)
    # a 4-vector is k3 = 0; the centre never moves
    assert np.allclose(distort_points([0.3, 0.4], [0, 0, 0, 0.01]), [0.3043, 0.4024], atol=1e-15)
    assert np.array_equal(distort_points(np.zeros(2), BARREL), np.zeros(2))


def test_distort_points_all_terms_and_batch_shape():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.6, 0.6, (3, 4, 2))
    out = distort_points(xy, PINCUSHION)
    assert out.shape == (3, 4, 2) and out.dtype == np.float64
    for i in np.ndindex(3, 4):
        assert np.allclose(out[i], _distort_ref(*xy[i], *PINCUSHION), atol=1e-14, rtol=0)
    with pytest.raises(InputError, match=r"xy must have shape \(\.\.\., 2\)"):
        distort_points(np.zeros((4, 3)), BARREL)
    with pytest.raises(InputError, match="dist must have shape"):
        distort_points(np.zeros(2), np.zeros((2, 5)))


# ---- undistort_map --------------------------------------------------------------------------------
@pytest.mark.parametrize("dist", [BARREL, PINCUSHION])
def test_undistort_map_inverts_to_the_pixel_grid(dist):
    """Undistorting the sample positions (OpenCV's iteration, written here) gives back each pixel."""
    m = undistort_map(K0, dist, W, H)
    assert m.shape == (H, W, 2) and m.dtype == np.float64
    fx, fy, cx, cy = K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2]
    x, y = _undistort_ref((m[..., 0] - cx) / fx, (m[..., 1] - cy) / fy, *dist)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    assert np.abs(fx * x + cx - u).max() < 1e-6 and np.abs(fy * y + cy - v).max() < 1e-6
    assert np.abs(m[..., 0] - u).max() > 5          # the distortion is visible
    assert np.array_equal(undistort_map(K0, np.zeros(5), W, H), np.stack([u, v], -1).astype(float))


def test_undistort_map_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    for K, dist in ((K0, BARREL), (K1, PINCUSHION), (K0, np.array([0.02, -0.01, 3e-3, -1e-3, 0.004]))):
        mx, my = cv2.initUndistortRectifyMap(K, dist, None, K, (W, H), cv2.CV_32FC1)
        m = undistort_map(K, dist, W, H)
        assert np.abs(m[..., 0] - mx).max() < 1e-3 and np.abs(m[..., 1] - my).max() < 1e-3


def test_undistort_map_bad_input():
    with pytest.raises(InputError, match=r"K must have shape \(3, 3\)"):
        undistort_map(np.eye(4), BARREL, W, H)
    with pytest.raises(InputError, match="no skew"):
        undistort_map(K0 + [[0, 1, 0], [0, 0, 0], [0, 0, 0]], BARREL, W, H)
    with pytest.raises(InputError, match="image size"):
        undistort_map(K0, BARREL, 0, H)


# ---- undistort_images: a synthetic scene --------------------------------------------------------
def _blobs(centres, sigma=1.5):
    """(H, W) sum of unit Gaussian blobs at ``centres`` (P, 2) pixels (u, v)."""
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    return sum(np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / (2 * sigma ** 2)) for cu, cv in centres)


def _centroid(img, near, r=5):
    """Intensity-weighted centroid (u, v) of ``img`` (H, W) in the (2r+1)^2 window around ``near``."""
    iu, iv = np.rint(near).astype(int)
    win = img[iv - r:iv + r + 1, iu - r:iu + r + 1].astype(np.float64)
    u, v = np.meshgrid(np.arange(iu - r, iu + r + 1), np.arange(iv - r, iv + r + 1))
    return np.array([(win * u).sum(), (win * v).sum()]) / win.sum()


def test_undistorted_blobs_land_on_the_pinhole_projection():
    rng = np.random.default_rng(1)
    Ks, dists = np.stack([K0, K1]), np.stack([BARREL, [-0.18, 0.03, -2e-3, 1.5e-3, -0.01]])
    # 12 points in camera coordinates (metres) spread over the image
    uu, vv = np.meshgrid([22.0, 62.0, 101.0, 139.0], [21.0, 59.0, 98.0])
    pix = np.stack([uu.ravel(), vv.ravel()], -1) + rng.uniform(-0.5, 0.5, (12, 2))
    z = rng.uniform(0.5, 3.0, 12)
    colour = np.array([1.0, 0.5, 0.25])
    rgb = np.zeros((2, 2, H, W, 3))
    pinhole = []
    for c in range(2):
        K = Ks[c]
        q = z[:, None] * np.c_[(pix - K[:2, 2]) / K[[0, 1], [0, 1]], np.ones(12)]       # (12, 3) metres
        xy = q[:, :2] / q[:, 2:]
        p = xy * K[[0, 1], [0, 1]] + K[:2, 2]                                          # K @ (x/z, y/z)
        pd = distort_points(xy, dists[c]) * K[[0, 1], [0, 1]] + K[:2, 2]               # where the lens puts them
        assert np.linalg.norm(pd - p, axis=1).max() > 2.0                              # visibly distorted
        img = _blobs(pd)
        rgb[0, c], rgb[1, c] = img[..., None] * colour, 0.5 * img[..., None] * colour
        pinhole.append(p)
    for images in (rgb, rgb.astype(np.float32), np.rint(255 * np.clip(rgb, 0, 1)).astype(np.uint8)):
        out = undistort_images(images, Ks, dists, kind="rgb")
        assert out.shape == images.shape and out.dtype == images.dtype
        for b in range(2):
            for c in range(2):
                for p in pinhole[c]:
                    for ch in range(3):
                        err = np.linalg.norm(_centroid(out[b, c, ..., ch], p) - p)
                        assert err < 0.2, (images.dtype, b, c, p, ch, err)
    # a camera is its own map: swapping the dists moves the blobs off their projections
    wrong = undistort_images(rgb[:1], Ks, dists[::-1], kind="rgb")
    errs = [np.linalg.norm(_centroid(wrong[0, 0, ..., 0], p) - p) for p in pinhole[0]]
    assert max(errs) > 1.0


def test_rgb_matches_scipy_bilinear_and_outside_is_zero():
    rng = np.random.default_rng(2)
    img = rng.uniform(0.1, 1.0, (1, H, W, 3))
    out = undistort_images(img, K0[None], PINCUSHION[None], kind="rgb")
    m = undistort_map(K0, PINCUSHION, W, H)
    inside = (m[..., 0] >= -0.5) & (m[..., 0] <= W - 0.5) & (m[..., 1] >= -0.5) & (m[..., 1] <= H - 0.5)
    assert 0 < (~inside).sum() < 0.5 * inside.size                    # pincushion: the corners fall outside
    for ch in range(3):
        ref = map_coordinates(img[0, ..., ch], [m[..., 1], m[..., 0]], order=1, mode="nearest")
        assert np.allclose(out[0, ..., ch][inside], ref[inside], atol=1e-12)
        assert (out[0, ..., ch][~inside] == 0).all()
    # uint8 stays uint8, rounded from the same bilinear values
    img8 = rng.integers(0, 256, (2, 1, H, W, 3), dtype=np.uint8)
    out8 = undistort_images(img8, K0[None], PINCUSHION[None], kind="rgb")
    ref8 = np.rint(undistort_images(img8.astype(np.float64), K0[None], PINCUSHION[None], kind="rgb"))
    assert out8.dtype == np.uint8 and np.array_equal(out8, ref8.astype(np.uint8))


# ---- mask and depth ---------------------------------------------------------------------------------
def test_depth_is_never_blended_and_mask_is_bool():
    rng = np.random.default_rng(3)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    robot = (u - 70) ** 2 / 40 ** 2 + (v - 60) ** 2 / 30 ** 2 < 1
    depth = np.where(robot, 0.8 + 0.1 * (u > 70), 3.2).astype(np.float32)           # three depths
    depth = np.stack([depth, depth[:, ::-1]])[None].repeat(2, axis=0)                 # (2, 2, H, W)
    Ks, dists = np.stack([K0, K1]), np.stack([PINCUSHION, BARREL])
    out = undistort_images(depth, Ks, dists, kind="depth")
    assert out.shape == depth.shape and out.dtype == np.float32
    assert set(np.unique(out)) <= set(np.unique(depth)) | {0.0}
    assert (out[:, 0] == 0).any() and not (out[:, 1] == 0).any()       # pincushion corners are outside, barrel's not
    # nearest: each output is the input at the rounded sample position
    m = undistort_map(K1, BARREL, W, H)
    iu, iv = np.floor(m[..., 0] + 0.5).astype(int), np.floor(m[..., 1] + 0.5).astype(int)
    assert np.array_equal(out[1, 1], depth[1, 1][iv, iu])

    mask = np.stack([robot, robot[:, ::-1]])[None] & (rng.uniform(size=(3, 1, 1, 1)) < 2)   # (3, 2, H, W)
    mout = undistort_images(mask, Ks, dists, kind="mask")
    assert mout.dtype == np.bool_ and mout.shape == mask.shape
    ref = map_coordinates(mask[0, 0].astype(float), [undistort_map(K0, PINCUSHION, W, H)[..., 1],
                                                     undistort_map(K0, PINCUSHION, W, H)[..., 0]], order=1, mode="nearest")
    assert np.array_equal(mout[0, 0], ref >= 0.5)                      # the mask is far from the edge
    assert np.array_equal(undistort_images(mask.astype(np.uint8), Ks, dists, kind="mask"), mout)
    assert 0.8 < mout[0, 0].sum() / mask[0, 0].sum() < 1.25


def test_no_distortion_returns_the_input():
    img = np.zeros((2, H, W, 3), np.uint8)
    Ks = np.stack([K0, K1])
    assert undistort_images(img, Ks, None, kind="rgb") is img
    assert undistort_images(img, Ks, np.zeros((2, 5)), kind="rgb") is img
    depth = img[..., 0]
    assert undistort_images(depth, Ks, [0, 0, 0, 0], kind="depth") is depth
    # a camera without distortion beside one with: its images are copied exactly
    depth = np.random.default_rng(4).uniform(0.5, 2.0, (2, H, W))
    out = undistort_images(depth, Ks, np.stack([np.zeros(5), BARREL]), kind="depth")
    assert np.array_equal(out[0], depth[0]) and not np.array_equal(out[1], depth[1])


# ---- check_distortion and bad input ---------------------------------------------------------------------
def test_check_distortion_shapes():
    assert check_distortion(None, 3) is None
    assert check_distortion(np.zeros(5), 3) is None and check_distortion(np.zeros((3, 4)), 3) is None
    d = check_distortion([0.1, -0.2, 1e-3, 2e-3], 3)
    assert d.shape == (3, 5) and d.dtype == np.float64 and np.array_equal(d[2], [0.1, -0.2, 1e-3, 2e-3, 0])
    per = np.arange(10.0).reshape(2, 5)
    d = check_distortion(per, 2)
    assert np.array_equal(d, per) and d is not per
    d[0, 0] = 99
    assert per[0, 0] == 0                                                 # a copy
    assert np.array_equal(check_distortion(np.arange(8.0).reshape(2, 4), 2)[:, 4], [0, 0])
    for n in (8, 12, 14):                                                 # extra coefficients that are 0: dropped
        v = np.r_[BARREL, np.zeros(n - 5)]
        assert np.array_equal(check_distortion(v, 1), BARREL[None])
        assert np.array_equal(check_distortion(np.stack([v, v]), 2), np.stack([BARREL, BARREL]))


def test_check_distortion_errors():
    with pytest.raises(InputError, match=r"distortion has 8 coefficients .*distortion\[5\] \(k4\).*only k1, k2, p1, p2, k3 are supported"):
        check_distortion(np.r_[BARREL, 0.1, 0, 0], 2)
    with pytest.raises(InputError, match=r"distortion has 14 coefficients .*distortion\[1, 12\] \(tauX\)"):
        check_distortion(np.stack([np.zeros(14), np.r_[np.zeros(12), 0.01, 0]]), 2)
    with pytest.raises(InputError, match="12 coefficients"):
        check_distortion(np.r_[np.zeros(8), 1e-3, 0, 0, 0], 1)
    with pytest.raises(InputError, match="6 coefficients"):
        check_distortion(np.zeros(6), 1)
    with pytest.raises(InputError, match=r"shape \(4,\), \(5,\), \(3, 4\) or \(3, 5\) for 3 cameras .*got \(2, 5\)$"):
        check_distortion(np.zeros((2, 5)), 3)
    bad = np.zeros((3, 5))
    bad[1, 2] = np.nan
    with pytest.raises(InputError) as e:
        check_distortion(bad, 3)
    assert str(e.value) == "cameras: distortion[1, 2] (p1) is nan"
    with pytest.raises(InputError, match=r"^Cameras.from_opencv: distortion\[4\] \(k3\) is inf$"):
        check_distortion([0, 0, 0, 0, np.inf], 2, "Cameras.from_opencv")
    with pytest.raises(InputError, match="must be numbers"):
        check_distortion("barrel", 1)


def test_undistort_images_bad_input():
    Ks, dists = np.stack([K0, K1]), np.stack([BARREL, PINCUSHION])
    rgb = np.zeros((2, H, W, 3))
    with pytest.raises(InputError, match=r"images must have shape \(\.\.\., 2, H, W, 3\) for kind='rgb' with 2 cameras"):
        undistort_images(rgb[..., 0], Ks, dists, kind="rgb")
    with pytest.raises(InputError, match=r"images must have shape \(\.\.\., 2, H, W\) for kind='depth'.*got \(3, 120, 160\)"):
        undistort_images(np.zeros((3, H, W)), Ks, dists, kind="depth")
    with pytest.raises(InputError, match=r"images must have shape \(\.\.\., 2, H, W, 3\)"):
        undistort_images(np.zeros((2, H, W, 4)), Ks, dists, kind="rgb")
    with pytest.raises(InputError, match=r"K must have shape \(C, 3, 3\)"):
        undistort_images(rgb, K0, dists, kind="rgb")
    with pytest.raises(InputError, match=r"distortion must have shape .* for 2 cameras"):
        undistort_images(rgb, Ks, np.zeros((3, 5)) + 0.1, kind="rgb")
    with pytest.raises(InputError, match=r"K\[1\] must be .*no skew"):
        undistort_images(rgb, np.stack([K0, K1 + [[0, 0.5, 0], [0, 0, 0], [0, 0, 0]]]), dists, kind="rgb")
    with pytest.raises(InputError, match="kind must be one of"):
        undistort_images(rgb, Ks, dists, kind="gray")
    with pytest.raises(InputError, match=r"distortion has 8 coefficients.*only k1, k2, p1, p2, k3"):
        undistort_images(rgb, Ks, np.c_[dists, np.zeros((2, 3)) + [0.1, 0, 0]], kind="rgb")
