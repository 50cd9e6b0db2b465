//! Tile-based Gaussian-splat rasterization on the CPU: forward compositing and its exact
//! backward, over Gaussians already projected to the image (2D means, conics, opacities,
//! colours, camera depths). Projection stays in torch, so autograd carries these gradients on
//! to joint angles, Gaussian parameters and cameras; this file knows nothing of either.
//!
//! # The image model (identical to `render/rasterize.py: _rasterize_torch`)
//! For camera `c` and pixel `p = (x, y)` (pixel centres at integer coordinates), each
//! Gaussian `i` with centre `u_i`, conic `Q_i = [[a, b], [b, c]]` (the inverse 2D covariance)
//! and opacity `o_i` gives
//!
//! ```text
//! d = p - u_i,   q_i = a dx² + 2 b dx dy + c dy²,   G_i = exp(-q_i / 2)
//! α_i = min(0.99, o_i G_i) - 1/255   (soft cutoff, kept when > 0)
//! α_i = min(0.99, o_i G_i)           (hard cutoff, kept when o_i G_i >= 1/255)
//! ```
//!
//! Front to back by camera depth `z`, `T_i = Π_{j<i} (1 - α_j)`, `w_i = α_i T_i`; a pixel
//! stops at the first Gaussian after which `T` would fall below `1e-4` (that one is not
//! composited). Outputs per pixel: `rgb = Σ w_i c_i`, `alpha = Σ w_i`, `dsum = Σ w_i z_i`
//! (torch turns `dsum / alpha` into expected depth and adds the background), and per
//! Gaussian `contrib = max_p w_i(p)`.
//!
//! # Tiles
//! Each camera's image is cut into `TILE × TILE` tiles. A Gaussian is listed in every tile its
//! pixel box meets; the box is the tight bounding box of the ellipse where `o G >= 1/255`,
//! half-widths `sqrt(k Σ_xx)`, `sqrt(k Σ_yy)` with `k = 2 ln(255 o)` and `Σ = Q⁻¹`. Every
//! pixel outside it has `o G < 1/255` (because `q >= dx²/Σ_xx`), hence α ≤ 0 under either
//! cutoff: the lists lose nothing, and the output equals compositing every Gaussian.
//! Each tile's list is sorted by `(z, Gaussian index)`, a total order, so the result is the
//! same whatever sorts it.
//!
//! # Backward
//! With per-pixel upstream gradients `g_rgb`, `g_alpha`, `g_dsum`, let `F_i = g_rgb·c_i +
//! g_alpha + g_dsum z_i`, so the pixel's loss is `L = Σ_i w_i F_i`. Then
//!
//! ```text
//! ∂L/∂c_i = w_i g_rgb,   ∂L/∂z_i = w_i g_dsum,
//! ∂L/∂α_i = T_i F_i - (Σ_{j>i} w_j F_j) / (1 - α_i)
//! ```
//!
//! walked back to front from the pixel's last composited Gaussian, recovering
//! `T_i = T_{i+1} / (1 - α_i)` from the final transmittance (f64 throughout; α ≤ 0.99 keeps
//! the division finite), and chained through `α(o G)`, `G(q)` and `q(u, v, a, b, c)`.
//!
//! # Determinism
//! Pixels are independent in the forward. In the backward each tile writes the gradients of
//! its own list entries (no shared accumulator); each Gaussian then sums its entries in a
//! fixed order (its tiles in row-major order). Results are bit-identical for any thread count.

use rayon::prelude::*;

use crate::error::{invalid_input, Result};

/// Tile side in pixels.
pub const TILE: usize = 8;
/// α below which a pair does not contribute (3DGS).
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// α is clamped to at most this (keeps `1 - α` away from 0).
pub const ALPHA_MAX: f64 = 0.99;
/// A pixel stops compositing before its transmittance would drop below this.
pub const T_MIN: f64 = 1e-4;
/// Gaussians closer to the camera than this (metres) are not drawn.
pub const NEAR: f64 = 0.01;

/// How α is cut at `1/255` (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cutoff {
    /// `max(0, α - 1/255)`: continuous, so gradients match finite differences.
    Soft,
    /// 3DGS: α below `1/255` is dropped.
    Hard,
}

