//! Remembered separating axes: a cheap proof that two convex geoms are apart, tried before GJK.
//!
//! When GJK finds a pair apart it returns a separating direction. The next time the pair reaches
//! the narrow phase (the next pose of the same thread) that direction, kept in the first geom's
//! frame, often still separates the two: the relative pose of two links moves with the few
//! joints between them only. One support point per geom along it (what one GJK iteration costs,
//! without the simplex) then decides the pair instead of a full GJK run.
//!
//! # Exactness
//! The test only ever proves separation, and only by more than `SLACK` beyond the margin: the
//! gap `min over B of d.b - max over A of d.a` along a unit `d` is computed from exact support
//! points (parry's, `shapes::Convex`) with rounding far below 1e-12 m for shapes within metres
//! of the origin. A pair it rejects is therefore farther apart than `margin + 1e-9 m`, where
//! GJK never reports an intersection (its simplex, inside the Minkowski difference, stays
//! 1e-9 from the origin, against its 1e-15 tolerance) nor parry's distance a value below the
//! margin: the answer is the one GJK would have given. When the test fails, GJK runs exactly
//! as before (same call, same start, no warm start), so nothing else changes. A leaf module:
//! it knows parry, nalgebra and `shapes` only.

use nalgebra::{Isometry3, Unit, Vector3};
use parry3d_f64::query::details::intersection_test_support_map_support_map_with_params;
use parry3d_f64::query::gjk::{CSOPoint, VoronoiSimplex};
use parry3d_f64::shape::SupportMap;

use crate::geometry::shapes::Convex;

/// Absolute slack (metres) a remembered axis must clear beyond the margin.
const SLACK: f64 = 1e-9;

/// Whether the unit axis `d` (in `a`'s frame; zero: none yet) proves `a` and `b` (at `pos12`
/// in `a`'s frame) farther apart than `margin + SLACK`.
#[inline]
pub(crate) fn separated_along(a: &Convex, b: &Convex, pos12: &Isometry3<f64>, d: &Vector3<f64>, margin: f64) -> bool {
    if *d == Vector3::zeros() {
        return false;
    }
    let pa = a.local_support_point(d);
    let pb = b.support_point(pos12, &-d);
    d.dot(&(pb.coords - pa.coords)) > margin + SLACK
}

/// parry's `intersection_test_support_map_support_map` (the same call: a fresh simplex, no
/// initial direction), after the remembered axis `axis`: `true` when in contact. A separating
/// direction GJK finds becomes the new remembered axis.
#[inline]
pub(crate) fn intersection_test_remembering(a: &Convex, b: &Convex, pos12: &Isometry3<f64>, axis: &mut Vector3<f64>) -> bool {
    if separated_along(a, b, pos12, axis, 0.0) {
        return false;
    }
    let (hit, dir) = intersection_test_support_map_support_map_with_params(pos12, a, b, &mut VoronoiSimplex::new(), None);
    if !hit {
        *axis = dir.into_inner();
    }
    hit
}

/// Relative precision at which [`separating_axis`] stops: the separation along its axis is then
/// within this share of the shapes' distance, which the certificate's steps (proportional to
/// the distance above the need) barely feel. Parry's own GJK converges to ~1.5e-7 of the cores'
/// distance, at ~6.5 support points a run on MotionBenchMaker's first plans; at 1e-3 and at 1e-2
/// (20 first plans, one thread, callgrind) 735 M → 703 M and 696 M instructions, the same paths.
const AXIS_PRECISION: f64 = 1e-2;

