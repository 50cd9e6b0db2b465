//! The float types the renderer computes in: `f32` for speed (float32 tensors), `f64` for
//! gradient checks (float64 tensors). One generic kernel serves both.

use num_traits::Float;

/// `f32` or `f64`.
pub trait Real: Float + Default + Send + Sync + std::fmt::Debug + 'static {
    /// Relative widening of the pixel boxes and row spans that decide which pixels a Gaussian
    /// may reach: a few units in the last place of this type, so that a pixel the exact test
    /// (in this type) would accept is never left out of the lists.
    const HAIR: f64;

    /// A positive value's bits as an integer that orders like the value (a positive float's
    /// bits do), in the low `DEPTH_BITS` bits.
    fn order_bits(self) -> u64;

    /// How many bits [`Real::order_bits`] uses.
    const DEPTH_BITS: u32;

    /// `e^x` for the splat kernel's `x ∈ [-87, 0]`: in `f32` a Cephes-style polynomial
    /// (relative error ≤ 2e-7, no libm call, a third of `expf`'s instructions); in `f64` the
    /// standard `exp`, so gradient checks see the exact function.
    fn exp_kernel(self) -> Self;

    /// The constant `x` in this type.
    fn c(x: f64) -> Self;

    /// This value as an `f64` (exact).
    fn f64(self) -> f64;
}

impl Real for f32 {
    const HAIR: f64 = 1e-5;
    const DEPTH_BITS: u32 = 32;

    #[inline(always)]
    fn exp_kernel(self) -> f32 {
        // e^x = 2^n e^r, n = round(x / ln 2), r = x - n ln 2 ∈ [-ln 2 / 2, ln 2 / 2] (ln 2 split in
        // two so that n ln 2 is exact), e^r by Cephes' expf polynomial.
        let x = self.clamp(-87.0, 88.0);
        // 1.5 · 2²³: adding it rounds to an integer, which then sits in the low mantissa bits
        // (bits(MAGIC + n) = bits(MAGIC) + n for |n| < 2²²), so 2ⁿ comes from integer
        // arithmetic alone, no float-to-int conversion (which would not vectorise).
        const MAGIC: f32 = 12_582_912.0;
        let shifted = x * std::f32::consts::LOG2_E + MAGIC;
        let n = shifted - MAGIC;
        let r = x - n * 0.693_359_4 - n * -2.121_944_4e-4;
        let mut p = 1.987_569_1e-4f32;
        p = p * r + 1.398_199_9e-3;
        p = p * r + 8.333_452e-3;
        p = p * r + 4.166_579_6e-2;
        p = p * r + 1.666_666_5e-1;
        p = p * r + 0.5;
        let e_r = p * r * r + r + 1.0;
        e_r * f32::from_bits(shifted.to_bits().wrapping_sub(MAGIC.to_bits()).wrapping_add(127) << 23)
    }

    #[inline(always)]
    fn order_bits(self) -> u64 {
        self.to_bits() as u64
    }

    #[inline(always)]
    fn c(x: f64) -> f32 {
        x as f32
    }

    #[inline(always)]
    fn f64(self) -> f64 {
        self as f64
    }
}

impl Real for f64 {
    const HAIR: f64 = 1e-9;
    const DEPTH_BITS: u32 = 64;

    #[inline(always)]
    fn exp_kernel(self) -> f64 {
        self.exp()
    }

    #[inline(always)]
    fn order_bits(self) -> u64 {
        self.to_bits()
    }

    #[inline(always)]
    fn c(x: f64) -> f64 {
        x
    }

    #[inline(always)]
    fn f64(self) -> f64 {
        self
    }
}

/// The index of the first non-finite value of `v`, if any: blocks scanned in parallel (one
/// flag each, not a shared atomic per value), then the first bad block searched in order.
pub(crate) fn first_non_finite<T: Real>(v: &[T]) -> Option<usize> {
    use rayon::prelude::*;
    const BLOCK: usize = 1 << 14;
    let bad: Vec<bool> = v.par_chunks(BLOCK).map(|c| c.iter().any(|x| !x.is_finite())).collect();
    let b = bad.iter().position(|&b| b)?;
    v[b * BLOCK..].iter().position(|x| !x.is_finite()).map(|k| b * BLOCK + k)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_non_finite_finds_the_first_in_any_block() {
        let mut v = vec![1.0f32; 100_000];
        assert_eq!(first_non_finite(&v), None);
        v[70_000] = f32::INFINITY;
        v[99_999] = f32::NAN;
        assert_eq!(first_non_finite(&v), Some(70_000));
        v[3] = f32::NAN;
        assert_eq!(first_non_finite(&v), Some(3));
    }

    #[test]
    fn f32_kernel_exp_within_2e7_of_exp() {
        let mut worst = 0.0f64;
        for k in 0..=200_000 {
            let x = -87.0 + 87.0 * k as f64 / 200_000.0;
            let (got, want) = ((x as f32).exp_kernel() as f64, (x as f32 as f64).exp());
            worst = worst.max(((got - want) / want).abs());
        }
        assert!(worst <= 2e-7, "{worst}");
    }
}
