//! Four poses at once: nalgebra's quaternion, vector and matrix arithmetic, lane for lane.
//!
//! Forward kinematics (`kinematics::body_poses`) and the broad phase's spheres (`model/broad.rs`)
//! compose unit quaternions, rotate vectors and turn quaternions into matrices with nalgebra, one
//! pose at a time. Here the same products, sums and differences run in the same order on four
//! lanes (`F4`: one pose a lane), which the compiler lays out as vector instructions: every
//! lane's result is the scalar result bit for bit (IEEE arithmetic is per lane, and nothing is
//! fused or reassociated). The order of each formula is nalgebra 0.34's, written out beside it;
//! `kinematics::tests::four_lanes_are_body_poses_bit_for_bit` and
//! `collide::tests::poses_placed_four_at_a_time_are_placed_bit_for_bit` pin it on every bundled
//! robot. The labelling batches (`collide::label_batch`, `fastpath`) place four poses at a time.
//!
//! A leaf module: it knows nalgebra only.

use nalgebra::{Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3};

/// Four `f64`s, one pose a lane.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub(crate) struct F4(pub(crate) [f64; 4]);

impl F4 {
    #[inline(always)]
    pub(crate) fn splat(x: f64) -> F4 {
        F4([x; 4])
    }
}

macro_rules! lanewise {
    ($tr:ident, $f:ident, $op:tt) => {
        impl std::ops::$tr for F4 {
            type Output = F4;
            #[inline(always)]
            fn $f(self, o: F4) -> F4 {
                F4([self.0[0] $op o.0[0], self.0[1] $op o.0[1], self.0[2] $op o.0[2], self.0[3] $op o.0[3]])
            }
        }
    };
}
lanewise!(Add, add, +);
lanewise!(Sub, sub, -);
lanewise!(Mul, mul, *);

/// A vector a lane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct V4 {
    pub(crate) x: F4,
    pub(crate) y: F4,
    pub(crate) z: F4,
}

impl V4 {
    #[inline(always)]
    pub(crate) fn splat(v: &Vector3<f64>) -> V4 {
        V4 { x: F4::splat(v.x), y: F4::splat(v.y), z: F4::splat(v.z) }
    }

    /// nalgebra's `cross`: `(ay bz − az by, az bx − ax bz, ax by − ay bx)`.
    #[inline(always)]
    pub(crate) fn cross(&self, b: &V4) -> V4 {
        V4 { x: self.y * b.z - self.z * b.y, y: self.z * b.x - self.x * b.z, z: self.x * b.y - self.y * b.x }
    }

    #[inline(always)]
    pub(crate) fn add(&self, b: &V4) -> V4 {
        V4 { x: self.x + b.x, y: self.y + b.y, z: self.z + b.z }
    }

    #[inline(always)]
    pub(crate) fn sub(&self, b: &V4) -> V4 {
        V4 { x: self.x - b.x, y: self.y - b.y, z: self.z - b.z }
    }

    #[inline(always)]
    pub(crate) fn scale(&self, s: F4) -> V4 {
        V4 { x: self.x * s, y: self.y * s, z: self.z * s }
    }

    /// Bit `l` set where lane `l`'s squared distance to `b`, `(dx² + dy²) + dz²` as the scalar
    /// sphere tests sum it (`model/sphere_pairs.rs`), is at most `reach2`.
    #[inline(always)]
    pub(crate) fn within(&self, b: &V4, reach2: f64) -> u32 {
        let d = self.sub(b);
        let d2 = (d.x * d.x + d.y * d.y) + d.z * d.z;
        // (four compares and their bits or-ed, which the compiler turns into one vector compare
        // and a mask move)
        let m: [bool; 4] = std::array::from_fn(|l| d2.0[l] <= reach2);
        (m[0] as u32) | ((m[1] as u32) << 1) | ((m[2] as u32) << 2) | ((m[3] as u32) << 3)
    }
}

impl V4 {
    /// `within` in AVX2 registers, the same sums in the same order (so the same bits): LLVM
    /// vectorises the lane arrays of `within` or not as the code around it allows.
    ///
    /// # Safety
    /// The CPU has AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(crate) unsafe fn within_avx2(&self, b: &V4, reach2: f64) -> u32 {
        use std::arch::x86_64::*;
        // SAFETY (the loads): an `F4` is four `f64`s.
        let ld = |f: &F4| unsafe { _mm256_loadu_pd(f.0.as_ptr()) };
        let (dx, dy, dz) =
            (_mm256_sub_pd(ld(&self.x), ld(&b.x)), _mm256_sub_pd(ld(&self.y), ld(&b.y)), _mm256_sub_pd(ld(&self.z), ld(&b.z)));
        let d2 = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)), _mm256_mul_pd(dz, dz));
        _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(d2, _mm256_set1_pd(reach2))) as u32
    }

    /// `within`, in AVX2 registers where `AVX2`.
    ///
    /// # Safety
    /// With `AVX2`, the CPU has AVX2.
    #[inline(always)]
    pub(crate) unsafe fn within_in<const AVX2: bool>(&self, b: &V4, reach2: f64) -> u32 {
        #[cfg(target_arch = "x86_64")]
        if AVX2 {
            // SAFETY: as the caller promises.
            return unsafe { self.within_avx2(b, reach2) };
        }
        self.within(b, reach2)
    }
}

