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

    /// The constant `x` in this type.
    fn c(x: f64) -> Self;

    /// This value as an `f64` (exact).
    fn f64(self) -> f64;
}

impl Real for f32 {
    const HAIR: f64 = 1e-5;
    const DEPTH_BITS: u32 = 32;

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
