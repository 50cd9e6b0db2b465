//! Balls inside each convex shape, and the overlaps they prove.
//!
//! The narrow phase proves most pairs apart cheaply (bounding spheres, boxes, remembered axes)
//! but pays a whole GJK run for every pair in contact: GJK stops only once its simplex holds the
//! origin. A pair whose geoms overlap deeply is proven in contact here instead, from a few balls
//! fixed inside each shape: a ball of one geom that reaches more than [`SLACK`] into the other
//! (measured exactly where the other is a primitive, ball against ball where both are hulls)
//! puts a common point inside both, deeper than GJK's tolerance, so GJK would report the
//! intersection too. Pairs these balls do not decide go on to GJK as before.
//!
//! A leaf module: it knows nalgebra, parry's primitive shapes and `hull`.

use nalgebra::{Isometry3, Point3, Vector3};
use parry3d_f64::shape::{Ball, Capsule, Cuboid, Cylinder};

use crate::geometry::hull::Hull;

/// How far (metres) a ball must reach into the other geom for the pair to count as proven in
/// contact: far above the rounding of the tests (~1e-15 m for geoms within metres of the
/// origin) and of GJK's own termination (relative ~1e-7 of the shapes' separation), far below
/// any overlap that matters (the balls are centimetres across).
pub const SLACK: f64 = 1e-5;

/// At most this many balls a shape: each costs a transform and a distance per test.
const MAX_BALLS: usize = 8;

/// At most this many balls a hull (two hulls test every ball of one against every ball of the
/// other).
const HULL_BALLS: usize = 4;

/// A ball inside a shape, in the shape's frame (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InnerBall {
    pub centre: Vector3<f64>,
    pub radius: f64,
}

/// A radius shrunk for rounding: the balls stay inside the shape although their centres and
/// radii were rounded (relative 1e-9, absolute 1e-12 m; both far below `SLACK`).
fn shrunk(r: f64) -> f64 {
    r * (1.0 - 1e-9) - 1e-12
}

/// `n` points evenly from `-half` to `half` (the middle one when `n == 1`).
fn spread(half: f64, n: usize) -> impl Iterator<Item = f64> {
    (0..n).map(move |i| if n == 1 { 0.0 } else { -half + 2.0 * half * i as f64 / (n - 1) as f64 })
}

/// How many balls of radius `r` it takes to cover a segment `2 half` long, at most `cap`.
fn count(half: f64, r: f64, cap: usize) -> usize {
    if half <= 0.0 {
        1
    } else {
        // (in floats first: a very long, thin shape must not overflow the cast)
        ((2.0 * half / r).ceil() + 1.0).clamp(2.0, cap as f64) as usize
    }
}

/// The ball itself.
pub fn of_ball(b: &Ball) -> Vec<InnerBall> {
    vec![InnerBall { centre: Vector3::zeros(), radius: shrunk(b.radius) }]
}

/// Balls of the capsule's radius along its segment, about a radius apart.
pub fn of_capsule(c: &Capsule) -> Vec<InnerBall> {
    let (a, b) = (c.segment.a.coords, c.segment.b.coords);
    let n = count((b - a).norm() / 2.0, c.radius, MAX_BALLS);
    spread(0.5, n).map(|t| InnerBall { centre: (a + b) / 2.0 + (b - a) * t, radius: shrunk(c.radius) }).collect()
}

/// Balls of the box's smallest half extent `ρ` on a grid whose centres stay `ρ` inside every
/// face: up to four along the longest axis, two along the middle one.
pub fn of_cuboid(c: &Cuboid) -> Vec<InnerBall> {
    let h = c.half_extents;
    let rho = h.min();
    let mut axes = [0usize, 1, 2];
    axes.sort_by(|&i, &j| h[j].total_cmp(&h[i]));
    let caps = [4, 2, 1];
    let mut n = [1usize; 3];
    for (&axis, &cap) in axes.iter().zip(&caps) {
        n[axis] = count(h[axis] - rho, rho, cap);
    }
    let mut out = Vec::with_capacity(n.iter().product());
    for x in spread(h.x - rho, n[0]) {
        for y in spread(h.y - rho, n[1]) {
            for z in spread(h.z - rho, n[2]) {
                out.push(InnerBall { centre: Vector3::new(x, y, z), radius: shrunk(rho) });
            }
        }
    }
    out
}