/// Projected Gaussians of `cameras` cameras, `n` per camera (row-major arrays).
#[derive(Clone, Debug)]
pub struct Splats {
    pub cameras: usize,
    pub n: usize,
    pub width: usize,
    pub height: usize,
    /// `[C, N, 2]` pixel centres.
    pub uv: Vec<f64>,
    /// `[C, N, 3]` `(a, b, c)` of the conic `[[a, b], [b, c]]` (px⁻²).
    pub conic: Vec<f64>,
    /// `[C, N]`.
    pub opacity: Vec<f64>,
    /// `[C, N, 3]`.
    pub color: Vec<f64>,
    /// `[C, N]` camera depth, metres.
    pub depth: Vec<f64>,
    pub cutoff: Cutoff,
}

/// Forward outputs; `state` is what the backward needs.
#[derive(Clone, Debug)]
pub struct Forward {
    /// `[C, H, W, 3]` `Σ w c` (no background).
    pub rgb: Vec<f64>,
    /// `[C, H, W]` `Σ w`.
    pub alpha: Vec<f64>,
    /// `[C, H, W]` `Σ w z`.
    pub dsum: Vec<f64>,
    /// `[C, N]` each Gaussian's largest blending weight.
    pub contrib: Vec<f64>,
    /// Composited (pixel, Gaussian) pairs.
    pub npairs: u64,
    pub state: State,
}

/// The tile lists and each pixel's compositing end, kept for the backward.
#[derive(Clone, Debug)]
pub struct State {
    pub splats: Splats,
    bins: Bins,
    packed: Vec<Packed>,
    /// `[C, H, W]` transmittance after the last composited Gaussian.
    t_final: Vec<f64>,
    /// `[C, H, W]` list entries visited up to and including the last composited one.
    last: Vec<u32>,
}

/// Gradients of a scalar loss w.r.t. every input of [`Splats`], same layouts.
#[derive(Clone, Debug)]
pub struct Grads {
    pub uv: Vec<f64>,
    pub conic: Vec<f64>,
    pub opacity: Vec<f64>,
    pub color: Vec<f64>,
    pub depth: Vec<f64>,
}

/// Tile lists. An *entry* is one (Gaussian, tile) incidence; entries are numbered
/// Gaussian-major (`gauss_start[g]..gauss_start[g + 1]` are Gaussian `g`'s tiles in row-major
/// order), and `order` lists them tile by tile, depth-sorted within a tile
/// (`tile_start[t]..tile_start[t + 1]` for global tile `t = camera * tiles + tile`).
#[derive(Clone, Debug)]
struct Bins {
    tiles_x: usize,
    tiles_y: usize,
    gauss_start: Vec<usize>,
    /// Per entry: its Gaussian's flat index `camera * N + i`.
    entry_gauss: Vec<u32>,
    order: Vec<u32>,
    tile_start: Vec<usize>,
    /// Per Gaussian: the rows `[y0, y1]` of its pixel box.
    rows: Vec<[u32; 2]>,
}

/// `floor` without a libm call (x86-64 without SSE4.1 has no rounding instruction); exact for
/// |x| < 2⁵³, and the callers clamp to the image afterwards, so saturation beyond is harmless.
#[inline(always)]
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// `ceil`, as [`floor`].
#[inline(always)]
fn ceil(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t < x {
        t + 1.0
    } else {
        t
    }
}

/// Pixel box `[x0, x1] × [y0, y1]` (inclusive, clipped to the image) of a drawable Gaussian.
struct PixelBox {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
}

