//! Rendered images finished and compared, with their gradients, in one pass over the pixels:
//! the background behind the robot and the expected depth (what `render/rasterize.py:
//! render_native` did in torch), and the image loss that every pose-from-images method
//! descends (`render/targets.py: pose_loss`). In torch each is a dozen element-wise passes over
//! the frame, forward and backward (40 % of a pose fit's time outside the renderer); here each
//! is one, per image in parallel. Generic over [`Real`]; every formula below is the torch
//! one, in torch's order of operations (no fused multiply-add). The loss's sums over pixels
//! accumulate in `f64` (torch's cascade sums in `f32` round differently; both are within a few
//! units in the last place of the exact sum).
//!
//! Where torch and this differ: a non-finite weight is an error here (torch returns NaN); a
//! pixel outside every term (off the mask, not seen) is not read, so a NaN there does not reach
//! the loss (the renderer's outputs are finite: its inputs are checked).
//!
//! # Finishing (per pixel, image `v`, background `b_v`)
//! ```text
//! rgb ← rgb + (1 - α) b_v
//! D    = dsum / α  where α > 1e-6, else 0
//! ```
//! Backward: `∂/∂rgb` passes through; `∂/∂α = g_α - Σ_c g_rgb,c b_v,c - g_D D / α` (the last
//! term where α > 1e-6); `∂/∂dsum = g_D / α` there, 0 elsewhere.
//!
//! # The image loss (per image; `M*` the target's mask, `V` the pixels a photo saw)
//! ```text
//! L = Σ_M* |I - I*|² / max(|M*|, 1)
//!   + w_mask  Σ_V |α - M*| / max(|V|, 1)
//!   + w_depth Σ_{M* ∧ α > 1/2} |D - D*| / max(|M* ∧ α > 1/2|, 1)      (only when w_depth ≠ 0)
//! ```
//! `α > 1/2` selects pixels and carries no gradient (torch's `alpha.detach() > 0.5`); the
//! gradient of `|x|` at 0 is 0 (torch's `sgn`).

use rayon::prelude::*;

use crate::error::{invalid_input, Result};
use crate::render::real::Real;

/// Expected depth's threshold: below this α a pixel's depth is 0.
pub const DEPTH_ALPHA_MIN: f64 = 1e-6;

/// `v` images of `hw` pixels: checks the lengths of one per-pixel array.
fn check_len(name: &str, len: usize, images: usize, hw: usize, per: usize) -> Result<()> {
    if len != images * hw * per {
        return invalid_input(format!("{name} holds {len} values; expected {images} x {hw} x {per}"));
    }
    Ok(())
}

/// The background of image `v`: `[V, 3]` or one `[3]` for all.
fn background_of<T: Real>(background: Option<&[T]>, v: usize) -> [T; 3] {
    match background {
        None => [T::zero(); 3],
        Some(b) if b.len() == 3 => [b[0], b[1], b[2]],
        Some(b) => [b[3 * v], b[3 * v + 1], b[3 * v + 2]],
    }
}

fn check_background<T>(background: Option<&[T]>, images: usize) -> Result<()> {
    match background {
        Some(b) if b.len() != 3 && b.len() != 3 * images => {
            invalid_input(format!("background holds {} values; expected 3 or {images} x 3", b.len()))
        }
        _ => Ok(()),
    }
}

/// Finishes `images` images of `hw` pixels in place: `rgb` `[V, hw, 3]` gets the background
/// `[V, 3]` or `[3]` (None: black) behind the robot, `dsum` `[V, hw]` (`Σ w z`) becomes the
/// expected depth, given `alpha` `[V, hw]` (`Σ w`).
pub fn finish<T: Real>(rgb: &mut [T], dsum: &mut [T], alpha: &[T], background: Option<&[T]>, images: usize, hw: usize) -> Result<()> {
    check_len("rgb", rgb.len(), images, hw, 3)?;
    check_len("dsum", dsum.len(), images, hw, 1)?;
    check_len("alpha", alpha.len(), images, hw, 1)?;
    check_background(background, images)?;
    if hw == 0 {
        return Ok(());
    }
    let (one, lo) = (T::one(), T::c(DEPTH_ALPHA_MIN));
    rgb.par_chunks_mut(3 * hw).zip(dsum.par_chunks_mut(hw)).zip(alpha.par_chunks(hw)).enumerate().for_each(|(v, ((rgb, dsum), alpha))| {
        let b = background_of(background, v);
        for ((px, d), &a) in rgb.chunks_exact_mut(3).zip(dsum.iter_mut()).zip(alpha) {
            if background.is_some() {
                let t = one - a;
                for c in 0..3 {
                    px[c] = px[c] + t * b[c];
                }
            }
            *d = if a > lo { *d / a } else { T::zero() };
        }
    });
    Ok(())
}