/// Balls of radius `min(radius, half height)` along parry's cylinder axis (y).
pub fn of_cylinder(c: &Cylinder) -> Vec<InnerBall> {
    let rho = c.radius.min(c.half_height);
    let half = c.half_height - rho;
    spread(half, count(half, rho, MAX_BALLS)).map(|y| InnerBall { centre: Vector3::new(0.0, y, 0.0), radius: shrunk(rho) }).collect()
}

/// The largest balls about points of the hull's longest chord (from the vertex farthest from
/// the centre to the vertex farthest from that one) and about its centre, each as deep as its
/// centre lies below every triangle of the hull; the deepest `HULL_BALLS` of them.
///
/// Depth is measured against each triangle's own plane (its normal from its three vertices, its
/// offset the largest over all the hull's vertices, so no vertex lies above it), not against
/// `Hull::planes`: those are parry's merged faces, whose one normal can tilt away from a
/// triangle folded by up to ~1.7e-4 rad (`hull_balls_stay_inside_a_face_folded_within_parrys_merge`).
pub fn of_hull(h: &Hull) -> Vec<InnerBall> {
    let points = h.points();
    let Some(depth) = hull_depth(h) else {
        return Vec::new();
    };
    let farthest = |from: Vector3<f64>| {
        points
            .iter()
            .map(|p| p.coords)
            .fold(from, |best, p| if (p - from).norm_squared() > (best - from).norm_squared() { p } else { best })
    };
    let c = h.centre();
    let a = farthest(c);
    let b = farthest(a);
    let mut balls: Vec<InnerBall> = (0..2 * MAX_BALLS)
        .map(|i| a + (b - a) * ((i as f64 + 0.5) / (2 * MAX_BALLS) as f64))
        .chain(std::iter::once(c))
        .map(|p| InnerBall { centre: p, radius: shrunk(depth(&p)) })
        .filter(|s| s.radius > SLACK)
        .collect();
    balls.sort_by(|s, t| t.radius.total_cmp(&s.radius));
    // Keep the deepest, skipping balls mostly inside one already kept.
    let mut kept: Vec<InnerBall> = Vec::new();
    for s in balls {
        if kept.len() == HULL_BALLS {
            break;
        }
        if kept.iter().all(|k| (k.centre - s.centre).norm() + 0.5 * s.radius > k.radius) {
            kept.push(s);
        }
    }
    kept
}

/// How deep a point lies inside the hull (metres; negative outside), by the hull's triangles:
/// the smallest over them of `d − n·p`, with `n` the triangle's unit normal from its vertices
/// and `d` the largest `n·v` over the hull's vertices `v`. Each such half-space holds the hull,
/// and their triangles are its facets, so this is its depth up to rounding. `None` when parry
/// cannot triangulate the vertices again.
fn hull_depth(h: &Hull) -> Option<impl Fn(&Vector3<f64>) -> f64> {
    let points = h.points();
    let (vertices, triangles) = parry3d_f64::transformation::try_convex_hull(points).ok()?;
    let planes: Vec<(Vector3<f64>, f64)> = triangles
        .iter()
        .filter_map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize].coords);
            let n = (b - a).cross(&(c - a)).try_normalize(1e-300)?;
            Some((n, points.iter().map(|p| n.dot(&p.coords)).fold(f64::NEG_INFINITY, f64::max)))
        })
        .collect();
    Some(move |p: &Vector3<f64>| planes.iter().map(|(n, d)| d - n.dot(p)).fold(f64::INFINITY, f64::min))
}

/// Distance (metres) from the point `p` (shape frame) to the ball, 0 inside.
pub fn outside_ball(b: &Ball, p: &Vector3<f64>) -> f64 {
    (p.norm() - b.radius).max(0.0)
}

