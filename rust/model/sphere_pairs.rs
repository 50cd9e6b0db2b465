//! Many sphere-pair tests at once: which of a list of (centre, centre, squared reach) triples
//! have their centres within reach, as a bit mask. The broad phase's inner loop (`model/broad.rs`).
//!
//! Centres live in structure-of-arrays form (`Centres`: x, y, z apart), and a list in lanes of
//! four (`PairList`, padded), so that one AVX2 step gathers four pairs' coordinates and tests
//! them together. The AVX2 kernel and the portable one compute the same IEEE operations in the
//! same order (`dx·dx + dy·dy` then `+ dz·dz`, no fused multiply-add), so they give the same
//! bits; the tests compare them. A leaf module: it knows nothing of geoms or bodies.

/// Points in structure-of-arrays form (metres).
#[derive(Clone, Debug, Default)]
pub(crate) struct Centres {
    pub(crate) x: Vec<f64>,
    pub(crate) y: Vec<f64>,
    pub(crate) z: Vec<f64>,
}

impl Centres {
    pub(crate) fn zeros(n: usize) -> Self {
        Centres { x: vec![0.0; n], y: vec![0.0; n], z: vec![0.0; n] }
    }

    #[inline]
    pub(crate) fn set(&mut self, i: usize, p: &nalgebra::Vector3<f64>) {
        self.x[i] = p.x;
        self.y[i] = p.y;
        self.z[i] = p.z;
    }

    #[inline]
    pub(crate) fn get(&self, i: usize) -> nalgebra::Vector3<f64> {
        nalgebra::Vector3::new(self.x[i], self.y[i], self.z[i])
    }
}

/// Pairs of centres (indices into a `Centres`) and the squared distance within which each pair
/// passes, in lanes of `LANES`: a run that starts on a lane boundary is padded with pairs that
/// never pass (centre 0 with itself, squared reach -1).
#[derive(Clone, Debug, Default)]
pub(crate) struct PairList {
    i: Vec<u32>,
    j: Vec<u32>,
    reach2: Vec<f64>,
}

/// Pairs tested per step.
pub(crate) const LANES: usize = 4;

impl PairList {
    /// Number of entries, padding included.
    pub(crate) fn len(&self) -> usize {
        self.i.len()
    }

    pub(crate) fn push(&mut self, i: u32, j: u32, reach2: f64) {
        self.i.push(i);
        self.j.push(j);
        self.reach2.push(reach2);
    }

    /// Pads to the next lane boundary with pairs that never pass.
    pub(crate) fn pad(&mut self) {
        while self.i.len() % LANES != 0 {
            self.push(0, 0, -1.0);
        }
    }

    /// Bit `t` set when entry `start + t` passes: `|c[i] - c[j]|² <= reach2`, for `t` in
    /// `0..len`. `start` is a lane boundary, `len <= 64`, and `start + len` rounded up to a lane
    /// boundary is within the list (padded runs); the centres hold every index the list names.
    #[inline(always)]
    pub(crate) fn mask_portable(&self, c: &Centres, start: usize, len: usize) -> u64 {
        let mut bits = 0u64;
        for t in 0..len {
            let (i, j) = (self.i[start + t] as usize, self.j[start + t] as usize);
            let (dx, dy, dz) = (c.x[i] - c.x[j], c.y[i] - c.y[j], c.z[i] - c.z[j]);
            let d2 = (dx * dx + dy * dy) + dz * dz;
            bits |= ((d2 <= self.reach2[start + t]) as u64) << t;
        }
        bits
    }

    /// `mask_portable`, four entries a step.
    ///
    /// # Safety
    /// The CPU has AVX2 (`has_avx2`); the run is laid out as `mask_portable` asks (the kernel
    /// reads entries up to the lane boundary after `start + len`), and every index the list
    /// holds is within the centres (the gathers are not bounds-checked).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(crate) unsafe fn mask_avx2(&self, c: &Centres, start: usize, len: usize) -> u64 {
        use std::arch::x86_64::*;
        debug_assert!(start % LANES == 0 && len <= 64 && start + len.div_ceil(LANES) * LANES <= self.len());
        let mut bits = 0u64;
        let (xi, yi, zi) = (c.x.as_ptr(), c.y.as_ptr(), c.z.as_ptr());
        for s in 0..len.div_ceil(LANES) {
            let e = start + s * LANES;
            let vi = _mm_loadu_si128(self.i.as_ptr().add(e) as *const __m128i);
            let vj = _mm_loadu_si128(self.j.as_ptr().add(e) as *const __m128i);
            let dx = _mm256_sub_pd(_mm256_i32gather_pd::<8>(xi, vi), _mm256_i32gather_pd::<8>(xi, vj));
            let dy = _mm256_sub_pd(_mm256_i32gather_pd::<8>(yi, vi), _mm256_i32gather_pd::<8>(yi, vj));
            let dz = _mm256_sub_pd(_mm256_i32gather_pd::<8>(zi, vi), _mm256_i32gather_pd::<8>(zi, vj));
            let d2 = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)), _mm256_mul_pd(dz, dz));
            let pass = _mm256_cmp_pd::<_CMP_LE_OQ>(d2, _mm256_loadu_pd(self.reach2.as_ptr().add(e)));
            bits |= (_mm256_movemask_pd(pass) as u64) << (s * LANES);
        }
        // (the last step may test padding: drop its bits)
        if len < 64 {
            bits &= (1u64 << len) - 1;
        }
        bits
    }
}

/// Whether the AVX2 kernel may run here.
pub(crate) fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The AVX2 kernel and the portable one give the same mask on every run of a padded list,
    /// and the mask is the definition's, pair by pair (a pair exactly at its reach passes).
    #[test]
    fn avx2_mask_is_the_portable_one_and_the_definition() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let n = 40;
        let mut c = Centres::zeros(n);
        for i in 0..n {
            c.set(i, &nalgebra::Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)));
        }
        let mut list = PairList::default();
        let mut runs = Vec::new();
        for len in [1usize, 3, 4, 5, 8, 13, 64] {
            let start = list.len();
            for t in 0..len {
                let (i, j) = (rng.random_range(0..n) as u32, rng.random_range(0..n) as u32);
                let d = c.get(i as usize) - c.get(j as usize);
                let d2 = (d.x * d.x + d.y * d.y) + d.z * d.z;
                // some exactly at reach, some just under, some over
                let reach2 = match t % 3 {
                    0 => d2,
                    1 => d2 * 0.999,
                    _ => rng.random_range(0.0..3.0),
                };
                list.push(i, j, reach2);
            }
            list.pad();
            runs.push((start, len));
        }
        for &(start, len) in &runs {
            let want: u64 = (0..len)
                .map(|t| {
                    let e = start + t;
                    let d = c.get(list.i[e] as usize) - c.get(list.j[e] as usize);
                    (((d.x * d.x + d.y * d.y) + d.z * d.z <= list.reach2[e]) as u64) << t
                })
                .sum();
            assert_eq!(list.mask_portable(&c, start, len), want);
            assert!(want != 0);
            #[cfg(target_arch = "x86_64")]
            if has_avx2() {
                // SAFETY: AVX2 is there, the runs are padded, the indices within the centres.
                assert_eq!(unsafe { list.mask_avx2(&c, start, len) }, want, "run at {start}, {len} long");
            }
        }
    }
}
