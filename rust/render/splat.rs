//! Tile-based Gaussian-splat rasterization on the CPU: forward compositing and its exact
//! backward, over Gaussians already projected to the image (2D means, conics, opacities,
//! colours, camera depths). `render/mod.rs` projects and colours them and chains these gradients
//! on to the 3D Gaussians and the cameras; this file knows nothing of either. Generic over
//! [`Real`]: `f32` (float32 tensors) or `f64` (gradient checks).
//!
//! # The image model (identical to `render/rasterize.py: _rasterize_torch`)
//! For image `c` and pixel `p = (x, y)` (pixel centres at integer coordinates), each
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
//! Each image is cut into `TILE × TILE` tiles. A Gaussian is listed in every tile its
//! pixel box meets; the box is the tight bounding box of the ellipse where `o G >= 1/255`,
//! half-widths `sqrt(k Σ_xx)`, `sqrt(k Σ_yy)` with `k = 2 ln(255 o)` and `Σ = Q⁻¹`. Every
//! pixel outside it has `o G < 1/255` (because `q >= dx²/Σ_xx`), hence α ≤ 0 under either
//! cutoff: the lists lose nothing, and the output equals compositing every Gaussian (the
//! boxes are widened by [`Real::HAIR`] so that rounding in `f32` cannot shrink them).
//! Each tile's list is sorted by `(z, Gaussian index)`, a total order, so the result is the
//! same whatever sorts it.
//!
//! # Per-Gaussian constants, folded once; rows at once
//! Each drawn Gaussian is packed once into one record (`Packed`: centre, conic, opacity,
//! colour, depth; its box within each tile is in the tile list itself), the records in (camera, depth) order so that a tile reads them at
//! increasing addresses. A tile walks its list front to back; per row it keeps a bit per column
//! still compositing. A Gaussian visits only the rows of its box with an open pixel in its
//! columns, and on each runs every step on the row's 8 columns at once, without branches:
//! `o G` (`exp` is a branch-free polynomial in `f32`, [`Real::exp_kernel`]), `α`, the next
//! transmittance, the masks of the columns that composite and stop, then the sums and `T`
//! updated with the composited columns' `α` (0 elsewhere, which leaves a sum or `T` exactly as
//! it was). The compiler vectorises it: one AVX2 instruction per step in `f32` where the CPU
//! has AVX2 (chosen at run time; the same IEEE operations in the same order, no fused
//! multiply-add, so the images are bit-identical with or without it). Only the composited
//! pairs' records are written one by one. Most Gaussians behind the front surface cost a few
//! mask tests.
//!
//! The tile lists are built camera by camera in parallel (each camera's Gaussians, entries,
//! tiles and list positions are contiguous blocks of the frame's arrays), the images assembled
//! camera by camera, and the backward's per-Gaussian sums read each entry's gradient through
//! its list position: no step that costs more than a pass over the Gaussians is serial.
//!
//! # Backward, without searching again
//! The forward records every composited pair of a tile, in the order it composited them,
//! with what the backward needs: the list entry, the pixel, `α` and the transmittance `T`
//! before it, and whether `α` was clamped at 0.99 (12 bytes per pair in `f32`; a few MB for a
//! 4 × 128² frame, read once, sequentially). Per pixel those pairs run front to back, so the
//! tile's record read backwards walks every pixel back to front. With per-pixel upstream
//! gradients `g_rgb`, `g_alpha`, `g_dsum`, let `F_i = g_rgb·c_i + g_alpha + g_dsum z_i`, so
//! the pixel's loss is `L = Σ_i w_i F_i`. Then
//!
//! ```text
//! ∂L/∂c_i = w_i g_rgb,   ∂L/∂z_i = w_i g_dsum,
//! ∂L/∂α_i = T_i F_i - (Σ_{j>i} w_j F_j) / (1 - α_i)
//! ```
//!
//! (the suffix sum grows as the walk goes; α ≤ 0.99 keeps the division finite), chained
//! through `α(o G)` (`o G = α + 1/255` under the soft cutoff, `α` under the hard one, and flat
//! where clamped), `G(q)` and `q(u, v, a, b, c)`. No pair is searched for, no `exp` is taken.
//!
//! # Determinism
//! Pixels are independent in the forward. In the backward each tile writes the gradients of
//! its own list entries (no shared accumulator); each Gaussian then sums its entries in a
//! fixed order (its tiles in row-major order). Results are bit-identical for any thread count.

use rayon::prelude::*;

use crate::error::{invalid_input, Result};
use crate::render::real::{first_non_finite, Real};

/// Tile side in pixels.
pub const TILE: usize = 8;
/// Pixels per tile (the low bits of a recorded pair's key).
const TILE_PIXELS: usize = TILE * TILE;
/// α below which a pair does not contribute (3DGS).
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// α is clamped to at most this (keeps `1 - α` away from 0).
pub const ALPHA_MAX: f64 = 0.99;
/// A pixel stops compositing before its transmittance would drop below this.
pub const T_MIN: f64 = 1e-4;
/// Gaussians closer to the camera than this (metres) are not drawn.
pub const NEAR: f64 = 0.01;
/// Bits of a recorded pair's key: pixel in the tile (6), clamped flag (1), list entry (25).
const PIXEL_BITS: u32 = 6;
const CLAMP_BIT: u32 = 1 << PIXEL_BITS;
const ENTRY_SHIFT: u32 = PIXEL_BITS + 1;
/// Most list entries one tile may hold (the entry's bits in a pair key).
const MAX_TILE_ENTRIES: usize = 1 << (32 - ENTRY_SHIFT);