/// Distance from `p` to the capsule, 0 inside.
pub fn outside_capsule(c: &Capsule, p: &Vector3<f64>) -> f64 {
    let (a, b) = (c.segment.a.coords, c.segment.b.coords);
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    ((p - (a + ab * t)).norm() - c.radius).max(0.0)
}

/// Distance from `p` to the box, 0 inside.
pub fn outside_cuboid(c: &Cuboid, p: &Vector3<f64>) -> f64 {
    (p.abs() - c.half_extents).sup(&Vector3::zeros()).norm()
}

/// Distance from `p` to the cylinder (axis y), 0 inside.
pub fn outside_cylinder(c: &Cylinder, p: &Vector3<f64>) -> f64 {
    let radial = ((p.x * p.x + p.z * p.z).sqrt() - c.radius).max(0.0);
    let axial = (p.y.abs() - c.half_height).max(0.0);
    (radial * radial + axial * axial).sqrt()
}

/// Whether one of `balls` (in the frame `pose` maps into the other shape's frame) reaches more
/// than `SLACK` into the shape whose exact distance from a point is `outside`.
#[inline]
pub fn reach_into(balls: &[InnerBall], pose: &Isometry3<f64>, outside: impl Fn(&Vector3<f64>) -> f64) -> bool {
    balls.iter().any(|s| outside(&(pose * Point3::from(s.centre)).coords) < s.radius - SLACK)
}