/// Four `f64` lanes in registers, for kernels written once: the portable arrays (`F4`), or
/// AVX2's (`Avx2`). The same IEEE operations in the same order, so the same bits.
///
/// Every operation is an `unsafe fn`: `Avx2`'s may run only on a CPU that has AVX2. (Kernels
/// call them from a function compiled with AVX2, `#[target_feature(enable = "avx2")]`, where
/// they inline: called from code compiled without it, they stay function calls.)
pub(crate) trait Reg: Copy {
    unsafe fn load(x: &F4) -> Self;
    unsafe fn splat(x: f64) -> Self;
    unsafe fn add(self, o: Self) -> Self;
    unsafe fn mul(self, o: Self) -> Self;
    unsafe fn abs(self) -> Self;
    /// Bit `l` set where lane `l` of `self` is above `o`'s (never for NaN).
    unsafe fn gt(self, o: Self) -> u32;
    /// `(a0 b0 + a1 b1) + a2 b2`, nalgebra's order.
    #[inline(always)]
    unsafe fn dot3(a: [Self; 3], b: [Self; 3]) -> Self {
        unsafe { a[0].mul(b[0]).add(a[1].mul(b[1])).add(a[2].mul(b[2])) }
    }
}

impl Reg for F4 {
    #[inline(always)]
    unsafe fn load(x: &F4) -> Self {
        *x
    }
    #[inline(always)]
    unsafe fn splat(x: f64) -> Self {
        F4([x; 4])
    }
    #[inline(always)]
    unsafe fn add(self, o: Self) -> Self {
        self + o
    }
    #[inline(always)]
    unsafe fn mul(self, o: Self) -> Self {
        self * o
    }
    #[inline(always)]
    unsafe fn abs(self) -> Self {
        F4(self.0.map(f64::abs))
    }
    #[inline(always)]
    unsafe fn gt(self, o: Self) -> u32 {
        let m: [bool; 4] = std::array::from_fn(|l| self.0[l] > o.0[l]);
        (m[0] as u32) | ((m[1] as u32) << 1) | ((m[2] as u32) << 2) | ((m[3] as u32) << 3)
    }
}

/// Four lanes in an AVX2 register (`Reg`'s safety contract).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct Avx2(std::arch::x86_64::__m256d);

// SAFETY (every intrinsic below): the CPU has AVX2, the contract of these `unsafe fn`s; the
// loads read the four `f64`s of an `F4`.
#[cfg(target_arch = "x86_64")]
impl Reg for Avx2 {
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn load(x: &F4) -> Self {
        Avx2(unsafe { std::arch::x86_64::_mm256_loadu_pd(x.0.as_ptr()) })
    }
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn splat(x: f64) -> Self {
        Avx2(std::arch::x86_64::_mm256_set1_pd(x))
    }
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn add(self, o: Self) -> Self {
        Avx2(std::arch::x86_64::_mm256_add_pd(self.0, o.0))
    }
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn mul(self, o: Self) -> Self {
        Avx2(std::arch::x86_64::_mm256_mul_pd(self.0, o.0))
    }
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn abs(self) -> Self {
        use std::arch::x86_64::*;
        Avx2(_mm256_andnot_pd(_mm256_set1_pd(-0.0), self.0))
    }
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn gt(self, o: Self) -> u32 {
        use std::arch::x86_64::*;
        _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_GT_OQ>(self.0, o.0)) as u32
    }
}

/// A unit quaternion a lane, `(i, j, k, w)` as nalgebra stores it.
#[derive(Clone, Copy)]
pub(crate) struct Q4 {
    pub(crate) i: F4,
    pub(crate) j: F4,
    pub(crate) k: F4,
    pub(crate) w: F4,
}

impl Q4 {
    #[inline(always)]
    pub(crate) fn splat(q: &UnitQuaternion<f64>) -> Q4 {
        Q4 { i: F4::splat(q.i), j: F4::splat(q.j), k: F4::splat(q.k), w: F4::splat(q.w) }
    }

    /// nalgebra's quaternion product, term by term in its order.
    #[inline(always)]
    pub(crate) fn mul(&self, r: &Q4) -> Q4 {
        let s = self;
        Q4 {
            w: s.w * r.w - s.i * r.i - s.j * r.j - s.k * r.k,
            i: s.w * r.i + s.i * r.w + s.j * r.k - s.k * r.j,
            j: s.w * r.j - s.i * r.k + s.j * r.w + s.k * r.i,
            k: s.w * r.k + s.i * r.j - s.j * r.i + s.k * r.w,
        }
    }