/// How α is cut at `1/255` (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cutoff {
    /// `max(0, α - 1/255)`: continuous, so gradients match finite differences.
    Soft,
    /// 3DGS: α below `1/255` is dropped.
    Hard,
}

/// Projected Gaussians of `cameras` images, `n` per image (row-major arrays).
#[derive(Clone, Debug)]
pub struct Splats<T> {
    pub cameras: usize,
    pub n: usize,
    pub width: usize,
    pub height: usize,
    /// `[C, N, 2]` pixel centres.
    pub uv: Vec<T>,
    /// `[C, N, 3]` `(a, b, c)` of the conic `[[a, b], [b, c]]` (px⁻²).
    pub conic: Vec<T>,
    /// `[C, N]`.
    pub opacity: Vec<T>,
    /// `[C, N, 3]`.
    pub color: Vec<T>,
    /// `[C, N]` camera depth, metres.
    pub depth: Vec<T>,
    pub cutoff: Cutoff,
}

/// Forward outputs; `state` is what the backward needs (the rasterizer's own, or a caller's
/// that wraps it: [`Forward::with_state`]).
#[derive(Clone, Debug)]
pub struct Forward<T, S = State<T>> {
    /// `[C, H, W, 3]` `Σ w c` (no background).
    pub rgb: Vec<T>,
    /// `[C, H, W]` `Σ w`.
    pub alpha: Vec<T>,
    /// `[C, H, W]` `Σ w z`.
    pub dsum: Vec<T>,
    /// `[C, N]` each Gaussian's largest blending weight.
    pub contrib: Vec<T>,
    /// Composited (pixel, Gaussian) pairs.
    pub npairs: u64,
    pub state: S,
}

impl<T, S> Forward<T, S> {
    /// The same images with the state `wrap` makes of this one.
    pub fn with_state<S2>(self, wrap: impl FnOnce(S) -> S2) -> Forward<T, S2> {
        let Forward { rgb, alpha, dsum, contrib, npairs, state } = self;
        Forward { rgb, alpha, dsum, contrib, npairs, state: wrap(state) }
    }
}

/// One composited pair as the forward recorded it for the backward.
#[derive(Clone, Copy, Debug)]
struct Pair<T> {
    /// `entry << 7 | clamped << 6 | pixel in the tile`.
    key: u32,
    alpha: T,
    /// Transmittance in front of this pair.
    t: T,
}

/// The tile lists and every tile's composited pairs, kept for the backward.
#[derive(Clone, Debug)]
pub struct State<T> {
    /// The frame's sizes and cutoff; its arrays are emptied once packed (the records hold every
    /// value the tile loops and the backward read).
    pub splats: Splats<T>,
    bins: Bins,
    packed: Vec<Packed<T>>,
    /// Per tile, its composited pairs in compositing order.
    pairs: Vec<Vec<Pair<T>>>,
}

/// Gradients of a scalar loss w.r.t. every input of [`Splats`], same layouts.
#[derive(Clone, Debug)]
pub struct Grads<T> {
    pub uv: Vec<T>,
    pub conic: Vec<T>,
    pub opacity: Vec<T>,
    pub color: Vec<T>,
    pub depth: Vec<T>,
}

/// Tile lists. An *entry* is one (Gaussian, tile) incidence; entries are numbered
/// Gaussian-major (`gauss_start[g]..gauss_start[g + 1]` are Gaussian `g`'s tiles in row-major
/// order); the tile lists hold them tile by tile, depth-sorted within a tile (list positions
/// `tile_start[t]..tile_start[t + 1]` for global tile `t = camera * tiles + tile`), and
/// `entry_pos` maps each entry to its list position.
#[derive(Clone, Debug)]
struct Bins {
    tiles_x: usize,
    tiles_y: usize,
    gauss_start: Vec<usize>,
    /// Per tile-list position: the Gaussian's slot in the depth-sorted record array
    /// (`sorted`), so that a tile reads its records in increasing address order.
    order_slot: Vec<u32>,
    /// The drawn Gaussians (flat ids) by camera, then depth.
    sorted: Vec<u32>,
    /// Per tile-list position: the Gaussian's pixel box within the tile, `[row0, row1, col0,
    /// col1)` (tile-local, end exclusive).
    order_box: Vec<[u8; 4]>,
    tile_start: Vec<usize>,
    /// Per entry: its tile-list position.
    entry_pos: Vec<u32>,
}

/// `f(g, uv, conic, opacity, colour, depth)` on every Gaussian `g` of five arrays laid out as
/// [`Splats`]' (2, 3, 1, 3 and 1 values per Gaussian), in parallel: the projection writes the
/// rasterizer's inputs this way, the backward its gradients.
pub(crate) fn for_each_gaussian<T: Real>(
    uv: &mut [T],
    conic: &mut [T],
    opacity: &mut [T],
    color: &mut [T],
    depth: &mut [T],
    f: impl Fn(usize, &mut [T], &mut [T], &mut T, &mut [T], &mut T) + Sync + Send,
) {
    uv.par_chunks_mut(2)
        .zip(conic.par_chunks_mut(3))
        .zip(opacity.par_iter_mut())
        .zip(color.par_chunks_mut(3))
        .zip(depth.par_iter_mut())
        .enumerate()
        .for_each(|(g, ((((uv, conic), opacity), color), depth))| f(g, uv, conic, opacity, color, depth));
}

/// `v` cut into consecutive pieces, piece `k` of length `bounds[k + 1] - bounds[k]`
/// (`bounds` ascending from 0; each camera's or tile's block of a frame-wide array).
fn pieces<'a, X>(mut v: &'a mut [X], bounds: &[usize]) -> Vec<&'a mut [X]> {
    let mut out = Vec::with_capacity(bounds.len().saturating_sub(1));
    for w in bounds.windows(2) {
        let (piece, rest) = std::mem::take(&mut v).split_at_mut(w[1] - w[0]);
        out.push(piece);
        v = rest;
    }
    out
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

