//! `sin` and `cos` of a hinge's half angle: rust-lang's `libm` (musl's, from FreeBSD's msun)
//! rather than the platform's, one pose or four lanes at a time.
//!
//! Forward kinematics needs `(sin, cos)` of half of every hinge angle (the joint's quaternion).
//! glibc's `sincos` took 100-130 instructions a call, a tenth of a `collides` pose, part of it
//! saving and restoring the floating-point environment; and each platform's libm rounds some
//! arguments its own way (glibc and msun differ in the last bit on ~6 % of arguments), so the
//! frames, and the distances measured from them, depended on the platform. `libm::sincos` is
//! IEEE `+ - *` only: the same bits everywhere, within one unit in the last place of the truth.
//!
//! `sin_cos4` lays the same arithmetic out over four lanes for the arguments a half angle
//! usually has, `|x| <= 5 pi / 4` (msun's direct kernels up to pi/4, its "small" reduction with
//! one fixed quadrant per range beyond), and hands any quad with another argument (beyond
//! 5 pi / 4, within about 2^-20 of pi/2 or pi, where msun reduces further, or not finite) to
//! `libm::sincos` lane by lane. `tests` pin it to `libm::sincos` bit for bit. (The same bits
//! on every platform with IEEE double arithmetic: x86-64, aarch64; not x87-only targets.)
//!
//! The coefficients and pi/2's pieces are msun's (`k_sin.c`, `k_cos.c`, `e_rem_pio2.c`), under
//! its notice:
//!
//! > Copyright (C) 1993 by Sun Microsystems, Inc. All rights reserved.
//! > Developed at SunPro, a Sun Microsystems, Inc. business.
//! > Permission to use, copy, modify, and distribute this software is freely granted, provided
//! > that this notice is preserved.

const PIO2_1: f64 = f64::from_bits(0x3FF9_21FB_5440_0000); // first 33 bits of pi/2
const PIO2_1T: f64 = f64::from_bits(0x3DD0_B461_1A62_6331); // pi/2 - PIO2_1

const S1: f64 = f64::from_bits(0xBFC5_5555_5555_5549); // -1.66666666666666324348e-01
const S2: f64 = f64::from_bits(0x3F81_1111_1110_F8A6); // 8.33333333332248946124e-03
const S3: f64 = f64::from_bits(0xBF2A_01A0_19C1_61D5); // -1.98412698298579493134e-04
const S4: f64 = f64::from_bits(0x3EC7_1DE3_57B1_FE7D); // 2.75573137070700676789e-06
const S5: f64 = f64::from_bits(0xBE5A_E5E6_8A2B_9CEB); // -2.50507602534068634195e-08
const S6: f64 = f64::from_bits(0x3DE5_D93A_5ACF_D57C); // 1.58969099521155010221e-10

const C1: f64 = f64::from_bits(0x3FA5_5555_5555_554C); // 4.16666666666666019037e-02
const C2: f64 = f64::from_bits(0xBF56_C16C_16C1_5177); // -1.38888888888741095749e-03
const C3: f64 = f64::from_bits(0x3EFA_01A0_19CB_1590); // 2.48015872894767294178e-05
const C4: f64 = f64::from_bits(0xBE92_7E4F_809C_52AD); // -2.75573143513906633035e-07
const C5: f64 = f64::from_bits(0x3E21_EE9E_BDB4_B1C4); // 2.08757232129817482790e-09
const C6: f64 = f64::from_bits(0xBDA8_FAE9_BE88_38D4); // -1.13596475577881948265e-11

/// `(sin x, cos x)`: `libm::sincos`, the same bits on every platform (module docs).
#[inline(always)]
pub(crate) fn sin_cos(x: f64) -> (f64, f64) {
    libm::sincos(x)
}

