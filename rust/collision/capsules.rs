//! Two capsules measured in closed form: their signed distance is that of their segments less
//! the two radii, the same closed form MuJoCo's capsule-capsule collider uses.
//!
//! A capsule is the set of points within its radius of a segment (its Minkowski sum with a
//! ball), so two capsules are `dist(segments) - ra - rb` apart, penetrating when negative; the
//! closest points of the segments come from Ericson's clamped parameters (*Real-Time Collision
//! Detection*, 5.1.9), checked against the four ends' clamped projections for segments parallel
//! to within rounding (`closest_points`). Where a lower bound must hold whatever the rounding
//! (the certificates), `collide::Scratch::pair_lower_bound` takes the separation along the line
//! between these points from the two exact support points instead.
//!
//! Why not parry: its `intersection_test`, `distance` and `contact` treat capsules as generic
//! support maps (GJK, EPA), whose stopping rules leave micrometres on curved surfaces. The Shadow
//! Hand's finger capsules showed it: two capsules that MuJoCo and the segments put 4.2e-7 m into
//! each other were reported apart by all three (GJK's intersection test false, `distance`
//! 1.9e-6 m, `contact` 7.6e-6 m), so the labels missed the pair and a certification at 1e-6 m
//! clearance could have passed it (`tests::gjk_missed_a_finger_capsule_penetration_of_4e7_m`).
//! A leaf module: it knows nalgebra and parry's `Capsule` only.

use nalgebra::{Isometry3, Point3, Vector3};
use parry3d_f64::shape::Capsule;

/// Parameters `(s, t)` in [0, 1] of the closest points `p1 + s d1` and `p2 + t d2` of two
/// segments (Ericson 5.1.9; a degenerate segment is its point).
fn closest_parameters(p1: &Point3<f64>, d1: &Vector3<f64>, p2: &Point3<f64>, d2: &Vector3<f64>) -> (f64, f64) {
    const EPS: f64 = 1e-18;
    let r = p1 - p2;
    let (a, e, f) = (d1.dot(d1), d2.dot(d2), d2.dot(&r));
    if a <= EPS && e <= EPS {
        return (0.0, 0.0);
    }
    if a <= EPS {
        return (0.0, (f / e).clamp(0.0, 1.0));
    }
    let c = d1.dot(&r);
    if e <= EPS {
        return ((-c / a).clamp(0.0, 1.0), 0.0);
    }
    let b = d1.dot(d2);
    let denom = a * e - b * b;
    let s = if denom > 0.0 { ((b * f - c * e) / denom).clamp(0.0, 1.0) } else { 0.0 };
    let t = (b * s + f) / e;
    if t < 0.0 {
        ((-c / a).clamp(0.0, 1.0), 0.0)
    } else if t > 1.0 {
        (((b - c) / a).clamp(0.0, 1.0), 1.0)
    } else {
        (s, t)
    }
}

/// The point of segment `p + s d` (s in [0, 1]) nearest `x`: a clamped projection.
#[inline]
fn nearest_on(p: &Point3<f64>, d: &Vector3<f64>, x: &Point3<f64>) -> Point3<f64> {
    let dd = d.dot(d);
    let s = if dd > 0.0 { ((x - p).dot(d) / dd).clamp(0.0, 1.0) } else { 0.0 };
    p + d * s
}

/// A point of each capsule's segment (`a`'s, then `b`'s, both in `a`'s frame; `b` at `pos12`),
/// the two nearest to each other: Ericson's pair, or the nearest of an end of one segment to
/// the other segment where that is nearer. (When the segments are parallel to within rounding,
/// `a·e − b²` in Ericson's parameters is rounding alone and may put his `s` at the wrong end, up
/// to ~1e-8 rad × the length too far; the true minimum of two near-parallel segments is then at
/// an end, which the clamped projections find exactly. Near-parallel segments that cross inside
/// both, where neither is so, overlap their capsules by nearly the radii anyway.)
#[inline]
pub(crate) fn closest_points(a: &Capsule, b: &Capsule, pos12: &Isometry3<f64>) -> (Point3<f64>, Point3<f64>) {
    let (p1, q1) = (a.segment.a, a.segment.b);
    let (p2, q2) = (pos12 * b.segment.a, pos12 * b.segment.b);
    let (d1, d2) = (q1 - p1, q2 - p2);
    let (s, t) = closest_parameters(&p1, &d1, &p2, &d2);
    let mut best = (p1 + d1 * s, p2 + d2 * t);
    let mut best_d2 = (best.1 - best.0).norm_squared();
    for (x, y) in
        [(p1, nearest_on(&p2, &d2, &p1)), (q1, nearest_on(&p2, &d2, &q1)), (nearest_on(&p1, &d1, &p2), p2), (nearest_on(&p1, &d1, &q2), q2)]
    {
        let d = (y - x).norm_squared();
        if d < best_d2 {
            (best, best_d2) = ((x, y), d);
        }
    }
    best
}