impl<T: Real> Splats<T> {
    /// Shapes, finiteness and positive-definite conics; errors name the entry.
    pub fn check(&self) -> Result<()> {
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
            // (scanned in parallel blocks; the first non-finite entry is then found in order)
            if let Some(k) = first_non_finite(v) {
                let g = k / per;
                return invalid_input(format!("rasterize: {name}[{}, {}] is {:?}", g / n, g % n, v[k].f64()));
            }
        }
        for g in 0..c * n {
            let [a, b, cc] = self.conic3(g).map(|x| x.f64());
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

    fn conic3(&self, g: usize) -> [T; 3] {
        [self.conic[3 * g], self.conic[3 * g + 1], self.conic[3 * g + 2]]
    }

    /// The pixel box of flat Gaussian `g`, or None when it draws nothing (behind the near
    /// plane, opacity ≤ 1/255, or off the image). In `f64` whatever `T` is, widened by
    /// [`Real::HAIR`].
    fn pixel_box(&self, g: usize) -> Option<PixelBox> {
        let o = self.opacity[g].f64();
        if self.depth[g].f64() <= NEAR || o * 255.0 <= 1.0 {
            return None;
        }
        let [a, b, c] = self.conic3(g).map(|x| x.f64());
        let det = a * c - b * b;
        let k = 2.0 * (o * 255.0).ln() + 1e-6;
        // Σ = Q⁻¹: Σ_xx = c / det, Σ_yy = a / det; a hair wider than tight (never narrower).
        let rx = (k * c / det).sqrt() * (1.0 + T::HAIR) + T::HAIR;
        let ry = (k * a / det).sqrt() * (1.0 + T::HAIR) + T::HAIR;
        let (u, v) = (self.uv[2 * g].f64(), self.uv[2 * g + 1].f64());
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

    /// The drawn Gaussians' tile-loop records, in `bins.sorted` order.
    fn pack(&self, bins: &Bins) -> Vec<Packed<T>> {
        bins.sorted
            .par_iter()
            .map(|&g| {
                let g = g as usize;
                let [a, b, c] = self.conic3(g);
                let o = self.opacity[g];
                Packed {
                    u: self.uv[2 * g],
                    v: self.uv[2 * g + 1],
                    a,
                    b,
                    c,
                    o,
                    col: [self.color[3 * g], self.color[3 * g + 1], self.color[3 * g + 2]],
                    z: self.depth[g],
                }
            })
            .collect()
    }

    /// The tile lists, built camera by camera in parallel: a camera's Gaussians, entries, tiles,
    /// tile-list positions and depth-sorted slots are each one contiguous block of the global
    /// arrays (Gaussians are numbered camera-major, entries Gaussian-major, tiles camera-major),
    /// so each camera fills its own blocks, with global indices, and no step is serial over the
    /// frame. The blocks' offsets come from per-camera counts taken first.
    fn bin(&self) -> Result<Bins> {
        let (tx, ty) = (self.tiles_x(), self.tiles_y());
        let per_cam = tx * ty;
        let (n, cams) = (self.n, self.cameras);
        let total = cams * n;
        // Every Gaussian's pixel box and tile rectangle `[x0, x1, y0, y1]` (None: not drawn).
        let boxes: Vec<Option<([u32; 4], [u32; 4])>> = (0..total)
            .into_par_iter()
            .map(|g| {
                self.pixel_box(g).map(|b| {
                    let p = [b.x0, b.x1, b.y0, b.y1].map(|v| v as u32);
                    (p, p.map(|v| v / TILE as u32))
                })
            })
            .collect();
        let tiles_of = |b: &Option<([u32; 4], [u32; 4])>| b.map_or(0, |(_, [x0, x1, y0, y1])| ((x1 - x0 + 1) * (y1 - y0 + 1)) as usize);
        // Per camera: entries (= tile-list positions) and drawn Gaussians; Gaussian-major
        // entry starts within each camera, then offset by the cameras before.
        let per_camera: Vec<(Vec<usize>, usize)> = boxes
            .par_chunks(n)
            .map(|bs| {
                let mut starts = Vec::with_capacity(n + 1);
                let mut acc = 0usize;
                starts.push(0);
                for b in bs {
                    acc += tiles_of(b);
                    starts.push(acc);
                }
                (starts, bs.iter().filter(|b| b.is_some()).count())
            })
            .collect();
        let mut entry0 = vec![0usize; cams + 1];
        let mut slot0 = vec![0usize; cams + 1];
        for (c, (starts, drawn)) in per_camera.iter().enumerate() {
            entry0[c + 1] = entry0[c] + starts[n];
            slot0[c + 1] = slot0[c] + drawn;
        }
        let m = entry0[cams];
        if m as u64 > u32::MAX as u64 {
            return invalid_input(format!("rasterize: {m} (Gaussian, tile) incidences are too many for 32-bit indices"));
        }
        let mut gauss_start = vec![0usize; total + 1];
        gauss_start[total] = m;
        let mut order_slot = vec![0u32; m];
        let mut order_box = vec![[0u8; 4]; m];
        let mut sorted = vec![0u32; slot0[cams]];
        let mut tile_start = vec![0usize; cams * per_cam + 1];
        tile_start[cams * per_cam] = m;
        let mut entry_pos = vec![0u32; m];
        // Each camera's blocks of the global arrays.
        struct Blocks<'a> {
            gauss_start: &'a mut [usize],
            order_slot: &'a mut [u32],
            order_box: &'a mut [[u8; 4]],
            sorted: &'a mut [u32],
            tile_start: &'a mut [usize],
            entry_pos: &'a mut [u32],
        }
        let by_gauss: Vec<usize> = (0..=cams).map(|c| c * n).collect();
        let by_tile: Vec<usize> = (0..=cams).map(|c| c * per_cam).collect();
        let blocks: Vec<Blocks> = pieces(&mut gauss_start[..total], &by_gauss)
            .into_iter()
            .zip(pieces(&mut order_slot, &entry0))
            .zip(pieces(&mut order_box, &entry0))
            .zip(pieces(&mut sorted, &slot0))
            .zip(pieces(&mut tile_start[..cams * per_cam], &by_tile))
            .zip(pieces(&mut entry_pos, &entry0))
            .map(|(((((gauss_start, order_slot), order_box), sorted), tile_start), entry_pos)| Blocks {
                gauss_start,
                order_slot,
                order_box,
                sorted,
                tile_start,
                entry_pos,
            })
            .collect();
        let results: Vec<Result<()>> = blocks
            .into_par_iter()
            .zip(per_camera.into_par_iter())
            .enumerate()
            .map(|(c, (blk, (starts, _)))| {
                let (g0, e0) = (c * n, entry0[c]);
                let boxes = &boxes[g0..g0 + n];
                for (dst, s) in blk.gauss_start.iter_mut().zip(&starts) {
                    *dst = e0 + s;
                }
                // The drawn Gaussians front to back by (z, g), a total order (z > NEAR > 0, so
                // a depth's bits order like the depth). In f32 the key (z bits, g) packs into
                // one u64, which sorts several times faster than a pair.
                let drawn = (0..n).filter(|&i| boxes[i].is_some());
                if T::DEPTH_BITS == 32 {
                    let mut v: Vec<u64> = drawn.map(|i| self.depth[g0 + i].order_bits() << 32 | i as u64).collect();
                    radix_sort(&mut v);
                    for (dst, k) in blk.sorted.iter_mut().zip(v) {
                        *dst = (g0 as u64 + (k & u32::MAX as u64)) as u32;
                    }
                } else {
                    let mut v: Vec<(u64, u32)> = drawn.map(|i| (self.depth[g0 + i].order_bits(), i as u32)).collect();
                    v.sort_unstable();
                    for (dst, (_, i)) in blk.sorted.iter_mut().zip(v) {
                        *dst = g0 as u32 + i;
                    }
                }
                // A counting sort of the entries by tile, taken in depth order, keeps each
                // tile's list front to back.
                let mut count = vec![0usize; per_cam + 1];
                for (_, [x0, x1, y0, y1]) in boxes.iter().flatten() {
                    for ty_ in *y0 as usize..=*y1 as usize {
                        for n_tile in &mut count[ty_ * tx + *x0 as usize + 1..=ty_ * tx + *x1 as usize + 1] {
                            *n_tile += 1;
                        }
                    }
                }
                for t in 0..per_cam {
                    if count[t + 1] >= MAX_TILE_ENTRIES {
                        return invalid_input(format!(
                            "rasterize: {} Gaussians reach one 8x8 tile (at most {} can)",
                            count[t + 1],
                            MAX_TILE_ENTRIES - 1
                        ));
                    }
                    count[t + 1] += count[t];
                }
                for (dst, &s) in blk.tile_start.iter_mut().zip(&count) {
                    *dst = e0 + s;
                }
                let s0 = slot0[c] as u32;
                // the pixel box `[lo, hi]` within the tile starting at pixel `o`: tile-local, end
                // exclusive
                let local = |lo: usize, hi: usize, o: usize| [(lo.max(o) - o) as u8, ((hi + 1).min(o + TILE) - o) as u8];
                for (k, &g) in blk.sorted.iter().enumerate() {
                    let i = g as usize - g0;
                    let (slot, (pbox, [x0, x1, y0, y1])) = (s0 + k as u32, boxes[i].expect("a sorted Gaussian is drawn"));
                    let [bx0, bx1, by0, by1] = pbox.map(|v| v as usize);
                    // its entries in row-major tile order, numbered from `starts[i]`
                    let mut e = starts[i];
                    for ty_ in y0 as usize..=y1 as usize {
                        let [r0, r1] = local(by0, by1, ty_ * TILE);
                        for tx_ in x0 as usize..=x1 as usize {
                            let t = ty_ * tx + tx_;
                            let pos = count[t];
                            count[t] += 1;
                            blk.entry_pos[e] = (e0 + pos) as u32;
                            blk.order_slot[pos] = slot;
                            let [c0, c1] = local(bx0, bx1, tx_ * TILE);
                            blk.order_box[pos] = [r0, r1, c0, c1];
                            e += 1;
                        }
                    }
                }
                Ok(())
            })
            .collect();
        results.into_iter().collect::<Result<Vec<()>>>()?;
        Ok(Bins { tiles_x: tx, tiles_y: ty, gauss_start, order_slot, sorted, order_box, tile_start, entry_pos })
    }
}

/// Sorts `v` ascending: least-significant-digit radix sort, 11-bit digits, a pass skipped
/// when every key has the same digit (a few times fewer instructions than a comparison sort
/// for the tens of thousands of depth keys of a frame).
fn radix_sort(v: &mut Vec<u64>) {
    const BITS: u32 = 11;
    const BUCKETS: usize = 1 << BITS;
    let mut buf = vec![0u64; v.len()];
    let mut shift = 0;
    while shift < 64 {
        let digit = |k: u64| ((k >> shift) as usize) & (BUCKETS - 1);
        let mut count = vec![0usize; BUCKETS + 1];
        for &k in v.iter() {
            count[digit(k) + 1] += 1;
        }
        if count.contains(&v.len()) {
            shift += BITS;
            continue;
        }
        for b in 0..BUCKETS {
            count[b + 1] += count[b];
        }
        for &k in v.iter() {
            let d = digit(k);
            buf[count[d]] = k;
            count[d] += 1;
        }
        std::mem::swap(v, &mut buf);
        shift += BITS;
    }
}

/// One Gaussian as the tile loops read it (one cache-friendly record).
#[derive(Clone, Copy, Debug, Default)]
struct Packed<T> {
    u: T,
    v: T,
    a: T,
    b: T,
    c: T,
    o: T,
    col: [T; 3],
    z: T,
}

/// The pixel coordinates `start, start + 1, ..` of a tile's `TILE` columns (or rows), in `T`.
#[inline(always)]
fn coords<T: Real>(start: usize) -> [T; TILE] {
    std::array::from_fn(|k| T::c((start + k) as f64))
}

/// Pixel rectangle of global tile `t`: image, x range, y range.
fn tile_rect(width: usize, height: usize, bins: &Bins, t: usize) -> (usize, std::ops::Range<usize>, std::ops::Range<usize>) {
    let per_cam = bins.tiles_x * bins.tiles_y;
    let (cam, local) = (t / per_cam, t % per_cam);
    let (tx, ty) = (local % bins.tiles_x, local / bins.tiles_x);
    let xs = tx * TILE..((tx + 1) * TILE).min(width);
    let ys = ty * TILE..((ty + 1) * TILE).min(height);
    (cam, xs, ys)
}

/// One tile's forward: per channel (r, g, b, alpha, dsum), row and column of the tile, the
/// pixel's sum; the composited pairs in compositing order. (Each list entry's largest weight
/// goes to the caller's slice.)
struct TileForward<T> {
    pixels: [[[T; TILE]; TILE]; 5],
    pairs: Vec<Pair<T>>,
}

/// [`forward_tile_with`], compiled for AVX2 where the CPU has it (8 `f32` lanes: one row of a
/// tile per instruction). The arithmetic is the same IEEE operations in the same order either
/// way (no fused multiply-add), so the images and pairs are bit-identical on any x86-64.
fn forward_tile<T: Real>(s: &Splats<T>, packed: &[Packed<T>], bins: &Bins, t: usize, entry_max: &mut [T]) -> TileForward<T> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { forward_tile_avx2(s, packed, bins, t, entry_max) };
    }
    forward_tile_with(s, packed, bins, t, entry_max)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn forward_tile_avx2<T: Real>(s: &Splats<T>, packed: &[Packed<T>], bins: &Bins, t: usize, entry_max: &mut [T]) -> TileForward<T> {
    forward_tile_with(s, packed, bins, t, entry_max)
}