/// The gradient of [`finish`], in place: `g_alpha` (w.r.t. the finished images' α) becomes the
/// gradient w.r.t. the raw α, `g_depth` (w.r.t. the expected depth) the gradient w.r.t.
/// `dsum`; `g_rgb` passes through unchanged. `alpha` and `depth` are the finished outputs.
#[allow(clippy::too_many_arguments)]
pub fn finish_backward<T: Real>(
    g_rgb: &[T],
    g_alpha: &mut [T],
    g_depth: &mut [T],
    alpha: &[T],
    depth: &[T],
    background: Option<&[T]>,
    images: usize,
    hw: usize,
) -> Result<()> {
    check_len("grad_rgb", g_rgb.len(), images, hw, 3)?;
    for (name, len) in [("grad_alpha", g_alpha.len()), ("grad_depth", g_depth.len()), ("alpha", alpha.len()), ("depth", depth.len())] {
        check_len(name, len, images, hw, 1)?;
    }
    check_background(background, images)?;
    if hw == 0 {
        return Ok(());
    }
    let lo = T::c(DEPTH_ALPHA_MIN);
    g_alpha
        .par_chunks_mut(hw)
        .zip(g_depth.par_chunks_mut(hw))
        .zip(g_rgb.par_chunks(3 * hw))
        .zip(alpha.par_chunks(hw).zip(depth.par_chunks(hw)))
        .enumerate()
        .for_each(|(v, (((ga, gd), gr), (alpha, depth)))| {
            let b = background_of(background, v);
            for i in 0..hw {
                let mut g = ga[i];
                if background.is_some() {
                    g = g - (gr[3 * i] * b[0] + gr[3 * i + 1] * b[1] + gr[3 * i + 2] * b[2]);
                }
                let a = alpha[i];
                if a > lo {
                    // D = dsum / α: ∂D/∂dsum = 1/α, ∂D/∂α = -dsum/α² = -D/α
                    g = g - gd[i] * depth[i] / a;
                    gd[i] = gd[i] / a;
                } else {
                    gd[i] = T::zero();
                }
                ga[i] = g;
            }
        });
    Ok(())
}

/// The targets of [`image_loss`]: per image, `rgb` `[V, hw, 3]` in [0, 1], `depth` `[V, hw]`
/// metres, `mask` `[V, hw]` (the robot's pixels), `valid` `[V, hw]` (the pixels a photo saw;
/// None: all), and the weights.
pub struct LossTargets<'a, T> {
    pub rgb: &'a [T],
    pub depth: &'a [T],
    pub mask: &'a [bool],
    pub valid: Option<&'a [bool]>,
    pub w_depth: T,
    pub w_mask: T,
}

impl<T: Real> LossTargets<'_, T> {
    fn check(&self, who: &str, images: usize, hw: usize) -> Result<()> {
        check_len("rgb_t", self.rgb.len(), images, hw, 3)?;
        check_len("depth_t", self.depth.len(), images, hw, 1)?;
        check_len("mask_t", self.mask.len(), images, hw, 1)?;
        if let Some(v) = self.valid {
            check_len("valid", v.len(), images, hw, 1)?;
        }
        if !(self.w_depth.is_finite() && self.w_mask.is_finite()) {
            return invalid_input(format!("{who}: w_depth ({:?}) and w_mask ({:?}) must be finite", self.w_depth.f64(), self.w_mask.f64()));
        }
        Ok(())
    }
}