impl Splats {
    fn check(&self) -> Result<()> {
        let (c, n) = (self.cameras, self.n);
        if c == 0 {
            return invalid_input("rasterize: no cameras");
        }
        if n == 0 {
            return invalid_input("rasterize: the Gaussian set is empty (N = 0)");
        }
        if self.width == 0 || self.height == 0 {
            return invalid_input(format!("rasterize: image size must be positive; got {}x{}", self.width, self.height));
        }
        if (c * self.tiles_x() * self.tiles_y()) as u64 > u32::MAX as u64 || (c * n) as u64 > u32::MAX as u64 {
            return invalid_input("rasterize: too many cameras, tiles or Gaussians for 32-bit indices");
        }
        for (name, v, per) in [
            ("means2d", &self.uv, 2),
            ("conics", &self.conic, 3),
            ("opacities", &self.opacity, 1),
            ("colors", &self.color, 3),
            ("depths", &self.depth, 1),
        ] {
            if v.len() != c * n * per {
                return invalid_input(format!("rasterize: {name} holds {} values; expected {c} x {n} x {per}", v.len()));
            }
            if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                let g = k / per;
                return invalid_input(format!("rasterize: {name}[{}, {}] is {}", g / n, g % n, v[k]));
            }
        }
        for g in 0..c * n {
            let [a, b, cc] = self.conic3(g);
            if !(a > 0.0 && cc > 0.0 && a * cc - b * b > 0.0) {
                return invalid_input(format!(
                    "rasterize: conics[{}, {}] = ({a}, {b}, {cc}) is not positive definite (a degenerate 2D covariance)",
                    g / n,
                    g % n
                ));
            }
        }
        Ok(())
    }

    fn tiles_x(&self) -> usize {
        self.width.div_ceil(TILE)
    }

    fn tiles_y(&self) -> usize {
        self.height.div_ceil(TILE)
    }

    fn conic3(&self, g: usize) -> [f64; 3] {
        [self.conic[3 * g], self.conic[3 * g + 1], self.conic[3 * g + 2]]
    }

    /// The pixel box of flat Gaussian `g`, or None when it draws nothing (behind the near
    /// plane, opacity ≤ 1/255, or off the image).
    fn pixel_box(&self, g: usize) -> Option<PixelBox> {
        let o = self.opacity[g];
        if self.depth[g] <= NEAR || o * 255.0 <= 1.0 {
            return None;
        }
        let [a, b, c] = self.conic3(g);
        let det = a * c - b * b;
        let k = 2.0 * (o * 255.0).ln();
        // Σ = Q⁻¹: Σ_xx = c / det, Σ_yy = a / det; a hair wider than tight (never narrower).
        let rx = (k * c / det).sqrt() * (1.0 + 1e-9) + 1e-9;
        let ry = (k * a / det).sqrt() * (1.0 + 1e-9) + 1e-9;
        let (u, v) = (self.uv[2 * g], self.uv[2 * g + 1]);
        let (w, h) = (self.width as f64, self.height as f64);
        let x0 = ceil(u - rx).max(0.0);
        let x1 = floor(u + rx).min(w - 1.0);
        let y0 = ceil(v - ry).max(0.0);
        let y1 = floor(v + ry).min(h - 1.0);
        if x0 > x1 || y0 > y1 {
            return None;
        }
        Some(PixelBox { x0: x0 as usize, x1: x1 as usize, y0: y0 as usize, y1: y1 as usize })
    }

    /// Every Gaussian's tile-loop record (`rows` from its pixel box; unused when not drawn).
    fn pack(&self, bins: &Bins) -> Vec<Packed> {
        (0..self.cameras * self.n)
            .into_par_iter()
            .map(|g| {
                let [a, b, c] = self.conic3(g);
                let o = self.opacity[g];
                Packed {
                    u: self.uv[2 * g],
                    v: self.uv[2 * g + 1],
                    a,
                    b,
                    c,
                    o,
                    qmax: 2.0 * (o * 255.0).max(1.0).ln() + 1e-6,
                    col: [self.color[3 * g], self.color[3 * g + 1], self.color[3 * g + 2]],
                    z: self.depth[g],
                    rows: bins.rows[g],
                }
            })
            .collect()
    }

    fn bin(&self) -> Bins {
        let (tx, ty) = (self.tiles_x(), self.tiles_y());
        let per_cam = tx * ty;
        let total = self.cameras * self.n;
        // Tile rectangle of every Gaussian, then Gaussian-major entries.
        let boxes: Vec<Option<PixelBox>> = (0..total).into_par_iter().map(|g| self.pixel_box(g)).collect();
        let rects: Vec<Option<[usize; 4]>> =
            boxes.iter().map(|b| b.as_ref().map(|b| [b.x0 / TILE, b.x1 / TILE, b.y0 / TILE, b.y1 / TILE])).collect();
        let rows: Vec<[u32; 2]> = boxes.iter().map(|b| b.as_ref().map_or([1, 0], |b| [b.y0 as u32, b.y1 as u32])).collect();
        let mut gauss_start = Vec::with_capacity(total + 1);
        gauss_start.push(0usize);
        for r in &rects {
            let k = r.map_or(0, |[x0, x1, y0, y1]| (x1 - x0 + 1) * (y1 - y0 + 1));
            gauss_start.push(gauss_start.last().unwrap() + k);
        }
        let m = *gauss_start.last().unwrap();
        let mut entry_gauss = vec![0u32; m];
        let mut entry_tile = vec![0u32; m];
        for (g, r) in rects.iter().enumerate() {
            if let Some([x0, x1, y0, y1]) = *r {
                let cam = g / self.n;
                let mut e = gauss_start[g];
                for ty_ in y0..=y1 {
                    for tx_ in x0..=x1 {
                        entry_gauss[e] = g as u32;
                        entry_tile[e] = (cam * per_cam + ty_ * tx + tx_) as u32;
                        e += 1;
                    }
                }
            }
        }
        // Tile by tile, front to back. The drawn Gaussians are sorted once by (camera, z, g),
        // a total order (z > NEAR > 0, so its bits order like the numbers); a counting sort of
        // their entries by tile, taken in that order, keeps each tile's list front to back.
        let mut by_depth: Vec<(usize, usize)> = (0..total).filter(|&g| rects[g].is_some()).map(|g| (g / self.n, g)).collect();
        let depth = &self.depth;
        by_depth.par_sort_unstable_by_key(|&(c, g)| (c, depth[g].to_bits(), g));
        let ntiles = self.cameras * per_cam;
        let mut tile_start = vec![0usize; ntiles + 1];
        for &t in &entry_tile {
            tile_start[t as usize + 1] += 1;
        }
        for t in 0..ntiles {
            tile_start[t + 1] += tile_start[t];
        }
        let mut cursor = tile_start.clone();
        let mut order = vec![0u32; m];
        for &(_, g) in &by_depth {
            let entries = gauss_start[g]..gauss_start[g + 1];
            for (e, &t) in entries.clone().zip(&entry_tile[entries]) {
                order[cursor[t as usize]] = e as u32;
                cursor[t as usize] += 1;
            }
        }
        Bins { tiles_x: tx, tiles_y: ty, gauss_start, entry_gauss, order, tile_start, rows }
    }
}