/// `x < y ? x : y` and `x > y ? x : y` (no NaN here: one instruction each, unlike `min`/`max`,
/// which order NaNs).
#[inline(always)]
fn lesser<T: Real>(x: T, y: T) -> T {
    if x < y {
        x
    } else {
        y
    }
}

#[inline(always)]
fn greater<T: Real>(x: T, y: T) -> T {
    if x > y {
        x
    } else {
        y
    }
}

/// The tile loop (see the module docs). Per row a Gaussian visits, every step runs on the
/// row's `TILE` columns at once, without branches: `o G`, `α`, the next transmittance, which
/// columns composite (open, `α > 0`) and which stop (`T` would fall below `T_MIN`), then the
/// sums and `T` updated by selection; only the composited pairs' records are written one by
/// one, in column order. `entry_max` (the tile's list positions): each entry's largest weight.
#[inline(always)]
fn forward_tile_with<T: Real>(s: &Splats<T>, packed: &[Packed<T>], bins: &Bins, t: usize, entry_max: &mut [T]) -> TileForward<T> {
    let first = bins.tile_start[t];
    let entries = &bins.order_slot[first..bins.tile_start[t + 1]];
    let (_, xs, ys) = tile_rect(s.width, s.height, bins, t);
    let (zero, one, t_min) = (T::zero(), T::one(), T::c(T_MIN));
    let (amin, amax) = (T::c(ALPHA_MIN), T::c(ALPHA_MAX));
    let soft = s.cutoff == Cutoff::Soft;
    // r, g, b, alpha, dsum; transmittance: [row][column]
    let mut px = [[[zero; TILE]; TILE]; 5];
    let mut tt = [[one; TILE]; TILE];
    // Per row of the tile, a bit per column still compositing.
    let full = ((1u32 << xs.len()) - 1) as u16;
    let mut open_row = [0u16; TILE];
    for r in open_row.iter_mut().take(ys.len()) {
        *r = full;
    }
    let mut open = ys.len();
    let mut pairs = Vec::with_capacity(4 * entries.len());
    let cols = coords::<T>(xs.start);
    // Gaussians front to back; each visits only the rows of the tile its box spans that still
    // have open pixels in its columns; the tile ends when every pixel has stopped. Most
    // Gaussians behind the front surface cost a few mask tests.
    for (j, &k) in entries.iter().enumerate() {
        if open == 0 {
            break;
        }
        // the box, tile-local, from the list itself (sequential bytes): the record is read
        // only when a row of the box still has open pixels in its columns
        let [r0, r1, c0, c1] = bins.order_box[first + j].map(usize::from);
        let box_mask = (((1u32 << c1) - 1) & !((1u32 << c0) - 1)) as u16;
        if (r0..r1).all(|row| open_row[row] & box_mask == 0) {
            continue;
        }
        let p = &packed[k as usize];
        let mut w_max = zero;
        for row in r0..r1 {
            let live = open_row[row] & box_mask;
            if live == 0 {
                continue;
            }
            // o G at the row's columns (the branch-free kernel exp; columns outside the
            // ellipse come out < 1/255 and do not composite, as if they had been skipped)
            let dy = T::c((ys.start + row) as f64) - p.v;
            let (cdy, bdy) = (p.c * dy * dy, T::c(2.0) * p.b * dy);
            let t_row = tt[row];
            let (mut alpha, mut t_next) = ([zero; TILE], [zero; TILE]);
            // (u8 masks: one bit per column, TILE = 8; LLVM turns these into one movemask each)
            let (mut positive, mut low, mut clamped) = (0u8, 0u8, 0u8);
            for k in 0..TILE {
                let dx = cols[k] - p.u;
                let raw = p.o * (T::c(-0.5) * (p.a * dx * dx + bdy * dx + cdy)).exp_kernel();
                // α = min(0.99, o G) - 1/255, kept when > 0 (soft); min(0.99, o G) when
                // o G >= 1/255 (hard)
                let capped = lesser(raw, amax);
                let a = if soft {
                    greater(capped - amin, zero)
                } else if raw >= amin {
                    capped
                } else {
                    zero
                };
                alpha[k] = a;
                t_next[k] = t_row[k] * (one - a);
                positive |= ((a > zero) as u8) << k;
                low |= ((t_next[k] < t_min) as u8) << k;
                clamped |= ((raw > amax) as u8) << k;
            }
            // a pixel stops at the first Gaussian after which T would fall below T_MIN (that
            // one is not composited)
            let (positive, low, clamped) = (u16::from(positive), u16::from(low), u16::from(clamped));
            let stop = live & positive & low;
            let comp = live & positive & !low;
            if stop != 0 {
                open_row[row] &= !stop;
                if open_row[row] == 0 {
                    open -= 1;
                }
            }
            if comp == 0 {
                continue;
            }
            // the composited columns' α, 0 elsewhere: then every update below is plain
            // arithmetic on the whole row, exact where a column does not composite (T (1 - 0)
            // = T, and a sum plus ±0 is the sum: sums start at +0 and never become -0)
            let am: [T; TILE] = std::array::from_fn(|k| if comp >> k & 1 != 0 { alpha[k] } else { zero });
            let wm: [T; TILE] = std::array::from_fn(|k| am[k] * t_row[k]);
            for k in 0..TILE {
                px[0][row][k] = px[0][row][k] + wm[k] * p.col[0];
                px[1][row][k] = px[1][row][k] + wm[k] * p.col[1];
                px[2][row][k] = px[2][row][k] + wm[k] * p.col[2];
                px[3][row][k] = px[3][row][k] + wm[k];
                px[4][row][k] = px[4][row][k] + wm[k] * p.z;
                tt[row][k] = t_row[k] * (one - am[k]);
                w_max = greater(w_max, wm[k]);
            }
            let base = (j as u32) << ENTRY_SHIFT | (row * TILE) as u32;
            let mut bits = comp;
            while bits != 0 {
                let col = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let flag = (clamped as u32 >> col & 1) << PIXEL_BITS; // CLAMP_BIT when clamped
                pairs.push(Pair { key: base | flag | col as u32, alpha: alpha[col], t: t_row[col] });
            }
        }
        entry_max[j] = w_max;
    }
    TileForward { pixels: px, pairs }
}