/// `|M*|`, `|V|` and `|M* ∧ α > 1/2|` of one image, as the loss's denominators (`max(·, 1)`).
fn counts<T: Real>(mask: &[bool], valid: Option<&[bool]>, alpha: &[T]) -> [T; 3] {
    let half = T::c(0.5);
    let (mut m, mut md) = (0usize, 0usize);
    for (&k, &a) in mask.iter().zip(alpha) {
        m += k as usize;
        md += (k && a > half) as usize;
    }
    let v = valid.map_or(mask.len(), |v| v.iter().filter(|&&x| x).count());
    [m, v, md].map(|k| T::c(k.max(1) as f64))
}

/// The renders' and the targets' lengths for `images` images of `hw` pixels.
fn check_frame<T: Real>(
    who: &str,
    rgb: &[T],
    alpha: &[T],
    depth: &[T],
    targets: &LossTargets<'_, T>,
    images: usize,
    hw: usize,
) -> Result<()> {
    check_len("rgb", rgb.len(), images, hw, 3)?;
    check_len("alpha", alpha.len(), images, hw, 1)?;
    check_len("depth", depth.len(), images, hw, 1)?;
    targets.check(who, images, hw)
}

/// Image `v`'s slices of the renders and the targets, and its loss's denominators.
struct Image<'a, T> {
    rgb: &'a [T],
    rgb_t: &'a [T],
    alpha: &'a [T],
    depth: &'a [T],
    depth_t: &'a [T],
    mask: &'a [bool],
    valid: Option<&'a [bool]>,
    /// `max(|M*|, 1)`, `max(|V|, 1)`, `max(|M* ∧ α > 1/2|, 1)`.
    counts: [T; 3],
}

fn image<'a, T: Real>(rgb: &'a [T], alpha: &'a [T], depth: &'a [T], t: &LossTargets<'a, T>, v: usize, hw: usize) -> Image<'a, T> {
    let px = v * hw..(v + 1) * hw;
    let (alpha, mask) = (&alpha[px.clone()], &t.mask[px.clone()]);
    let valid = t.valid.map(|x| &x[px.clone()]);
    Image {
        rgb: &rgb[3 * px.start..3 * px.end],
        rgb_t: &t.rgb[3 * px.start..3 * px.end],
        alpha,
        depth: &depth[px.clone()],
        depth_t: &t.depth[px],
        mask,
        valid,
        counts: counts(mask, valid, alpha),
    }
}

/// Per-image losses `[V]` of finished images (`rgb` `[V, hw, 3]`, `alpha`, `depth` `[V, hw]`)
/// against `targets` (module docs).
pub fn image_loss<T: Real>(rgb: &[T], alpha: &[T], depth: &[T], targets: &LossTargets<'_, T>, images: usize, hw: usize) -> Result<Vec<T>> {
    check_frame("image_loss", rgb, alpha, depth, targets, images, hw)?;
    let (zero, half) = (T::zero(), T::c(0.5));
    Ok((0..images)
        .into_par_iter()
        .map(|v| {
            let Image { rgb, rgb_t, alpha, depth, depth_t, mask, valid, counts: [nm, nv, nmd] } = image(rgb, alpha, depth, targets, v, hw);
            // each pixel's term in T (as torch's element-wise ops), the sums in f64
            let (mut l_rgb, mut l_mask, mut l_depth) = (0.0f64, 0.0f64, 0.0f64);
            for i in 0..hw {
                let k = mask[i];
                let mt = if k { T::one() } else { zero };
                if k {
                    let d = [0, 1, 2].map(|c| rgb[3 * i + c] - rgb_t[3 * i + c]);
                    l_rgb += (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).f64();
                    if alpha[i] > half {
                        l_depth += (depth[i] - depth_t[i]).abs().f64();
                    }
                }
                if valid.is_none_or(|x| x[i]) {
                    l_mask += (alpha[i] - mt).abs().f64();
                }
            }
            let [l_rgb, l_mask, l_depth] = [l_rgb, l_mask, l_depth].map(T::c);
            // torch: l_rgb / n + w_mask * (l_mask / n) + (w_depth * l_depth) / n
            let mut loss = l_rgb / nm + targets.w_mask * (l_mask / nv);
            if targets.w_depth != zero {
                loss = loss + targets.w_depth * l_depth / nmd;
            }
            loss
        })
        .collect())
}