/// Signed distance (metres; negative: penetration depth) of capsules `a` and `b`, `b` at
/// `pos12` in `a`'s frame.
#[inline]
pub(crate) fn signed_distance(a: &Capsule, b: &Capsule, pos12: &Isometry3<f64>) -> f64 {
    let (x, y) = closest_points(a, b, pos12);
    (y - x).norm() - a.radius - b.radius
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Quaternion, Translation3, UnitQuaternion};
    use parry3d_f64::query;
    use rand::{Rng, SeedableRng};

    /// The distance by another route: `f(s)`, the distance from the point at parameter `s` of
    /// `a`'s segment to `b`'s segment (a clamped projection), is convex in `s`, so a golden-section
    /// search finds its minimum; less the radii.
    fn reference_distance(a: &Capsule, b: &Capsule, pos12: &Isometry3<f64>) -> f64 {
        let (p2, q2) = (pos12 * b.segment.a, pos12 * b.segment.b);
        let f = |s: f64| {
            let x = a.segment.a + (a.segment.b - a.segment.a) * s;
            let d2 = q2 - p2;
            let t = if d2.norm_squared() > 0.0 { ((x - p2).dot(&d2) / d2.norm_squared()).clamp(0.0, 1.0) } else { 0.0 };
            (x - (p2 + d2 * t)).norm()
        };
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        let g = (5f64.sqrt() - 1.0) / 2.0;
        for _ in 0..200 {
            let (m1, m2) = (hi - g * (hi - lo), lo + g * (hi - lo));
            if f(m1) <= f(m2) {
                hi = m2
            } else {
                lo = m1
            }
        }
        f(0.5 * (lo + hi)).min(f(0.0)).min(f(1.0)) - a.radius - b.radius
    }

    /// On random placements (parallel, near-parallel, crossing and end-to-end segments among
    /// them), the distance is the reference's to 1e-12 m, never above parry's (GJK's distance
    /// is an upper bound) and the sign is GJK's intersection test's wherever the two are more
    /// than 1e-5 m from touching.
    #[test]
    fn agrees_with_parry_away_from_touching() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (mut hits, n) = (0, 20_000);
        for i in 0..n {
            let a = Capsule::new_z(rng.random_range(0.0..0.2), rng.random_range(0.005..0.05));
            let b = Capsule::new_z(rng.random_range(0.0..0.2), rng.random_range(0.005..0.05));
            let rot =
                UnitQuaternion::from_euler_angles(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0));
            // parallel, and parallel to within rounding (1e-9 to 1e-7 rad), where Ericson's
            // parameters alone can pick the wrong end
            let tiny = UnitQuaternion::from_euler_angles(rng.random_range(-1e-7..1e-7), rng.random_range(-1e-7..1e-7), 0.0);
            let rot = match i % 10 {
                0 => UnitQuaternion::identity(),
                1 | 2 => tiny,
                _ => rot,
            };
            let t = Vector3::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3));
            let pos12 = Isometry3::from_parts(Translation3::from(t), rot);
            let d = signed_distance(&a, &b, &pos12);
            if d.abs() > 1e-5 {
                let hit = query::details::intersection_test_support_map_support_map(&pos12, &a, &b);
                assert_eq!(d < 0.0, hit, "placement {i}: {d}");
                hits += hit as usize;
            }
            let want = reference_distance(&a, &b, &pos12);
            assert!((d - want).abs() < 1e-12, "placement {i}: {d} against {want}");
            if d > 1e-3 {
                // (parry's GJK distance is an upper bound, up to tens of micrometres loose on capsules)
                let parry = query::distance(&Isometry3::identity(), &a, &pos12, &b).unwrap();
                assert!(parry >= d - 1e-12 && parry - d < 1e-4, "placement {i}: {d} against parry's {parry}");
            }
        }
        assert!(hits > n / 40, "{hits} hits");
    }

    /// Touching end to end and side by side: distance 0 to rounding; 2e-9 m apart or into
    /// each other, the sign says so.
    #[test]
    fn touching_capsules_measure_zero() {
        let a = Capsule::new_z(0.1, 0.05);
        for (x, z, want) in [(0.1, 0.0, 0.0), (0.0, 0.3, 0.0), (0.1 + 2e-9, 0.0, 2e-9), (0.1 - 2e-9, 0.0, -2e-9)] {
            let d = signed_distance(&a, &a, &Isometry3::translation(x, 0.0, z));
            assert!((d - want).abs() < 1e-15, "at ({x}, {z}): {d}");
        }
        // a degenerate capsule (a ball) beside the other's side
        let ball = Capsule::new_z(0.0, 0.05);
        assert!((signed_distance(&a, &ball, &Isometry3::translation(0.09, 0.0, 0.0)) + 0.01).abs() < 1e-15);
    }

    /// Regression: two finger capsules of the Shadow Hand (radii 9 mm; `sample_uniform(.., 50 000,
    /// 12)` pose 12867, pair 434) that MuJoCo reports 4.2e-7 m into each other, and parry's GJK
    /// reported apart (its intersection test false, `distance` 1.9e-6 m).
    #[test]
    fn gjk_missed_a_finger_capsule_penetration_of_4e7_m() {
        let a = Capsule::new_z(0.0125, 0.009);
        let b = Capsule::new_z(0.02, 0.009);
        let rot = UnitQuaternion::from_quaternion(Quaternion::new(
            0.8381760973790613,
            -0.5419279942445407,
            0.02539171429446771,
            -0.055947651261542775,
        ));
        let pos12 = Isometry3::from_parts(Translation3::new(-0.018708619658212453, -0.021062984306305134, -0.026910523938801504), rot);
        let d = signed_distance(&a, &b, &pos12);
        assert!((d + 4.2e-7).abs() < 1e-9, "{d}");
        // (what parry said, pinned so that a parry that gets it right shows up here)
        assert!(!query::details::intersection_test_support_map_support_map(&pos12, &a, &b));
    }
}