/// Rasterizes `splats` after checking them (see the module docs). Errors name the input.
pub fn forward<T: Real>(splats: Splats<T>) -> Result<Forward<T>> {
    splats.check()?;
    forward_checked(splats)
}

/// [`forward`] for splats known to be well formed (`render/mod.rs` makes them).
pub(crate) fn forward_checked<T: Real>(full: Splats<T>) -> Result<Forward<T>> {
    let bins = full.bin()?;
    let packed = full.pack(&bins);
    // ~0.5 MB a view less to hold until the backward (a large batch's page faults)
    let splats = Splats { uv: Vec::new(), conic: Vec::new(), opacity: Vec::new(), color: Vec::new(), depth: Vec::new(), ..full };
    drop(full);
    let s = &splats;
    // per tile-list position: the entry's largest weight
    let mut pos_max = vec![T::zero(); bins.entry_pos.len()];
    let tiles: Vec<TileForward<T>> =
        pieces(&mut pos_max, &bins.tile_start).into_par_iter().enumerate().map(|(t, em)| forward_tile(s, &packed, &bins, t, em)).collect();
    // the images, camera by camera in parallel
    let (w, h) = (s.width, s.height);
    let per_cam = bins.tiles_x * bins.tiles_y;
    let npix = s.cameras * w * h;
    let mut rgb = vec![T::zero(); 3 * npix];
    let mut alpha = vec![T::zero(); npix];
    let mut dsum = vec![T::zero(); npix];
    rgb.par_chunks_mut(3 * w * h)
        .zip(alpha.par_chunks_mut(w * h))
        .zip(dsum.par_chunks_mut(w * h))
        .zip(tiles.par_chunks(per_cam))
        .enumerate()
        .for_each(|(cam, (((rgb, alpha), dsum), tiles))| {
            for (local, tf) in tiles.iter().enumerate() {
                let (_, xs, ys) = tile_rect(w, h, &bins, cam * per_cam + local);
                for (row, y) in ys.enumerate() {
                    for (col, x) in xs.clone().enumerate() {
                        let p = y * w + x;
                        let [r, g, b, acc, ds] = [0, 1, 2, 3, 4].map(|ch| tf.pixels[ch][row][col]);
                        rgb[3 * p..3 * p + 3].copy_from_slice(&[r, g, b]);
                        alpha[p] = acc;
                        dsum[p] = ds;
                    }
                }
            }
        });
    let npairs = tiles.iter().map(|tf| tf.pairs.len() as u64).sum();
    let pairs: Vec<Vec<Pair<T>>> = tiles.into_iter().map(|tf| tf.pairs).collect();
    let contrib: Vec<T> = (0..s.cameras * s.n)
        .into_par_iter()
        .map(|g| {
            let entries = &bins.entry_pos[bins.gauss_start[g]..bins.gauss_start[g + 1]];
            entries.iter().fold(T::zero(), |m, &pos| m.max(pos_max[pos as usize]))
        })
        .collect();
    Ok(Forward { rgb, alpha, dsum, contrib, npairs, state: State { splats, bins, packed, pairs } })
}

