//! Seeded uniform pose sampling that gives the same poses whatever the thread count.
//!
//! Poses are generated in fixed blocks of [`BLOCK`]; block `c` draws from ChaCha8 seeded with
//! `seed` on stream `c`. Which thread fills a block never changes what it holds.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::error::{invalid_input, Result};

/// Poses per independently seeded block.
pub const BLOCK: usize = 1024;

/// `n` poses drawn uniformly in `ranges` (`(K, 2)`, low and high per joint), row-major `(n, K)`.
///
/// # Example
/// ```
/// let a = profrobot::sample_uniform(&[[-1.0, 1.0], [0.0, 0.04]], 3000, 7).unwrap();
/// let b = profrobot::sample_uniform(&[[-1.0, 1.0], [0.0, 0.04]], 3000, 7).unwrap();
/// assert_eq!(a, b);
/// assert!(a.chunks(2).all(|q| (-1.0..=1.0).contains(&q[0]) && (0.0..=0.04).contains(&q[1])));
/// ```
pub fn sample_uniform(ranges: &[[f64; 2]], n: usize, seed: u64) -> Result<Vec<f64>> {
    let k = ranges.len();
    if k == 0 {
        return invalid_input("no joints to sample");
    }
    if n == 0 {
        return invalid_input("the number of poses must be positive");
    }
    for (j, &[lo, hi]) in ranges.iter().enumerate() {
        if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
            return invalid_input(format!("joint {j} has an unusable range [{lo}, {hi}]"));
        }
    }
    let mut out = vec![0.0; crate::budget::check("n (poses to sample)", &[n, k], 8)?];
    out.par_chunks_mut(BLOCK * k).enumerate().for_each(|(c, block)| fill_block(ranges, seed, c, block));
    Ok(out)
}

/// Fills `block` (at most [`BLOCK`] poses, row-major) with block `c` of `sample_uniform(ranges,
/// .., seed)`, on the calling thread (`ranges` already checked).
pub(crate) fn fill_block(ranges: &[[f64; 2]], seed: u64, c: usize, block: &mut [f64]) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(c as u64);
    for q in block.chunks_exact_mut(ranges.len()) {
        for (v, &[lo, hi]) in q.iter_mut().zip(ranges) {
            *v = lo + (hi - lo) * rng.random::<f64>();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_poses_on_one_and_two_threads() {
        let ranges = [[-2.0, 2.0], [0.0, 1.0], [-0.5, 0.5]];
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap().install(|| sample_uniform(&ranges, 5000, 3).unwrap());
        let two = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap().install(|| sample_uniform(&ranges, 5000, 3).unwrap());
        assert_eq!(one, two);
        assert_ne!(one, sample_uniform(&ranges, 5000, 4).unwrap());
    }

    #[test]
    fn samples_cover_the_range_uniformly() {
        let v = sample_uniform(&[[2.0, 4.0]], 100_000, 1).unwrap();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        assert!((mean - 3.0).abs() < 0.01, "{mean}");
        assert!(v.iter().all(|x| (2.0..=4.0).contains(x)));
    }
}