/// One Gaussian as the tile loops read it (one cache-friendly record).
#[derive(Clone, Copy, Debug, Default)]
struct Packed {
    u: f64,
    v: f64,
    a: f64,
    b: f64,
    c: f64,
    o: f64,
    /// `q` beyond which `o e^{-q/2} < 1/255`: such pairs are skipped without an `exp`
    /// (`o e^{-q/2} >= 1/255  <=>  q <= 2 ln(255 o)`; the margin only lets a few more pairs
    /// reach the exact test).
    qmax: f64,
    col: [f64; 3],
    z: f64,
    /// Rows `[y0, y1]` of the pixel box: other rows are skipped without arithmetic.
    rows: [u32; 2],
}

/// One tile's Gaussians in compositing order.
struct TileSplats {
    g: Vec<Packed>,
}

/// Pixel columns `lo..hi` (within `xs`) of row `py` where entry `j` may reach `o G >= 1/255`,
/// from the exact ellipse `q(x) <= qmax` on that row (widened by a hair, never narrowed):
/// `a dx² + 2 b dy dx + c dy² - qmax <= 0`, a quadratic in `dx`.
#[inline(always)]
fn row_span(ts: &TileSplats, j: usize, y: u32, xs: &std::ops::Range<usize>) -> std::ops::Range<usize> {
    let p = &ts.g[j];
    let [y0, y1] = p.rows;
    if y < y0 || y > y1 {
        return 0..0;
    }
    let dy = y as f64 - p.v;
    let (a, b) = (p.a, p.b);
    let disc = b * b * dy * dy - a * (p.c * dy * dy - p.qmax);
    if disc < 0.0 {
        return 0..0;
    }
    let half = disc.sqrt() / a * (1.0 + 1e-9) + 1e-9;
    let mid = p.u - b * dy / a;
    let lo = ceil(mid - half).max(xs.start as f64);
    let hi = floor(mid + half).min(xs.end as f64 - 1.0);
    if lo > hi {
        return 0..0;
    }
    lo as usize..hi as usize + 1
}

impl TileSplats {
    fn load(st: &[Packed], bins: &Bins, entries: &[u32]) -> Self {
        TileSplats { g: entries.iter().map(|&e| st[bins.entry_gauss[e as usize] as usize]).collect() }
    }

    /// `(α, o G, dx, dy)` of entry `j` at pixel `(px, py)`; α ≤ 0 means "not composited".
    #[inline(always)]
    fn alpha(&self, j: usize, px: f64, py: f64, cutoff: Cutoff) -> (f64, f64, f64, f64) {
        let p = &self.g[j];
        let dx = px - p.u;
        let dy = py - p.v;
        let q = p.a * dx * dx + 2.0 * p.b * dx * dy + p.c * dy * dy;
        if q > p.qmax {
            return (0.0, 0.0, dx, dy);
        }
        let raw = p.o * (-0.5 * q).exp();
        let alpha = match cutoff {
            Cutoff::Soft => (raw.min(ALPHA_MAX) - ALPHA_MIN).max(0.0),
            Cutoff::Hard if raw >= ALPHA_MIN => raw.min(ALPHA_MAX),
            Cutoff::Hard => 0.0,
        };
        (alpha, raw, dx, dy)
    }
}