/// `[u, v, a, b, c, o, r, g, b, z]` gradient of one list entry.
type EntryGrad<T> = [T; 10];

/// Tile `t`'s backward: the gradient of each of its list entries into `grads` (the tile's
/// list positions).
fn backward_tile<T: Real>(st: &State<T>, t: usize, g_rgb: &[T], g_alpha: &[T], g_dsum: &[T], grads: &mut [EntryGrad<T>]) {
    let (s, bins) = (&st.splats, &st.bins);
    let slots = &bins.order_slot[bins.tile_start[t]..bins.tile_start[t + 1]];
    let zero = T::zero();
    let (cam, xs, ys) = tile_rect(s.width, s.height, bins, t);
    let (w, h) = (s.width, s.height);
    // Upstream gradients of the tile's pixels (index row * TILE + column).
    let mut gr = [[zero; 3]; TILE_PIXELS];
    let mut ga = [zero; TILE_PIXELS];
    let mut gd = [zero; TILE_PIXELS];
    let mut suffix = [zero; TILE_PIXELS]; // Σ_{j>i} w_j F_j per pixel
    for (row, y) in ys.clone().enumerate() {
        for (col, x) in xs.clone().enumerate() {
            let (p, i) = ((cam * h + y) * w + x, row * TILE + col);
            gr[i] = [g_rgb[3 * p], g_rgb[3 * p + 1], g_rgb[3 * p + 2]];
            ga[i] = g_alpha[p];
            gd[i] = g_dsum[p];
        }
    }
    let (one, two, half) = (T::one(), T::c(2.0), T::c(0.5));
    let cut = if s.cutoff == Cutoff::Soft { T::c(ALPHA_MIN) } else { zero };
    // the tile's pixel coordinates, converted once
    let (cols, rows) = (coords::<T>(xs.start), coords::<T>(ys.start));
    // The tile's pairs read backwards: every pixel back to front.
    for pair in st.pairs[t].iter().rev() {
        let i = (pair.key & (TILE_PIXELS as u32 - 1)) as usize;
        let j = (pair.key >> ENTRY_SHIFT) as usize;
        let p = &st.packed[slots[j] as usize];
        let (a, tb) = (pair.alpha, pair.t);
        let wgt = a * tb;
        let f = gr[i][0] * p.col[0] + gr[i][1] * p.col[1] + gr[i][2] * p.col[2] + ga[i] + gd[i] * p.z;
        let d_alpha = tb * f - suffix[i] / (one - a);
        suffix[i] = suffix[i] + wgt * f;
        let e = &mut grads[j];
        e[6] = e[6] + wgt * gr[i][0];
        e[7] = e[7] + wgt * gr[i][1];
        e[8] = e[8] + wgt * gr[i][2];
        e[9] = e[9] + wgt * gd[i];
        // α = min(0.99, o G) [- 1/255]: flat where clamped.
        if pair.key & CLAMP_BIT != 0 {
            continue;
        }
        let raw = a + cut;
        e[5] = e[5] + d_alpha * raw / p.o;
        let d_q = -half * raw * d_alpha;
        let dx = cols[i % TILE] - p.u;
        let dy = rows[i / TILE] - p.v;
        e[2] = e[2] + d_q * dx * dx;
        e[3] = e[3] + d_q * two * dx * dy;
        e[4] = e[4] + d_q * dy * dy;
        // ∂q/∂u = -(2a dx + 2b dy), ∂q/∂v = -(2b dx + 2c dy)
        e[0] = e[0] - d_q * two * (p.a * dx + p.b * dy);
        e[1] = e[1] - d_q * two * (p.b * dx + p.c * dy);
    }
}