/// `sin_cos` of four arguments, bit for bit, laid out for vector instructions (module docs).
///
/// msun's `sincos` by the high word `ix` of `|x|`: below `0x3e46a09e` (|x| < 2^-27 sqrt 2)
/// `(x, 1)`; up to `0x3fe921fb` (pi/4) the kernels on `x` itself; up to `0x4002d97c` (3 pi/4)
/// and `0x400f6a7a` (5 pi/4), one and two quarter turns taken off with pi/2's first two pieces
/// (`z = x - n PIO2_1`, `y0 = z - n PIO2_1T`, `y1 = (z - y0) - n PIO2_1T`), then the kernels
/// on `y0 + y1` and the quadrant's swap and signs. A quad with a lane beyond 5 pi / 4, near
/// pi/2 or pi (`ix & 0xfffff == 0x921fb`, where msun reduces further) or not finite goes to
/// `sin_cos` lane by lane.
#[inline(always)]
pub(crate) fn sin_cos4(x: [f64; 4]) -> ([f64; 4], [f64; 4]) {
    let ix = x.map(|v| ((v.to_bits() >> 32) & 0x7fff_ffff) as u32);
    let other = ix.map(|i| (i > 0x3fe9_21fb) & ((i > 0x400f_6a7a) | (i & 0xfffff == 0x921fb)));
    if other[0] | other[1] | other[2] | other[3] {
        let (mut s, mut c) = ([0.0; 4], [0.0; 4]);
        for l in 0..4 {
            (s[l], c[l]) = sin_cos(x[l]);
        }
        return (s, c);
    }
    // (each step on all four lanes at once: lane-wise arithmetic and selects, no branches)
    let f4 = |f: &dyn Fn(usize) -> f64| -> [f64; 4] { std::array::from_fn(f) };
    let sel = |m: [bool; 4], a: [f64; 4], b: [f64; 4]| f4(&|l| if m[l] { a[l] } else { b[l] });
    let flip = |v: [f64; 4], m: [u64; 4]| f4(&|l| f64::from_bits(v[l].to_bits() ^ m[l]));
    // The quarter turns n: 0, 1 or 2, with x's sign.
    let turns: [u64; 4] = std::array::from_fn(|l| (ix[l] > 0x3fe9_21fb) as u64 + (ix[l] > 0x4002_d97c) as u64);
    let n = f4(&|l| f64::from_bits((turns[l] as f64).to_bits() | (x[l].to_bits() & (1 << 63))));
    let z = f4(&|l| x[l] - n[l] * PIO2_1);
    let y0 = f4(&|l| z[l] - n[l] * PIO2_1T);
    let y1 = f4(&|l| (z[l] - y0[l]) - n[l] * PIO2_1T);
    // msun's `__kernel_sin(y0, y1, iy)`, `iy = 0` where no turn was taken (y1 = 0 there), and
    // `__kernel_cos(y0, y1)`.
    let zz = f4(&|l| y0[l] * y0[l]);
    let w = f4(&|l| zz[l] * zz[l]);
    let r = f4(&|l| S2 + zz[l] * (S3 + zz[l] * S4) + zz[l] * w[l] * (S5 + zz[l] * S6));
    let v = f4(&|l| zz[l] * y0[l]);
    let ks0 = f4(&|l| y0[l] + v[l] * (S1 + zz[l] * r[l]));
    let ks1 = f4(&|l| y0[l] - ((zz[l] * (0.5 * y1[l] - v[l] * r[l]) - y1[l]) - v[l] * S1));
    let ks = sel(turns.map(|t| t == 0), ks0, ks1);
    let rc = f4(&|l| zz[l] * (C1 + zz[l] * (C2 + zz[l] * C3)) + w[l] * w[l] * (C4 + zz[l] * (C5 + zz[l] * C6)));
    let hz = f4(&|l| 0.5 * zz[l]);
    let wc = f4(&|l| 1.0 - hz[l]);
    let kc = f4(&|l| wc[l] + (((1.0 - wc[l]) - hz[l]) + (zz[l] * rc[l] - y0[l] * y1[l])));
    // The quadrant n mod 4 (msun's match, without branches): an odd n swaps sine and cosine,
    // bit 1 of n negates the sine, bit 1 of n + 1 the cosine.
    // (n as a two's complement integer: the turns, negated where x is negative)
    let q: [u64; 4] = std::array::from_fn(|l| {
        let negative = x[l].to_bits() >> 63;
        (turns[l] ^ negative.wrapping_neg()).wrapping_add(negative)
    });
    let odd = q.map(|q| q & 1 == 1);
    let s = flip(sel(odd, kc, ks), q.map(|q| (q & 2) << 62));
    let c = flip(sel(odd, ks, kc), q.map(|q| (q.wrapping_add(1) & 2) << 62));
    // (below 2^-27 sqrt 2, msun's early return)
    let tiny = ix.map(|i| i < 0x3e46_a09e);
    (sel(tiny, x, s), sel(tiny, [1.0; 4], c))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The constants are the decimal values msun prints beside them (as msun prints them).
    #[test]
    #[allow(clippy::excessive_precision)]
    fn constants_are_msuns() {
        for (bits, decimal) in [
            (S1, -1.66666666666666324348e-01),
            (S2, 8.33333333332248946124e-03),
            (S3, -1.98412698298579493134e-04),
            (S4, 2.75573137070700676789e-06),
            (S5, -2.50507602534068634195e-08),
            (S6, 1.58969099521155010221e-10),
            (C1, 4.16666666666666019037e-02),
            (C2, -1.38888888888741095749e-03),
            (C3, 2.48015872894767294178e-05),
            (C4, -2.75573143513906633035e-07),
            (C5, 2.08757232129817482790e-09),
            (C6, -1.13596475577881948265e-11),
            (PIO2_1, 1.57079632673412561417e+00),
            (PIO2_1T, 6.07710050650619224932e-11),
        ] {
            assert_eq!(bits, decimal);
        }
    }

    /// `sin_cos4` is `libm::sincos` bit for bit, lane by lane: on two million half angles
    /// within +-4 pi (most quads on the four-lane path, the rest handed over), on the range
    /// boundaries and multiples of pi/4 with their neighbours (the ones msun reduces further),
    /// tiny, subnormal, signed-zero and non-finite arguments, in every lane. And `libm::sincos`
    /// is within one unit in the last place of the platform's libm (each is within one of the
    /// truth).
    #[test]
    fn four_lanes_are_libms_sincos_bit_for_bit() {
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut uniform = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut args: Vec<f64> = (0..1_000_000).map(|_| (uniform() * 2.0 - 1.0) * 1.25 * std::f64::consts::PI).collect();
        args.extend((0..1_000_000).map(|_| (uniform() * 8.0 - 4.0) * std::f64::consts::PI));
        let mut special = Vec::new();
        for k in -16..=16 {
            special.push(k as f64 * std::f64::consts::FRAC_PI_4);
        }
        for hi in [0x3e46_a09eu64, 0x3fe9_21fb, 0x4002_d97c, 0x400f_6a7a] {
            special.push(f64::from_bits(hi << 32));
            special.push(f64::from_bits((hi << 32) | 0xffff_ffff));
        }
        special.extend([1e-300, 1e-9, 3e-8, 1.0e-320, 0.5, 1e5 + 0.25, 2e6, f64::INFINITY, f64::NAN, f64::MAX, f64::MIN_POSITIVE]);
        for v in special {
            let mut u = v;
            for _ in 0..6 {
                args.extend([u, -u]);
                u = u.next_up();
            }
        }
        args.extend([0.0, -0.0]);
        let same = |a: f64, b: f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        for (i, quad) in args.chunks(4).enumerate() {
            // (each quad also in another order, so every argument meets every lane)
            let mut x = [0.0; 4];
            for l in 0..4 {
                x[l] = quad[(l + i) % quad.len()];
            }
            let (s, c) = sin_cos4(x);
            for l in 0..4 {
                let (ws, wc) = libm::sincos(x[l]);
                assert!(
                    same(s[l], ws) && same(c[l], wc),
                    "lane {l}: sin_cos4({:e}) = ({:e}, {:e}); libm ({ws:e}, {wc:e})",
                    x[l],
                    s[l],
                    c[l]
                );
            }
        }
        let mut agree = 0usize;
        for &x in args.iter().filter(|x| x.abs() < 1e3) {
            let ((s, c), (ps, pc)) = (sin_cos(x), x.sin_cos());
            let ulps = |a: f64, b: f64| (a.to_bits() as i64).abs_diff(b.to_bits() as i64);
            assert!(ulps(s, ps) <= 1 && ulps(c, pc) <= 1, "{x:e}: ({s:e}, {c:e}) against ({ps:e}, {pc:e})");
            agree += (s == ps && c == pc) as usize;
        }
        assert!(agree as f64 > 0.9 * args.len() as f64, "{agree} of {}", args.len());
    }
}