/// Pixel rectangle of global tile `t`: camera, x range, y range.
fn tile_rect(s: &Splats, bins: &Bins, t: usize) -> (usize, std::ops::Range<usize>, std::ops::Range<usize>) {
    let per_cam = bins.tiles_x * bins.tiles_y;
    let (cam, local) = (t / per_cam, t % per_cam);
    let (tx, ty) = (local % bins.tiles_x, local / bins.tiles_x);
    let xs = tx * TILE..((tx + 1) * TILE).min(s.width);
    let ys = ty * TILE..((ty + 1) * TILE).min(s.height);
    (cam, xs, ys)
}

/// One tile's forward: per pixel (row-major within the tile) rgb, alpha, dsum, T_final, last;
/// per list entry the largest weight; composited pairs.
struct TileForward {
    pixels: Vec<[f64; 6]>,
    last: Vec<u32>,
    entry_max: Vec<f64>,
    npairs: u64,
}

fn forward_tile(s: &Splats, packed: &[Packed], bins: &Bins, t: usize) -> TileForward {
    let entries = &bins.order[bins.tile_start[t]..bins.tile_start[t + 1]];
    let ts = TileSplats::load(packed, bins, entries);
    let (_, xs, ys) = tile_rect(s, bins, t);
    let nx = xs.len();
    let mut out = TileForward {
        pixels: Vec::with_capacity(nx * ys.len()),
        last: Vec::with_capacity(nx * ys.len()),
        entry_max: vec![0.0; entries.len()],
        npairs: 0,
    };
    // One row of the tile at a time, Gaussians front to back; a Gaussian touches only the
    // columns its ellipse spans on this row, and the row ends when every pixel has stopped.
    for y in ys {
        let py = y as f64;
        let mut px = [[0.0f64; 6]; TILE]; // r, g, b, alpha, dsum, T
        let mut last = [0u32; TILE];
        let mut done = [false; TILE];
        let mut open = nx;
        for p in px.iter_mut() {
            p[5] = 1.0;
        }
        for j in 0..entries.len() {
            if open == 0 {
                break;
            }
            for x in row_span(&ts, j, y as u32, &xs) {
                let i = x - xs.start;
                if done[i] {
                    continue;
                }
                let (alpha, _, _, _) = ts.alpha(j, x as f64, py, s.cutoff);
                if alpha <= 0.0 {
                    continue;
                }
                let p = &mut px[i];
                let t_next = p[5] * (1.0 - alpha);
                if t_next < T_MIN {
                    done[i] = true;
                    open -= 1;
                    continue;
                }
                let w = alpha * p[5];
                let [cr, cg, cb] = ts.g[j].col;
                p[0] += w * cr;
                p[1] += w * cg;
                p[2] += w * cb;
                p[3] += w;
                p[4] += w * ts.g[j].z;
                p[5] = t_next;
                if w > out.entry_max[j] {
                    out.entry_max[j] = w;
                }
                last[i] = j as u32 + 1;
                out.npairs += 1;
            }
        }
        out.pixels.extend_from_slice(&px[..nx]);
        out.last.extend_from_slice(&last[..nx]);
    }
    out
}

/// Rasterizes `splats` (see the module docs). Errors name the offending input.
pub fn forward(splats: Splats) -> Result<Forward> {
    splats.check()?;
    let s = &splats;
    let bins = s.bin();
    let packed = s.pack(&bins);
    let ntiles = bins.tile_start.len() - 1;
    let tiles: Vec<TileForward> = (0..ntiles).into_par_iter().map(|t| forward_tile(s, &packed, &bins, t)).collect();
    let (w, h) = (s.width, s.height);
    let npix = s.cameras * w * h;
    let mut rgb = vec![0.0; 3 * npix];
    let mut alpha = vec![0.0; npix];
    let mut dsum = vec![0.0; npix];
    let mut t_final = vec![1.0; npix];
    let mut last = vec![0u32; npix];
    let mut entry_max = vec![0.0; bins.entry_gauss.len()];
    let mut npairs = 0;
    for (t, tf) in tiles.iter().enumerate() {
        let (cam, xs, ys) = tile_rect(s, &bins, t);
        let mut k = 0;
        for y in ys {
            for x in xs.clone() {
                let p = (cam * h + y) * w + x;
                let [r, g, b, acc, ds, tt] = tf.pixels[k];
                rgb[3 * p..3 * p + 3].copy_from_slice(&[r, g, b]);
                alpha[p] = acc;
                dsum[p] = ds;
                t_final[p] = tt;
                last[p] = tf.last[k];
                k += 1;
            }
        }
        for (i, &e) in bins.order[bins.tile_start[t]..bins.tile_start[t + 1]].iter().enumerate() {
            entry_max[e as usize] = tf.entry_max[i];
        }
        npairs += tf.npairs;
    }
    let contrib: Vec<f64> = (0..s.cameras * s.n)
        .into_par_iter()
        .map(|g| entry_max[bins.gauss_start[g]..bins.gauss_start[g + 1]].iter().fold(0.0, |m: f64, &x| m.max(x)))
        .collect();
    Ok(Forward { rgb, alpha, dsum, contrib, npairs, state: State { splats, bins, packed, t_final, last } })
}