/// Gradients of `L = Σ g_rgb·rgb + g_alpha·alpha + g_dsum·dsum` (layouts of [`Forward`]).
pub fn backward<T: Real>(st: &State<T>, g_rgb: &[T], g_alpha: &[T], g_dsum: &[T]) -> Result<Grads<T>> {
    let s = &st.splats;
    let npix = s.cameras * s.width * s.height;
    for (name, v, per) in [("grad_rgb", g_rgb, 3), ("grad_alpha", g_alpha, 1), ("grad_dsum", g_dsum, 1)] {
        if v.len() != npix * per {
            return invalid_input(format!("rasterize backward: {name} holds {} values; expected {}", v.len(), npix * per));
        }
        if let Some(k) = v.iter().position(|x| !x.is_finite()) {
            return invalid_input(format!("rasterize backward: {name} has a non-finite value ({:?}) at {k}", v[k].f64()));
        }
    }
    let bins = &st.bins;
    // per tile-list position: the entry's gradient
    let mut pos_grad = vec![[T::zero(); 10]; bins.entry_pos.len()];
    pieces(&mut pos_grad, &bins.tile_start)
        .into_par_iter()
        .enumerate()
        .for_each(|(t, grads)| backward_tile(st, t, g_rgb, g_alpha, g_dsum, grads));
    // one fixed-order sum per Gaussian (its entries in Gaussian-major order), straight into the
    // outputs
    let total = s.cameras * s.n;
    let mut out = Grads {
        uv: vec![T::zero(); 2 * total],
        conic: vec![T::zero(); 3 * total],
        opacity: vec![T::zero(); total],
        color: vec![T::zero(); 3 * total],
        depth: vec![T::zero(); total],
    };
    for_each_gaussian(
        &mut out.uv,
        &mut out.conic,
        &mut out.opacity,
        &mut out.color,
        &mut out.depth,
        |g, uv, conic, opacity, color, depth| {
            let mut acc = [T::zero(); 10];
            for &pos in &bins.entry_pos[bins.gauss_start[g]..bins.gauss_start[g + 1]] {
                let e = &pos_grad[pos as usize];
                for k in 0..10 {
                    acc[k] = acc[k] + e[k];
                }
            }
            uv.copy_from_slice(&acc[0..2]);
            conic.copy_from_slice(&acc[2..5]);
            *opacity = acc[5];
            color.copy_from_slice(&acc[6..9]);
            *depth = acc[9];
        },
    );
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::threads::with_threads;

    fn scene(n: usize, cams: usize, w: usize, h: usize, seed: u64) -> Splats<f64> {
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
    fn brute(s: &Splats<f64>) -> (Vec<f64>, Vec<f64>) {
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
        let loss = |s: Splats<f64>| {
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
            type Field = fn(&mut Splats<f64>) -> &mut Vec<f64>;
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

    /// `s` rounded to `f32`, with `cutoff`.
    fn in_f32(s: &Splats<f64>, cutoff: Cutoff) -> Splats<f32> {
        let to32 = |v: &Vec<f64>| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
        Splats {
            cameras: s.cameras,
            n: s.n,
            width: s.width,
            height: s.height,
            uv: to32(&s.uv),
            conic: to32(&s.conic),
            opacity: to32(&s.opacity),
            color: to32(&s.color),
            depth: to32(&s.depth),
            cutoff,
        }
    }

    #[test]
    fn float32_images_and_gradients_follow_float64() {
        // The same scene in f32: images within 1e-5, gradients within 1e-3 relative of f64's.
        let s = scene(300, 2, 37, 29, 4);
        let s32 = in_f32(&s, s.cutoff);
        let (f64_, f32_) = (forward(s.clone()).unwrap(), forward(s32).unwrap());
        for (a, b) in f64_.rgb.iter().zip(&f32_.rgb).chain(f64_.alpha.iter().zip(&f32_.alpha)) {
            assert!((a - *b as f64).abs() < 1e-5, "{a} vs {b}");
        }
        let npix = s.cameras * s.width * s.height;
        let g64 = backward(&f64_.state, &vec![0.3; 3 * npix], &vec![-0.2; npix], &vec![0.1; npix]).unwrap();
        let g32 = backward(&f32_.state, &vec![0.3f32; 3 * npix], &vec![-0.2f32; npix], &vec![0.1f32; npix]).unwrap();
        for (a, b) in [(&g64.uv, &g32.uv), (&g64.conic, &g32.conic), (&g64.opacity, &g32.opacity)] {
            let scale = a.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let err = a.iter().zip(b.iter()).fold(0.0f64, |m, (x, y)| m.max((x - *y as f64).abs()));
            assert!(err <= 1e-3 * scale, "{err} vs scale {scale}");
        }
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn avx2_tile_loop_is_bit_identical_to_the_portable_one() {
        // `forward_tile` takes the AVX2 copy where the CPU has it; the portable loop (other
        // CPUs) must give the same bits: pixels, pair records and per-entry weights.
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        for cutoff in [Cutoff::Soft, Cutoff::Hard] {
            let s = in_f32(&scene(400, 2, 37, 29, 9), cutoff);
            let bins = s.bin().unwrap();
            let packed = s.pack(&bins);
            let mut pairs = 0;
            for t in 0..bins.tile_start.len() - 1 {
                let n = bins.tile_start[t + 1] - bins.tile_start[t];
                let (mut max_a, mut max_b) = (vec![0f32; n], vec![0f32; n]);
                let a = forward_tile_with(&s, &packed, &bins, t, &mut max_a);
                // SAFETY: the CPU has AVX2 (checked above).
                let b = unsafe { forward_tile_avx2(&s, &packed, &bins, t, &mut max_b) };
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
                assert_eq!(bits(a.pixels.as_flattened().as_flattened()), bits(b.pixels.as_flattened().as_flattened()), "tile {t}");
                assert_eq!(bits(&max_a), bits(&max_b), "tile {t}");
                let rec = |p: &[Pair<f32>]| p.iter().map(|p| (p.key, p.alpha.to_bits(), p.t.to_bits())).collect::<Vec<_>>();
                assert_eq!(rec(&a.pairs), rec(&b.pairs), "tile {t}");
                pairs += a.pairs.len();
            }
            assert!(pairs > 1000, "{pairs} composited pairs: the scene tests too little");
        }
    }

    #[test]
    fn radix_sort_sorts() {
        let mut x = 12345u64;
        let mut v: Vec<u64> = (0..5000)
            .map(|_| {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                x >> (x % 40)
            })
            .collect();
        let mut w = v.clone();
        w.sort_unstable();
        radix_sort(&mut v);
        assert_eq!(v, w);
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