/// Whether a ball of `a` and a ball of `b` (`pos12`: b's frame in a's) overlap by more than
/// `SLACK`.
#[inline]
pub fn balls_overlap(a: &[InnerBall], b: &[InnerBall], pos12: &Isometry3<f64>) -> bool {
    b.iter().any(|t| {
        let c = (pos12 * Point3::from(t.centre)).coords;
        a.iter().any(|s| (s.centre - c).norm() < s.radius + t.radius - SLACK)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    use parry3d_f64::query::PointQuery;
    use rand::{Rng, SeedableRng};

    /// Every inner ball lies inside its shape: random points of the ball (on its sphere) project
    /// inside the shape by parry's own point query, for boxes flat and long, capsules, cylinders
    /// squat and tall, and a hull.
    #[test]
    fn inner_balls_lie_inside_their_shapes() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let hull_pts: Vec<Point3<f64>> =
            (0..60).map(|_| Point3::new(rng.random_range(-0.3..0.3), rng.random_range(-0.05..0.05), rng.random_range(-0.1..0.1))).collect();
        let hull = Hull::new(&hull_pts).unwrap();
        let cases: Vec<(Vec<InnerBall>, Box<dyn PointQuery>)> = vec![
            (of_ball(&Ball::new(0.1)), Box::new(Ball::new(0.1))),
            (of_capsule(&Capsule::new_z(0.3, 0.02)), Box::new(Capsule::new_z(0.3, 0.02))),
            (of_cuboid(&Cuboid::new(Vector3::new(0.5, 0.4, 0.01))), Box::new(Cuboid::new(Vector3::new(0.5, 0.4, 0.01)))),
            (of_cuboid(&Cuboid::new(Vector3::new(0.02, 0.3, 0.05))), Box::new(Cuboid::new(Vector3::new(0.02, 0.3, 0.05)))),
            (of_cylinder(&Cylinder::new(0.3, 0.02)), Box::new(Cylinder::new(0.3, 0.02))),
            (of_cylinder(&Cylinder::new(0.01, 0.2)), Box::new(Cylinder::new(0.01, 0.2))),
            (of_hull(&hull), Box::new(hull.poly().clone())),
        ];
        for (i, (balls, shape)) in cases.iter().enumerate() {
            assert!(!balls.is_empty() && balls.len() <= MAX_BALLS, "case {i}: {} balls", balls.len());
            for s in balls {
                for _ in 0..200 {
                    let d = Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)).normalize();
                    let p = Point3::from(s.centre + d * s.radius);
                    assert!(shape.distance_to_local_point(&p, true) <= 1e-12, "case {i}: ball {s:?} leaves the shape at {p:?}");
                }
            }
        }
    }

    /// Review of 7bb452e: a hull's balls were sized by parry's merged faces, whose one normal
    /// can tilt away from the triangles of a face folded by less than parry's merge angle, so a
    /// ball could reach tens of micrometres out of the hull GJK sees. A 1 m x 1 m x 2 cm slab
    /// whose top is folded down 100 um at one corner (1.4e-4 rad: parry merges the two top
    /// triangles into one face): at points all over it, the depth the balls are sized by is
    /// never more than the true depth (under both top triangles and inside the other faces),
    /// where the merged faces' depth is more by over `SLACK` near the lowered corner.
    #[test]
    fn hull_balls_stay_inside_a_face_folded_within_parrys_merge() {
        let (h, t, fold) = (0.5, 0.01, 1e-4);
        let mut pts = Vec::new();
        for (x, y) in [(-h, -h), (h, -h), (-h, h), (h, h)] {
            pts.push(Point3::new(x, y, -t));
            pts.push(Point3::new(x, y, if (x, y) == (h, h) { t - fold } else { t }));
        }
        let hull = Hull::new(&pts).unwrap();
        let depth = hull_depth(&hull).unwrap();
        // The true facets: the bottom, the four sides, the flat top triangle and the one tilted
        // down to the lowered corner.
        let tilted = {
            let (a, b, c) = (Vector3::new(h, -h, t), Vector3::new(-h, h, t), Vector3::new(h, h, t - fold));
            let n = (b - a).cross(&(c - a)).normalize();
            let n = if n.z < 0.0 { -n } else { n };
            (n, n.dot(&a))
        };
        let truth = |p: &Vector3<f64>| {
            [t - p.z, p.z + t, h - p.x.abs(), h - p.y.abs(), tilted.1 - tilted.0.dot(p)].into_iter().fold(f64::INFINITY, f64::min)
        };
        let merged = |p: &Vector3<f64>| hull.planes().iter().map(|(n, d)| d - n.dot(p)).fold(f64::INFINITY, f64::min);
        let mut worst_merged = f64::NEG_INFINITY;
        for i in 0..=20 {
            for j in 0..=20 {
                let p = Vector3::new(-0.45 + 0.045 * i as f64, -0.45 + 0.045 * j as f64, 0.0);
                assert!(depth(&p) <= truth(&p) + 1e-12, "{p:?}: depth {} against {}", depth(&p), truth(&p));
                worst_merged = worst_merged.max(merged(&p) - truth(&p));
            }
        }
        assert!(worst_merged > SLACK, "the merged faces' depth is off by {worst_merged} m at most");
        for s in of_hull(&hull) {
            assert!(s.radius <= truth(&s.centre) + 1e-12, "ball {s:?}");
        }
    }

    /// The exact outside distances agree with parry's point queries.
    #[test]
    fn outside_distances_are_parrys() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let (ball, caps, cub, cyl) =
            (Ball::new(0.1), Capsule::new_z(0.2, 0.05), Cuboid::new(Vector3::new(0.1, 0.2, 0.3)), Cylinder::new(0.2, 0.1));
        for _ in 0..2000 {
            let p = Vector3::new(rng.random_range(-0.6..0.6), rng.random_range(-0.6..0.6), rng.random_range(-0.6..0.6));
            let q = Point3::from(p);
            for (mine, theirs) in [
                (outside_ball(&ball, &p), ball.distance_to_local_point(&q, true)),
                (outside_capsule(&caps, &p), caps.distance_to_local_point(&q, true)),
                (outside_cuboid(&cub, &p), cub.distance_to_local_point(&q, true)),
                (outside_cylinder(&cyl, &p), cyl.distance_to_local_point(&q, true)),
            ] {
                assert!((mine - theirs).abs() < 1e-9, "{p:?}: {mine} against parry's {theirs}");
            }
        }
    }
}