/// `[u, v, a, b, c, o, r, g, b, z]` gradient of one list entry.
type EntryGrad = [f64; 10];

fn backward_tile(st: &State, t: usize, g_rgb: &[f64], g_alpha: &[f64], g_dsum: &[f64]) -> Vec<EntryGrad> {
    let (s, bins) = (&st.splats, &st.bins);
    let entries = &bins.order[bins.tile_start[t]..bins.tile_start[t + 1]];
    let ts = TileSplats::load(&st.packed, bins, entries);
    let mut grads = vec![[0.0; 10]; entries.len()];
    let (cam, xs, ys) = tile_rect(s, bins, t);
    let (w, h) = (s.width, s.height);
    let nx = xs.len();
    // Row by row, back to front from the row's last composited Gaussian.
    for y in ys {
        let py = y as f64;
        let row0 = (cam * h + y) * w + xs.start;
        let mut gr = [[0.0f64; 3]; TILE];
        let mut ga = [0.0f64; TILE];
        let mut gd = [0.0f64; TILE];
        let mut tt = [0.0f64; TILE];
        let mut suffix = [0.0f64; TILE]; // Σ_{j>i} w_j F_j per pixel
        let mut last = [0usize; TILE];
        for i in 0..nx {
            let p = row0 + i;
            gr[i] = [g_rgb[3 * p], g_rgb[3 * p + 1], g_rgb[3 * p + 2]];
            ga[i] = g_alpha[p];
            gd[i] = g_dsum[p];
            tt[i] = st.t_final[p];
            last[i] = st.last[p] as usize;
        }
        let end = last[..nx].iter().copied().max().unwrap_or(0);
        for j in (0..end).rev() {
            for x in row_span(&ts, j, y as u32, &xs) {
                let i = x - xs.start;
                if j >= last[i] {
                    continue;
                }
                let (alpha, raw, dx, dy) = ts.alpha(j, x as f64, py, s.cutoff);
                if alpha <= 0.0 {
                    continue;
                }
                let t_before = tt[i] / (1.0 - alpha);
                let wgt = alpha * t_before;
                let [cr, cg, cb] = ts.g[j].col;
                let f = gr[i][0] * cr + gr[i][1] * cg + gr[i][2] * cb + ga[i] + gd[i] * ts.g[j].z;
                let d_alpha = t_before * f - suffix[i] / (1.0 - alpha);
                suffix[i] += wgt * f;
                tt[i] = t_before;
                let e = &mut grads[j];
                e[6] += wgt * gr[i][0];
                e[7] += wgt * gr[i][1];
                e[8] += wgt * gr[i][2];
                e[9] += wgt * gd[i];
                // α = min(0.99, raw) [- 1/255]: flat where clamped.
                if raw > ALPHA_MAX {
                    continue;
                }
                e[5] += d_alpha * raw / ts.g[j].o;
                let d_q = -0.5 * raw * d_alpha;
                e[2] += d_q * dx * dx;
                e[3] += d_q * 2.0 * dx * dy;
                e[4] += d_q * dy * dy;
                // ∂q/∂u = -(2a dx + 2b dy), ∂q/∂v = -(2b dx + 2c dy)
                e[0] -= d_q * 2.0 * (ts.g[j].a * dx + ts.g[j].b * dy);
                e[1] -= d_q * 2.0 * (ts.g[j].b * dx + ts.g[j].c * dy);
            }
        }
    }
    grads
}