/// The gradient of `Σ_v seed_v L_v` ([`image_loss`]) w.r.t. `rgb`, `alpha` and `depth`.
#[allow(clippy::too_many_arguments)]
pub fn image_loss_backward<T: Real>(
    seed: &[T],
    rgb: &[T],
    alpha: &[T],
    depth: &[T],
    targets: &LossTargets<'_, T>,
    images: usize,
    hw: usize,
) -> Result<(Vec<T>, Vec<T>, Vec<T>)> {
    check_len("seed", seed.len(), images, 1, 1)?;
    check_frame("image_loss_backward", rgb, alpha, depth, targets, images, hw)?;
    let (zero, half, two) = (T::zero(), T::c(0.5), T::c(2.0));
    let sgn = |x: T| {
        if x > zero {
            T::one()
        } else if x < zero {
            -T::one()
        } else {
            zero
        }
    };
    let (mut g_rgb, mut g_alpha, mut g_depth) = (vec![zero; images * hw * 3], vec![zero; images * hw], vec![zero; images * hw]);
    if hw == 0 {
        return Ok((g_rgb, g_alpha, g_depth));
    }
    g_rgb.par_chunks_mut(3 * hw).zip(g_alpha.par_chunks_mut(hw)).zip(g_depth.par_chunks_mut(hw)).enumerate().for_each(
        |(v, ((gr, ga), gd))| {
            let Image { rgb, rgb_t, alpha, depth, depth_t, mask, valid, counts: [nm, nv, nmd] } = image(rgb, alpha, depth, targets, v, hw);
            // each term's seed over its denominator, as torch chains `sum / n` then `* w`
            let s = seed[v];
            let (c_rgb, c_mask) = (s / nm, targets.w_mask * s / nv);
            let c_depth = if targets.w_depth != zero { s / nmd * targets.w_depth } else { zero };
            for i in 0..hw {
                let k = mask[i];
                let mt = if k { T::one() } else { zero };
                if k {
                    for c in 0..3 {
                        gr[3 * i + c] = two * (rgb[3 * i + c] - rgb_t[3 * i + c]) * c_rgb;
                    }
                    if alpha[i] > half {
                        gd[i] = sgn(depth[i] - depth_t[i]) * c_depth;
                    }
                }
                if valid.is_none_or(|x| x[i]) {
                    ga[i] = sgn(alpha[i] - mt) * c_mask;
                }
            }
        },
    );
    Ok((g_rgb, g_alpha, g_depth))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(images: usize, hw: usize, seed: u64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let mut s = seed;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let rgb = (0..images * hw * 3).map(|_| next()).collect();
        // α over the whole range, exact zeros included (no robot there)
        let alpha = (0..images * hw).map(|k| if k % 7 == 0 { 0.0 } else { next() }).collect();
        let dsum = (0..images * hw).map(|_| 2.0 * next()).collect();
        (rgb, alpha, dsum)
    }

    /// Finishing then the loss, as one scalar `Σ_v seed_v L_v` of the raw images.
    #[allow(clippy::too_many_arguments)]
    fn total(rgb: &[f64], alpha: &[f64], dsum: &[f64], bg: &[f64], t: &LossTargets<'_, f64>, seed: &[f64], v: usize, hw: usize) -> f64 {
        let (mut r, mut d) = (rgb.to_vec(), dsum.to_vec());
        finish(&mut r, &mut d, alpha, Some(bg), v, hw).unwrap();
        image_loss(&r, alpha, &d, t, v, hw).unwrap().iter().zip(seed).map(|(l, s)| l * s).sum()
    }

    #[test]
    fn gradients_match_finite_differences() {
        let (v, hw) = (3, 40);
        let (rgb, alpha, dsum) = frame(v, hw, 1);
        let (rgb_t, _, depth_t) = frame(v, hw, 2);
        let mask: Vec<bool> = (0..v * hw).map(|k| k % 3 != 0).collect();
        let valid: Vec<bool> = (0..v * hw).map(|k| k % 5 != 1).collect();
        let bg = [0.2, 0.5, 0.9, 0.1, 0.0, 0.3, 1.0, 1.0, 1.0];
        let t = LossTargets { rgb: &rgb_t, depth: &depth_t, mask: &mask, valid: Some(&valid), w_depth: 3.0, w_mask: 0.5 };
        let seed = [1.0, -0.5, 2.0];
        // analytic: the loss's gradient, then back through finishing
        let (mut r, mut d) = (rgb.clone(), dsum.clone());
        finish(&mut r, &mut d, &alpha, Some(&bg), v, hw).unwrap();
        let (g_rgb, mut g_alpha, mut g_dsum) = image_loss_backward(&seed, &r, &alpha, &d, &t, v, hw).unwrap();
        finish_backward(&g_rgb, &mut g_alpha, &mut g_dsum, &alpha, &d, Some(&bg), v, hw).unwrap();
        let h = 1e-7;
        let fd = |which: usize, k: usize| {
            let (mut a, mut b, mut c) = (rgb.clone(), alpha.clone(), dsum.clone());
            let x = [&mut a, &mut b, &mut c][which].get_mut(k).unwrap();
            *x += h;
            let up = total(&a, &b, &c, &bg, &t, &seed, v, hw);
            let x = [&mut a, &mut b, &mut c][which].get_mut(k).unwrap();
            *x -= 2.0 * h;
            (up - total(&a, &b, &c, &bg, &t, &seed, v, hw)) / (2.0 * h)
        };
        for k in 0..v * hw {
            // the α > 1/2 selection is a step: skip pixels within the step's reach
            if (alpha[k] - 0.5).abs() < 1e-5 || (alpha[k] > 0.0 && alpha[k] < 1e-5) {
                continue;
            }
            for c in 0..3 {
                assert!((fd(0, 3 * k + c) - g_rgb[3 * k + c]).abs() < 1e-6, "rgb[{k}, {c}]");
            }
            assert!((fd(1, k) - g_alpha[k]).abs() < 1e-5 * (1.0 + g_alpha[k].abs()), "alpha[{k}]: {} vs {}", fd(1, k), g_alpha[k]);
            assert!((fd(2, k) - g_dsum[k]).abs() < 1e-5 * (1.0 + g_dsum[k].abs()), "dsum[{k}]");
        }
    }

    #[test]
    fn depth_is_zero_where_nothing_was_drawn_and_its_gradient_too() {
        let (mut rgb, mut dsum, alpha) = (vec![0.0f32; 6], vec![0.0f32, 0.3], vec![0.0f32, 0.5]);
        finish(&mut rgb, &mut dsum, &alpha, Some(&[1.0, 0.5, 0.25]), 1, 2).unwrap();
        assert_eq!(dsum, vec![0.0, 0.6]);
        assert_eq!(&rgb[..3], &[1.0, 0.5, 0.25]);
        let (mut ga, mut gd) = (vec![0.0f32; 2], vec![1.0f32; 2]);
        finish_backward(&[0.0; 6], &mut ga, &mut gd, &alpha, &dsum, None, 1, 2).unwrap();
        assert_eq!(gd, vec![0.0, 2.0]);
        assert_eq!(ga, vec![0.0, -1.2]);
    }

    #[test]
    fn regression_wrong_lengths_are_errors_not_panics() {
        let mut rgb = vec![0.0f64; 5];
        assert!(finish(&mut rgb, &mut [0.0; 2], &[0.0; 2], None, 1, 2).is_err());
        assert!(finish(&mut [0.0f64; 6], &mut [0.0; 2], &[0.0; 2], Some(&[1.0, 2.0]), 1, 2).is_err());
        let t = LossTargets { rgb: &[0.0; 6], depth: &[0.0; 2], mask: &[true], valid: None, w_depth: 1.0, w_mask: 0.5 };
        assert!(image_loss(&[0.0f64; 6], &[0.0; 2], &[0.0; 2], &t, 1, 2).is_err());
    }
}
