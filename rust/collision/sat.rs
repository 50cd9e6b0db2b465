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

use nalgebra::{Isometry3, Vector3};
use parry3d_f64::query::details::intersection_test_support_map_support_map_with_params;
use parry3d_f64::query::gjk::VoronoiSimplex;
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
}