/// Gradients of `L = Σ g_rgb·rgb + g_alpha·alpha + g_dsum·dsum` (layouts of [`Forward`]).
pub fn backward(st: &State, g_rgb: &[f64], g_alpha: &[f64], g_dsum: &[f64]) -> Result<Grads> {
    let s = &st.splats;
    let npix = s.cameras * s.width * s.height;
    for (name, v, per) in [("grad_rgb", g_rgb, 3), ("grad_alpha", g_alpha, 1), ("grad_dsum", g_dsum, 1)] {
        if v.len() != npix * per {
            return invalid_input(format!("rasterize backward: {name} holds {} values; expected {}", v.len(), npix * per));
        }
        if let Some(k) = v.iter().position(|x| !x.is_finite()) {
            return invalid_input(format!("rasterize backward: {name} has a non-finite value ({}) at {k}", v[k]));
        }
    }
    let bins = &st.bins;
    let ntiles = bins.tile_start.len() - 1;
    let tiles: Vec<Vec<EntryGrad>> = (0..ntiles).into_par_iter().map(|t| backward_tile(st, t, g_rgb, g_alpha, g_dsum)).collect();
    // Entry gradients back in Gaussian-major numbering, then one fixed-order sum per Gaussian.
    let mut by_entry = vec![[0.0; 10]; bins.entry_gauss.len()];
    for (t, tg) in tiles.iter().enumerate() {
        for (i, &e) in bins.order[bins.tile_start[t]..bins.tile_start[t + 1]].iter().enumerate() {
            by_entry[e as usize] = tg[i];
        }
    }
    let per_gauss: Vec<EntryGrad> = (0..s.cameras * s.n)
        .into_par_iter()
        .map(|g| {
            let mut acc = [0.0; 10];
            for e in &by_entry[bins.gauss_start[g]..bins.gauss_start[g + 1]] {
                for k in 0..10 {
                    acc[k] += e[k];
                }
            }
            acc
        })
        .collect();
    let mut out = Grads {
        uv: Vec::with_capacity(2 * per_gauss.len()),
        conic: Vec::with_capacity(3 * per_gauss.len()),
        opacity: Vec::with_capacity(per_gauss.len()),
        color: Vec::with_capacity(3 * per_gauss.len()),
        depth: Vec::with_capacity(per_gauss.len()),
    };
    for g in &per_gauss {
        out.uv.extend_from_slice(&g[0..2]);
        out.conic.extend_from_slice(&g[2..5]);
        out.opacity.push(g[5]);
        out.color.extend_from_slice(&g[6..9]);
        out.depth.push(g[9]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::threads::with_threads;

    fn scene(n: usize, cams: usize, w: usize, h: usize, seed: u64) -> Splats {
        // A small deterministic scene: Gaussians scattered over the image (LCG).
        let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let mut rnd = || {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let m = cams * n;
        let mut s = Splats {
            cameras: cams,
            n,
            width: w,
            height: h,
            uv: vec![],
            conic: vec![],
            opacity: vec![],
            color: vec![],
            depth: vec![],
            cutoff: Cutoff::Soft,
        };
        for _ in 0..m {
            s.uv.extend([rnd() * w as f64, rnd() * h as f64]);
            let (sx, sy, rho) = (1.0 + 4.0 * rnd(), 1.0 + 4.0 * rnd(), 0.8 * (rnd() - 0.5));
            let (a, b, c) = (sx * sx, rho * sx * sy, sy * sy);
            let det = a * c - b * b;
            s.conic.extend([c / det, -b / det, a / det]);
            s.opacity.push(0.2 + 0.8 * rnd());
            s.color.extend([rnd(), rnd(), rnd()]);
            s.depth.push(0.5 + rnd());
        }
        s
    }

    /// The same image by brute force: every Gaussian at every pixel, depth order.
    fn brute(s: &Splats) -> (Vec<f64>, Vec<f64>) {
        let mut rgb = vec![0.0; s.cameras * s.width * s.height * 3];
        let mut acc = vec![0.0; s.cameras * s.width * s.height];
        for cam in 0..s.cameras {
            let mut ids: Vec<usize> = (cam * s.n..(cam + 1) * s.n).collect();
            ids.sort_by(|&p, &q| s.depth[p].total_cmp(&s.depth[q]).then(p.cmp(&q)));
            for y in 0..s.height {
                for x in 0..s.width {
                    let p = (cam * s.height + y) * s.width + x;
                    let mut t = 1.0;
                    for &g in &ids {
                        let (dx, dy) = (x as f64 - s.uv[2 * g], y as f64 - s.uv[2 * g + 1]);
                        let [a, b, c] = s.conic3(g);
                        let q = a * dx * dx + 2.0 * b * dx * dy + c * dy * dy;
                        let al = ((s.opacity[g] * (-0.5 * q).exp()).min(ALPHA_MAX) - ALPHA_MIN).max(0.0);
                        if al <= 0.0 {
                            continue;
                        }
                        if t * (1.0 - al) < T_MIN {
                            break;
                        }
                        for k in 0..3 {
                            rgb[3 * p + k] += al * t * s.color[3 * g + k];
                        }
                        acc[p] += al * t;
                        t *= 1.0 - al;
                    }
                }
            }
        }
        (rgb, acc)
    }

    #[test]
    fn tiles_equal_brute_force() {
        let s = scene(300, 2, 37, 29, 3);
        let (rgb, acc) = brute(&s);
        let f = forward(s).unwrap();
        for (a, b) in f.rgb.iter().zip(&rgb).chain(f.alpha.iter().zip(&acc)) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
        assert!(f.npairs > 1000);
    }

    #[test]
    fn backward_matches_finite_differences() {
        let s = scene(40, 1, 20, 18, 5);
        let f = forward(s.clone()).unwrap();
        let npix = s.width * s.height;
        let wts: Vec<f64> = (0..5 * npix).map(|i| ((i * 7919) % 13) as f64 / 13.0 - 0.4).collect();
        let loss = |s: Splats| {
            let f = forward(s).unwrap();
            let mut l = 0.0;
            for p in 0..npix {
                l += wts[5 * p] * f.rgb[3 * p] + wts[5 * p + 1] * f.rgb[3 * p + 1] + wts[5 * p + 2] * f.rgb[3 * p + 2];
                l += wts[5 * p + 3] * f.alpha[p] + wts[5 * p + 4] * f.dsum[p];
            }
            l
        };
        let g_rgb: Vec<f64> = (0..npix).flat_map(|p| [wts[5 * p], wts[5 * p + 1], wts[5 * p + 2]]).collect();
        let g_a: Vec<f64> = (0..npix).map(|p| wts[5 * p + 3]).collect();
        let g_d: Vec<f64> = (0..npix).map(|p| wts[5 * p + 4]).collect();
        let g = backward(&f.state, &g_rgb, &g_a, &g_d).unwrap();
        let h = 1e-6;
        for i in [0usize, 7, 19, 33] {
            type Field = fn(&mut Splats) -> &mut Vec<f64>;
            let fields: [(Field, usize, &Vec<f64>); 5] = [
                (|s| &mut s.uv, 2, &g.uv),
                (|s| &mut s.conic, 3, &g.conic),
                (|s| &mut s.opacity, 1, &g.opacity),
                (|s| &mut s.color, 3, &g.color),
                (|s| &mut s.depth, 1, &g.depth),
            ];
            for (field, per, grad) in fields {
                for k in 0..per {
                    let (mut sp, mut sm) = (s.clone(), s.clone());
                    field(&mut sp)[per * i + k] += h;
                    field(&mut sm)[per * i + k] -= h;
                    let fd = (loss(sp) - loss(sm)) / (2.0 * h);
                    let an = grad[per * i + k];
                    assert!((fd - an).abs() <= 1e-5 * (1.0 + fd.abs()), "gaussian {i} comp {k}: fd {fd} vs {an}");
                }
            }
        }
    }

    #[test]
    fn same_bits_for_any_thread_count() {
        let s = scene(500, 3, 50, 40, 9);
        let run = |n| {
            with_threads(Some(n), || {
                let f = forward(s.clone()).unwrap();
                let npix = s.cameras * s.width * s.height;
                let g = backward(&f.state, &vec![0.3; 3 * npix], &vec![-0.2; npix], &vec![0.1; npix]).unwrap();
                (f.rgb, f.contrib, g.uv, g.conic, g.opacity)
            })
            .unwrap()
        };
        let (a, b) = (run(1), run(3));
        assert!(a.0.iter().zip(&b.0).all(|(x, y)| x.to_bits() == y.to_bits()));
        assert!(a.2.iter().zip(&b.2).all(|(x, y)| x.to_bits() == y.to_bits()));
        assert!(a.4.iter().zip(&b.4).all(|(x, y)| x.to_bits() == y.to_bits()));
    }

    #[test]
    fn regression_singular_conic_is_an_error_not_a_panic() {
        let mut s = scene(5, 1, 10, 10, 1);
        s.conic[3..6].copy_from_slice(&[1.0, 1.0, 1.0]); // det = 0
        let e = forward(s).unwrap_err().to_string();
        assert!(e.contains("conics[0, 1]") && e.contains("positive definite"), "{e}");
        let mut s = scene(5, 1, 10, 10, 1);
        s.uv[3] = f64::NAN;
        assert!(forward(s).unwrap_err().to_string().contains("means2d[0, 1] is NaN"));
        let mut s = scene(5, 1, 10, 10, 1);
        s.n = 0;
        assert!(forward(s).unwrap_err().to_string().contains("empty"));
    }
}