/// A unit axis (in `a`'s frame) along which `a` and `b` (at `pos12` in `a`'s frame) are apart
/// by nearly their distance, or by `enough`: GJK's iteration (parry's `VoronoiSimplex`, its
/// support points and its steps, as `gjk::closest_points` takes them) from the direction
/// `start`. The shapes are cores (`shapes::Core`), dilated by `rounding` (metres, summed) into the
/// shapes the caller measures. It stops where the separation along the current direction (a
/// lower bound on the distance) reaches `enough`, or, once the dilated shapes' separation is
/// above `floor` (the caller's least useful bound: a state is blocked below it, so a bound just
/// under it is never left for one just above), comes within [`AXIS_PRECISION`] of their distance
/// (from the simplex's distance to the origin, an upper bound; where `enough` is infinite, the
/// distance itself is wanted: within parry's own tolerance of the cores'), or where parry's
/// iteration stops; the direction of the largest separation met, the direction to the
/// simplex's closest point included where parry would return that. None where the shapes touch
/// or overlap, or GJK finds no separation.
///
/// Exactness is the caller's: a separation along any unit axis, from exact support points, is
/// a lower bound on the distance (`Scratch::pair_lower_bound`); the axis only makes it tight.
pub(crate) fn separating_axis<A, B>(
    a: &A,
    b: &B,
    pos12: &Isometry3<f64>,
    start: &Unit<Vector3<f64>>,
    rounding: f64,
    floor: f64,
    enough: f64,
) -> Option<Unit<Vector3<f64>>>
where
    A: SupportMap + ?Sized,
    B: SupportMap + ?Sized,
{
    let eps_tol = parry3d_f64::query::gjk::eps_tol();
    // (how far the separation may stay below the simplex's distance `max_bound`)
    let slack = |max_bound: f64, min_bound: f64| {
        if enough.is_finite() && min_bound - rounding > floor {
            AXIS_PRECISION * (max_bound - rounding)
        } else {
            eps_tol.sqrt() * max_bound
        }
    };
    let mut simplex = VoronoiSimplex::new();
    simplex.reset(CSOPoint::from_shapes(pos12, a, b, start));
    let mut proj = simplex.project_origin_and_reduce();
    let (mut best, mut best_dir) = (f64::NEG_INFINITY, None);
    // (the separation along `dir`: the distance is at least this)
    let mut measure = |dir: Unit<Vector3<f64>>| {
        let cso = CSOPoint::from_shapes(pos12, a, b, &dir);
        let min_bound = -dir.dot(&cso.point.coords);
        if min_bound > best {
            (best, best_dir) = (min_bound, Some(dir));
        }
        (cso, min_bound)
    };
    let mut max_bound = f64::MAX;
    for _ in 0..100 {
        // (the simplex's closest point to the origin: the distance is at most its norm)
        let (dir, dist) = Unit::try_new_and_get(-proj.coords, eps_tol)?;
        if dist >= max_bound {
            // (no progress: parry answers with the simplex's closest point, along `dir`)
            measure(dir);
            break;
        }
        max_bound = dist;
        let (cso, min_bound) = measure(dir);
        if min_bound >= enough || max_bound - min_bound <= slack(max_bound, min_bound) || !simplex.add_point(cso) {
            break;
        }
        proj = simplex.project_origin_and_reduce();
        if simplex.dimension() == 3 {
            // (the origin inside the simplex, or on it within GJK's tolerance)
            if min_bound < eps_tol {
                return None;
            }
            if let Some(dir) = Unit::try_new(-proj.coords, eps_tol) {
                measure(dir);
            }
            break;
        }
    }
    best_dir.filter(|_| best > 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use parry3d_f64::shape::{Capsule, Cuboid};

    #[test]
    fn remembered_axis_rejects_only_what_gjk_rejects() {
        let a = Convex::Cuboid(Cuboid::new(Vector3::new(0.1, 0.2, 0.3)));
        let b = Convex::Capsule(Capsule::new_z(0.2, 0.05));
        let mut axis = Vector3::zeros();
        let mut rejected = 0;
        for i in 0..2000 {
            let t = i as f64 * 0.01;
            let pos12 = Isometry3::from_parts(
                Translation3::new(0.3 * t.cos(), 0.4 * (1.3 * t).sin(), 0.2 * (0.7 * t).cos()),
                UnitQuaternion::from_euler_angles(t, 0.5 * t, 0.3),
            );
            let want = parry3d_f64::query::details::intersection_test_support_map_support_map(&pos12, &a, &b);
            let axis_before = axis;
            rejected += separated_along(&a, &b, &pos12, &axis_before, 0.0) as usize;
            assert_eq!(intersection_test_remembering(&a, &b, &pos12, &mut axis), want, "step {i}");
        }
        // Smooth motion: the remembered axis decides most separated steps.
        assert!(rejected > 500, "{rejected}");
    }

    #[test]
    fn touching_shapes_are_never_rejected_by_an_axis() {
        let a = Convex::Cuboid(Cuboid::new(Vector3::new(0.1, 0.1, 0.1)));
        // Face to face, exactly touching along x.
        let pos12 = Isometry3::translation(0.2, 0.0, 0.0);
        assert!(!separated_along(&a, &a, &pos12, &Vector3::x(), 0.0));
        // 2e-9 apart: proven only with no margin.
        let pos12 = Isometry3::translation(0.2 + 2e-9, 0.0, 0.0);
        assert!(separated_along(&a, &a, &pos12, &Vector3::x(), 0.0));
        assert!(!separated_along(&a, &a, &pos12, &Vector3::x(), 1e-9));
        assert!(!separated_along(&a, &a, &pos12, &Vector3::zeros(), 0.0));
    }

    /// The axis found is the distance's within `AXIS_PRECISION` (parry's distance between the
    /// shapes; on a capsule's core dilated by its radius too, a millimetre apart as a metre),
    /// or reaches `enough`, and clears a `floor` the distance clears; or, where nothing less is enough, is as tight as parry's own
    /// GJK run from the same start (to its tolerance, 1.5e-7 relative);
    /// the separation along it never exceeds the distance; shapes in contact give none.
    #[test]
    fn separating_axis_measures_the_distance_to_its_precision() {
        use parry3d_f64::query::gjk::{self, GJKResult};
        let (cuboid, capsule) = (Cuboid::new(Vector3::new(0.1, 0.2, 0.3)), Capsule::new_z(0.2, 0.05));
        let (a, b) = (Convex::Cuboid(cuboid), Convex::Capsule(capsule));
        let sep = |pos12: &Isometry3<f64>, n: &Vector3<f64>| n.dot(&(b.support_point(pos12, &-n).coords - a.local_support_point(n).coords));
        let (mut apart, mut touching, mut enough_met, mut near) = (0, 0, 0, 0);
        for i in 0..2000 {
            let t = i as f64 * 0.01;
            let pos12 = Isometry3::from_parts(
                Translation3::new(0.6 * t.cos(), 0.7 * (1.3 * t).sin(), 0.4 * (0.7 * t).cos()),
                UnitQuaternion::from_euler_angles(t, 0.5 * t, 0.3),
            );
            let d = parry3d_f64::query::distance(&Isometry3::identity(), &cuboid, &pos12, &capsule).unwrap();
            let start = Vector3::x_axis();
            let Some(n) = separating_axis(&a, &b, &pos12, &start, 0.0, 0.0, 0.5) else {
                assert!(d < 1e-9, "step {i}: no axis {d} m apart");
                touching += 1;
                continue;
            };
            apart += 1;
            let s = sep(&pos12, &n);
            assert!(s <= d + 1e-12, "step {i}: {s} above the distance {d}");
            assert!(s >= 0.5 || s >= d * (1.0 - AXIS_PRECISION) - 1e-12, "step {i}: {s} against {d}");
            enough_met += (s >= 0.5) as usize;
            // On the capsule's core (its segment) dilated by its radius, as the certificate runs
            // it: within the precision of the capsule's own distance, however near.
            let core = capsule.segment;
            if let Some(n) = separating_axis(&a, &core, &pos12, &start, capsule.radius, 0.0, 0.5) {
                let s = n.dot(&(core.support_point(&pos12, &-n).coords - a.local_support_point(&n).coords)) - capsule.radius;
                assert!(
                    s <= d + 1e-12 && (s >= 0.5 - capsule.radius || s >= d * (1.0 - AXIS_PRECISION) - 1e-12),
                    "step {i}: {s} against {d}"
                );
                near += (d < 0.01) as usize;
            }
            // A floor just under the distance that parry's converged GJK measures (a need the
            // pair barely clears): the bound clears it too, not 1 % short of the distance.
            let mut simplex = VoronoiSimplex::new();
            simplex.reset(CSOPoint::from_shapes(&pos12, &a, &core, &start));
            let GJKResult::ClosestPoints(p1, p2, _) = gjk::closest_points(&pos12, &a, &core, f64::MAX, true, &mut simplex) else {
                panic!("step {i}: parry found no closest points {d} m apart")
            };
            let n = (p2 - p1).normalize();
            let converged = n.dot(&(core.support_point(&pos12, &-n).coords - a.local_support_point(&n).coords)) - capsule.radius;
            if converged > 1e-6 {
                let floor = converged * (1.0 - 1e-5);
                let n = separating_axis(&a, &core, &pos12, &start, capsule.radius, floor, 2.0 * d + capsule.radius).unwrap();
                let s = n.dot(&(core.support_point(&pos12, &-n).coords - a.local_support_point(&n).coords)) - capsule.radius;
                assert!(s > floor, "step {i}: {s} not above the floor {floor} ({d})");
            }
            // With nothing less enough, as tight as parry's GJK from the same start.
            let exact = separating_axis(&a, &b, &pos12, &start, 0.0, 0.0, f64::INFINITY).unwrap();
            let mut simplex = VoronoiSimplex::new();
            simplex.reset(CSOPoint::from_shapes(&pos12, &a, &b, &start));
            let GJKResult::ClosestPoints(p1, p2, _) = gjk::closest_points(&pos12, &a, &b, f64::MAX, true, &mut simplex) else {
                panic!("step {i}: parry found no closest points {d} m apart")
            };
            let (ours, parry) = (sep(&pos12, &exact), sep(&pos12, &(p2 - p1).normalize()));
            assert!(ours >= parry - 2e-7 * d - 1e-15, "step {i}: {ours} against {parry} ({d})");
        }
        assert!(
            apart > 300 && touching > 50 && enough_met > 10 && near > 10,
            "{apart} apart, {touching} touching, {enough_met} enough, {near} within 1 cm"
        );
    }
}