    /// nalgebra's `UnitQuaternion * Vector3`: `t = 2 (q.v × v)`, then `t w + q.v × t + v`.
    #[inline(always)]
    pub(crate) fn rotate(&self, v: &V4) -> V4 {
        let qv = V4 { x: self.i, y: self.j, z: self.k };
        let t = qv.cross(v).scale(F4::splat(2.0));
        let cross = qv.cross(&t);
        t.scale(self.w).add(&cross).add(v)
    }

    /// nalgebra's `Unit::renormalize_fast`: the coordinates times `0.5 (3 − |q|²)`, with `|q|²`
    /// summed as its 4-vector dot product does, `(i² + k²) + (j² + w²)` (added to a zero first,
    /// which changes nothing: the sum is positive).
    #[inline(always)]
    pub(crate) fn renormalize_fast(&self) -> Q4 {
        let sq = (self.i * self.i + self.k * self.k) + (self.j * self.j + self.w * self.w);
        let s = F4::splat(0.5) * (F4::splat(3.0) - sq);
        Q4 { i: self.i * s, j: self.j * s, k: self.k * s, w: self.w * s }
    }
}

/// An isometry a lane.
#[derive(Clone, Copy)]
pub(crate) struct Iso4 {
    pub(crate) t: V4,
    pub(crate) r: Q4,
}

impl Iso4 {
    #[inline(always)]
    pub(crate) fn splat(x: &Isometry3<f64>) -> Iso4 {
        Iso4 { t: V4::splat(&x.translation.vector), r: Q4::splat(&x.rotation) }
    }

    /// nalgebra's `Isometry * Isometry`: `(t_a + R_a t_b, R_a R_b)`.
    #[inline(always)]
    pub(crate) fn mul(&self, b: &Iso4) -> Iso4 {
        Iso4 { t: self.t.add(&self.r.rotate(&b.t)), r: self.r.mul(&b.r) }
    }

    /// Lane `l` as an isometry.
    #[inline(always)]
    pub(crate) fn lane(&self, l: usize) -> Isometry3<f64> {
        let q = Quaternion::new(self.r.w.0[l], self.r.i.0[l], self.r.j.0[l], self.r.k.0[l]);
        Isometry3::from_parts(Translation3::new(self.t.x.0[l], self.t.y.0[l], self.t.z.0[l]), UnitQuaternion::new_unchecked(q))
    }
}

/// A 3 x 3 matrix a lane, row by row.
#[derive(Clone, Copy)]
pub(crate) struct M4(pub(crate) [[F4; 3]; 3]);

impl M4 {
    /// nalgebra's `UnitQuaternion::to_rotation_matrix`, entry by entry in its order.
    #[inline(always)]
    pub(crate) fn rotation(q: &Q4) -> M4 {
        let two = F4::splat(2.0);
        let (i, j, k, w) = (q.i, q.j, q.k, q.w);
        let (ww, ii, jj, kk) = (w * w, i * i, j * j, k * k);
        let (ij, wk, wj, ik, jk, wi) = (i * j * two, w * k * two, w * j * two, i * k * two, j * k * two, w * i * two);
        M4([[ww + ii - jj - kk, ij - wk, wj + ik], [wk + ij, ww - ii + jj - kk, jk - wi], [ik - wj, wi + jk, ww - ii - jj + kk]])
    }

    /// nalgebra's `Matrix3 * Vector3` (its `gemv`, a column at a time): row `r` is
    /// `(m_r0 v_0 + m_r1 v_1) + m_r2 v_2`.
    #[inline(always)]
    pub(crate) fn mul_vec(&self, v: &V4) -> V4 {
        let row = |r: &[F4; 3]| r[0] * v.x + r[1] * v.y + r[2] * v.z;
        V4 { x: row(&self.0[0]), y: row(&self.0[1]), z: row(&self.0[2]) }
    }

    /// The same matrix in every lane.
    #[inline(always)]
    pub(crate) fn splat(m: &Matrix3<f64>) -> M4 {
        M4(std::array::from_fn(|r| std::array::from_fn(|c| F4::splat(m[(r, c)]))))
    }

    /// Lane `l` as a matrix.
    #[inline(always)]
    pub(crate) fn lane(&self, l: usize) -> Matrix3<f64> {
        let m = &self.0;
        Matrix3::new(
            m[0][0].0[l],
            m[0][1].0[l],
            m[0][2].0[l],
            m[1][0].0[l],
            m[1][1].0[l],
            m[1][2].0[l],
            m[2][0].0[l],
            m[2][1].0[l],
            m[2][2].0[l],
        )
    }
}

/// Per-thread room for four poses: their body frames (`kinematics::body_poses4`) and the
/// bodies' rotation matrices (`model/broad.rs`).
#[derive(Default)]
pub(crate) struct Frames4 {
    pub(crate) bodies: Vec<Iso4>,
    pub(crate) rots: Vec<M4>,
    /// The broad phase's sphere centres of the four poses: per body, per geom (`model/broad.rs`).
    pub(crate) body_centres: Vec<V4>,
    pub(crate) geom_centres: Vec<V4>,
}
