//! parry shapes from MuJoCo geom descriptions.
//!
//! MuJoCo collides primitives exactly and meshes as their convex hulls; planes are half-spaces
//! (`z <= 0` in the plane's frame). Each geom becomes a [`Solid`], one of these two cases, plus
//! a fixed rotation where parry's axis convention differs from MuJoCo's (cylinders: parry's
//! axis is y, MuJoCo's z). A point cloud (`geometry/cloud.rs`: a union of balls, not a MuJoCo geom) is
//! the third case.

use nalgebra::{Isometry3, Point3, Unit, UnitQuaternion, Vector3};
use parry3d_f64::query::details::local_point_projection_on_support_map;
use parry3d_f64::query::gjk::VoronoiSimplex;
use parry3d_f64::shape::{Ball, Capsule, Cuboid, Cylinder, Segment, Shape, SupportMap};

use std::sync::Arc;

use crate::error::{invalid_model, Result};
use crate::geometry::cloud::{box_sd, Cloud, PointDistance};
use crate::geometry::hull::Hull;
use crate::geometry::inner::{self, InnerBall};

/// MuJoCo's `mjtGeom` codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GeomType {
    Plane,
    Sphere,
    Capsule,
    Cylinder,
    Box,
    Mesh,
    /// A point cloud (`geometry/cloud.rs`), which MuJoCo knows as one sphere geom per point.
    Cloud,
}

impl GeomType {
    pub fn from_mujoco(code: i32, geom_id: i32) -> Result<Self> {
        Ok(match code {
            0 => GeomType::Plane,
            2 => GeomType::Sphere,
            3 => GeomType::Capsule,
            5 => GeomType::Cylinder,
            6 => GeomType::Box,
            7 => GeomType::Mesh,
            1 => return invalid_model(format!("geom {geom_id} is a height field; height fields are not supported")),
            4 => return invalid_model(format!("geom {geom_id} is an ellipsoid; ellipsoids are not supported by the exact labeller")),
            8 => return invalid_model(format!("geom {geom_id} is an SDF geom; SDF geoms are not supported")),
            c => return invalid_model(format!("geom {geom_id} has unknown type {c}")),
        })
    }
}

/// What a geom is to the narrow phase: MuJoCo's two cases, and point clouds.
pub enum Solid {
    /// A plane: the half-space `z <= 0` of its geom frame. Unbounded, so it has no support
    /// map; pairs with it are decided by the other geom's support point along the normal.
    HalfSpace,
    /// Every other geom: a convex body (meshes as their convex hulls).
    Convex {
        /// The shape as a concrete support map, for the hot path (GJK, plane support): an enum
        /// match instead of dyn dispatch, and hill climbing instead of a scan for hulls.
        convex: Convex,
        /// The same shape boxed for parry's generic queries (exact distance, contact).
        shape: Box<dyn Shape>,
    },
    /// A union of balls in a tree (`geometry/cloud.rs`), static, in its geom frame. Pairs with it are
    /// decided by the tree's queries against the other geom's exact shape.
    Cloud(Arc<Cloud>),
}

/// A collision shape in its geom frame, with the data the broad phase needs.
pub struct GeomShape {
    pub kind: GeomType,
    pub solid: Solid,
    /// Centre and half extents of a box bounding the shape in its own frame (OBB culling).
    /// Infinite half extents for half-spaces.
    pub obb_center: Vector3<f64>,
    pub obb_half: Vector3<f64>,
    /// Radius of a sphere about the shape-frame origin that holds the shape (sphere culling).
    pub rbound: f64,
    /// Radius of a sphere about `obb_center` that holds the shape: the farthest vertex of a
    /// hull, not the corner of its box, so the broad phase (`model/broad.rs`) culls more pairs.
    /// Infinite for half-spaces.
    pub radius: f64,
    /// Balls inside the shape, in its frame (`geometry/inner.rs`): none for half-spaces and clouds.
    pub inner: Vec<InnerBall>,
}

impl std::fmt::Debug for GeomShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GeomShape").field("kind", &self.kind).field("rbound", &self.rbound).finish()
    }
}

fn positive(geom_id: i32, what: &str, v: f64) -> Result<f64> {
    if v > 0.0 && v.is_finite() {
        Ok(v)
    } else {
        invalid_model(format!("geom {geom_id} has {what} {v}; it must be positive"))
    }
}

impl GeomShape {
    /// Builds the shape for a geom of MuJoCo `size` (and hull `points` for meshes).
    ///
    /// Returns the shape and the rotation to append to the geom frame so that parry's shape
    /// axis lines up with MuJoCo's.
    pub fn new(kind: GeomType, size: [f64; 3], points: &[Point3<f64>], geom_id: i32) -> Result<(Self, Isometry3<f64>)> {
        let mut axis_fix = Isometry3::identity();
        let convex = match kind {
            GeomType::Plane => return Ok((GeomShape::half_space(), axis_fix)),
            GeomType::Cloud => return invalid_model(format!("geom {geom_id}: a point cloud is built by `GeomShape::cloud`")),
            GeomType::Sphere => Convex::Ball(Ball::new(positive(geom_id, "radius", size[0])?)),
            GeomType::Capsule => {
                let r = positive(geom_id, "radius", size[0])?;
                let h = positive(geom_id, "half-length", size[1])?;
                Convex::Capsule(Capsule::new_z(h, r))
            }
            GeomType::Cylinder => {
                let r = positive(geom_id, "radius", size[0])?;
                let h = positive(geom_id, "half-length", size[1])?;
                // parry's cylinder runs along y; rotate +90 degrees about x to run along z.
                axis_fix = Isometry3::from_parts(
                    nalgebra::Translation3::identity(),
                    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
                );
                Convex::Cylinder(Cylinder::new(h, r))
            }
            GeomType::Box => {
                let h = Vector3::new(
                    positive(geom_id, "half-size x", size[0])?,
                    positive(geom_id, "half-size y", size[1])?,
                    positive(geom_id, "half-size z", size[2])?,
                );
                Convex::Cuboid(Cuboid::new(h))
            }
            GeomType::Mesh => {
                if points.len() < 4 {
                    return invalid_model(format!("mesh geom {geom_id} has {} hull vertices; at least 4 are needed", points.len()));
                }
                match Hull::new(points) {
                    Some(hull) => Convex::Hull(hull),
                    None => return invalid_model(format!("mesh geom {geom_id}: its vertices do not span a 3-D convex hull")),
                }
            }
        };
        let shape = convex.to_shape();
        // Bounds in the shape's own frame, the one `Geom::local` places in the body.
        let aabb = shape.compute_local_aabb();
        let sphere = shape.compute_local_bounding_sphere();
        let obb_center = aabb.center().coords;
        let radius = convex.radius_about(&obb_center);
        let inner = convex.inner_balls();
        let shape = GeomShape {
            kind,
            solid: Solid::Convex { convex, shape },
            obb_center,
            obb_half: aabb.half_extents(),
            rbound: sphere.center.coords.norm() + sphere.radius,
            radius,
            inner,
        };
        Ok((shape, axis_fix))
    }

    /// A plane geom: the half-space `z <= 0`, bounded by nothing.
    fn half_space() -> Self {
        GeomShape {
            kind: GeomType::Plane,
            solid: Solid::HalfSpace,
            obb_center: Vector3::zeros(),
            obb_half: Vector3::repeat(f64::INFINITY),
            rbound: f64::INFINITY,
            radius: f64::INFINITY,
            inner: Vec::new(),
        }
    }

    /// A point cloud's geom (the frame of its balls' coordinates). `None` for an empty cloud,
    /// which has nothing to collide with.
    pub fn cloud(cloud: Arc<Cloud>) -> Option<Self> {
        if cloud.is_empty() {
            return None;
        }
        let (obb_center, obb_half) = cloud.bounds();
        let radius = cloud.radius_about(&obb_center);
        Some(GeomShape {
            kind: GeomType::Cloud,
            rbound: (obb_center.norm() + radius) * (1.0 + 1e-12),
            solid: Solid::Cloud(cloud),
            obb_center,
            obb_half,
            radius,
            inner: Vec::new(),
        })
    }

    /// Whether the geom is a plane (a half-space).
    #[inline]
    pub fn is_half_space(&self) -> bool {
        matches!(self.solid, Solid::HalfSpace)
    }
}

/// A geom's convex shape as a concrete type (every geom but planes).
///
/// Its support points are exactly parry's for the same shape (the enum forwards every
/// `SupportMap` method; `Hull` returns the vertex parry's linear scan would), so GJK on it
/// gives bit-identical results to GJK on the boxed parry shape.
pub enum Convex {
    Ball(Ball),
    Cuboid(Cuboid),
    Capsule(Capsule),
    Cylinder(Cylinder),
    Hull(Hull),
}

impl Convex {
    /// An upper bound on the distance from `c` (shape frame) to any point of the shape,
    /// rounded up by a relative 1e-12 so that it bounds the rounded distances too.
    fn radius_about(&self, c: &Vector3<f64>) -> f64 {
        let r = match self {
            Convex::Ball(s) => c.norm() + s.radius,
            Convex::Capsule(s) => (s.segment.a.coords - c).norm().max((s.segment.b.coords - c).norm()) + s.radius,
            // parry's cylinder runs along y: its rim circles lie at y = +-h.
            Convex::Cylinder(s) => c.norm() + (s.half_height * s.half_height + s.radius * s.radius).sqrt(),
            Convex::Cuboid(s) => c.norm() + s.half_extents.norm(),
            Convex::Hull(h) => h.points().iter().map(|p| (p.coords - c).norm()).fold(0.0, f64::max),
        };
        r * (1.0 + 1e-12)
    }

    /// Balls inside the shape (`geometry/inner.rs`).
    fn inner_balls(&self) -> Vec<InnerBall> {
        match self {
            Convex::Ball(s) => inner::of_ball(s),
            Convex::Cuboid(s) => inner::of_cuboid(s),
            Convex::Capsule(s) => inner::of_capsule(s),
            Convex::Cylinder(s) => inner::of_cylinder(s),
            Convex::Hull(h) => inner::of_hull(h),
        }
    }

    /// Whether one of `balls` (in the frame `pose` maps into this shape's) reaches more than
    /// `inner::SLACK` into this shape, measured exactly; `None` for a hull, whose distance from a
    /// point takes GJK.
    #[inline]
    pub fn reached_by(&self, balls: &[InnerBall], pose: &Isometry3<f64>) -> Option<bool> {
        Some(match self {
            Convex::Ball(s) => inner::reach_into(balls, pose, |p| inner::outside_ball(s, p)),
            Convex::Cuboid(s) => inner::reach_into(balls, pose, |p| inner::outside_cuboid(s, p)),
            Convex::Capsule(s) => inner::reach_into(balls, pose, |p| inner::outside_capsule(s, p)),
            Convex::Cylinder(s) => inner::reach_into(balls, pose, |p| inner::outside_cylinder(s, p)),
            Convex::Hull(_) => return None,
        })
    }

    fn to_shape(&self) -> Box<dyn Shape> {
        match self {
            Convex::Ball(s) => Box::new(*s),
            Convex::Cuboid(s) => Box::new(*s),
            Convex::Capsule(s) => Box::new(*s),
            Convex::Cylinder(s) => Box::new(*s),
            Convex::Hull(h) => Box::new(h.poly().clone()),
        }
    }
}

/// A convex shape less its rounding: a ball's centre, a capsule's segment, any other shape
/// itself; the shape is its core dilated by its radius (a Minkowski sum with a ball).
///
/// Two such shapes are `dist(cores) - r_a - r_b` apart (`r`: the radii), and their closest points
/// lie on the line between the cores' closest points; GJK on the cores finds that line in a few
/// exact steps where one core is a point or a segment (a polytope), instead of creeping toward
/// its tolerance on the rounded surface (`collide::Scratch::pair_lower_bound`).
pub enum Core<'a> {
    Point,
    Segment(Segment),
    Whole(&'a Convex),
}

impl Convex {
    /// This shape's core (see [`Core`]).
    #[inline]
    pub fn core(&self) -> Core<'_> {
        match self {
            Convex::Ball(_) => Core::Point,
            Convex::Capsule(c) => Core::Segment(c.segment),
            _ => Core::Whole(self),
        }
    }

    /// The radius by which [`Convex::core`] is dilated into this shape (metres; 0 for a shape
    /// that is its own core).
    #[inline]
    pub fn rounding(&self) -> f64 {
        match self {
            Convex::Ball(b) => b.radius,
            Convex::Capsule(c) => c.radius,
            _ => 0.0,
        }
    }
}

impl SupportMap for Core<'_> {
    #[inline]
    fn local_support_point(&self, dir: &Vector3<f64>) -> Point3<f64> {
        match self {
            Core::Point => Point3::origin(),
            Core::Segment(s) => s.local_support_point(dir),
            Core::Whole(c) => c.local_support_point(dir),
        }
    }
}

impl SupportMap for Convex {
    #[inline]
    fn local_support_point(&self, dir: &Vector3<f64>) -> Point3<f64> {
        match self {
            Convex::Ball(s) => s.local_support_point(dir),
            Convex::Cuboid(s) => s.local_support_point(dir),
            Convex::Capsule(s) => s.local_support_point(dir),
            Convex::Cylinder(s) => s.local_support_point(dir),
            Convex::Hull(h) => h.support_point(dir),
        }
    }

    #[inline]
    fn local_support_point_toward(&self, dir: &Unit<Vector3<f64>>) -> Point3<f64> {
        match self {
            Convex::Ball(s) => s.local_support_point_toward(dir),
            Convex::Cuboid(s) => s.local_support_point_toward(dir),
            Convex::Capsule(s) => s.local_support_point_toward(dir),
            Convex::Cylinder(s) => s.local_support_point_toward(dir),
            Convex::Hull(h) => h.support_point(dir),
        }
    }

    #[inline]
    fn support_point(&self, m: &Isometry3<f64>, dir: &Vector3<f64>) -> Point3<f64> {
        match self {
            Convex::Ball(s) => s.support_point(m, dir),
            _ => m * self.local_support_point(&m.inverse_transform_vector(dir)),
        }
    }

    #[inline]
    fn support_point_toward(&self, m: &Isometry3<f64>, dir: &Unit<Vector3<f64>>) -> Point3<f64> {
        match self {
            Convex::Ball(s) => s.support_point_toward(m, dir),
            _ => m * self.local_support_point_toward(&Unit::new_unchecked(m.inverse_transform_vector(dir))),
        }
    }
}

impl PointDistance for Convex {
    /// Closed forms for the primitives; for a hull, the face planes (exact inside, a lower bound
    /// outside, which `exact: false` takes), then GJK (`geometry/cloud.rs`).
    fn point_sd(&self, p: &Vector3<f64>, bound: f64, exact: bool) -> std::result::Result<f64, f64> {
        Ok(match self {
            Convex::Ball(b) => p.norm() - b.radius,
            Convex::Cuboid(c) => box_sd(p, &c.half_extents),
            Convex::Capsule(c) => {
                let (a, b) = (c.segment.a.coords, c.segment.b.coords);
                let ab = b - a;
                let len2 = ab.norm_squared();
                let t = if len2 > 0.0 { ((p - a).dot(&ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
                (p - (a + ab * t)).norm() - c.radius
            }
            // parry's cylinder: axis y, half height `half_height`.
            Convex::Cylinder(c) => {
                let radial = (p.x * p.x + p.z * p.z).sqrt() - c.radius;
                let axial = p.y.abs() - c.half_height;
                let out = (radial.max(0.0).powi(2) + axial.max(0.0).powi(2)).sqrt();
                out + radial.max(axial).min(0.0)
            }
            Convex::Hull(h) => {
                let over = bound + 1e-9 * (1.0 + bound.abs());
                // A separating axis first: along the unit `n` from the hull's centre to the point,
                // `n·p − max_{x∈H} n·x` (the support point, by hill climbing) is at most the
                // distance whenever it is positive, for any `n`.
                let c = h.centre();
                if let Some(n) = (p - c).try_normalize(1e-12) {
                    let sep = n.dot(p) - n.dot(&h.support_point(&n).coords);
                    if sep > over {
                        return Err(sep);
                    }
                    if sep > 0.0 && !exact {
                        return Ok(sep);
                    }
                }
                // The largest face-plane distance: exact inside (the nearest boundary point of a
                // convex polytope lies on a face's plane), a lower bound outside; one plane above
                // `bound` already decides.
                let mut m = f64::NEG_INFINITY;
                for (n, d) in h.planes() {
                    let v = n.dot(p) - d;
                    if v > over {
                        return Err(v);
                    }
                    m = m.max(v);
                }
                if m <= 0.0 || !exact {
                    m
                } else {
                    let proj = local_point_projection_on_support_map(self, &mut VoronoiSimplex::new(), &Point3::from(*p), true);
                    // (GJK stops within its tolerance; the plane bound is exact arithmetic's.)
                    if proj.is_inside {
                        m
                    } else {
                        (p - proj.point.coords).norm().max(m)
                    }
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::geometry::hull::tests::random_dirs;

    #[test]
    fn planes_are_unbounded_half_spaces_and_nothing_else_is() {
        let (plane, fix) = GeomShape::new(GeomType::Plane, [1.0, 1.0, 0.1], &[], 0).unwrap();
        assert!(plane.is_half_space() && fix == Isometry3::identity());
        assert!(plane.radius.is_infinite() && plane.obb_half.iter().all(|h| h.is_infinite()));
        let (ball, _) = GeomShape::new(GeomType::Sphere, [0.1, 0.0, 0.0], &[], 1).unwrap();
        assert!(!ball.is_half_space());
    }

    #[test]
    fn convex_hull_support_points_are_parrys() {
        let cloud: Vec<Point3<f64>> =
            random_dirs(100, 11).iter().map(|d| Point3::from(d.component_mul(&Vector3::new(0.1, 0.2, 0.05)))).collect();
        let (shape, _) = GeomShape::new(GeomType::Mesh, [0.0; 3], &cloud, 0).unwrap();
        let Solid::Convex { convex, shape } = &shape.solid else { panic!("a mesh is convex") };
        let poly = shape.as_convex_polyhedron().expect("a mesh is parry's ConvexPolyhedron");
        for d in random_dirs(5000, 12) {
            assert_eq!(convex.local_support_point(&d), poly.local_support_point(&d));
        }
    }

    #[test]
    fn broad_phase_radius_holds_every_support_point_and_is_tight_for_hulls() {
        // Points on an ellipsoid: its hull reaches 0.2 from the centre, its box corners 0.27.
        let cloud: Vec<Point3<f64>> =
            random_dirs(200, 9).iter().map(|d| Point3::from(d.normalize().component_mul(&Vector3::new(0.2, 0.15, 0.1)))).collect();
        let shapes = [
            (GeomType::Sphere, [0.1, 0.0, 0.0]),
            (GeomType::Capsule, [0.05, 0.2, 0.0]),
            (GeomType::Cylinder, [0.05, 0.2, 0.0]),
            (GeomType::Box, [0.1, 0.2, 0.3]),
            (GeomType::Mesh, [0.0; 3]),
        ];
        for (kind, size) in shapes {
            let (shape, _) = GeomShape::new(kind, size, &cloud, 0).unwrap();
            let Solid::Convex { convex, .. } = &shape.solid else { panic!("{kind:?} is not a half-space") };
            let mut far = 0.0f64;
            for d in random_dirs(5000, 10) {
                far = far.max((convex.local_support_point(&d).coords - shape.obb_center).norm());
            }
            assert!(far <= shape.radius, "{kind:?}: {far} > {}", shape.radius);
            assert!(shape.radius <= shape.obb_half.norm() * (1.0 + 1e-9), "{kind:?}");
            if kind == GeomType::Mesh {
                // The farthest vertex, well inside the box's corner.
                assert!(shape.radius < 0.9 * shape.obb_half.norm(), "{} vs {}", shape.radius, shape.obb_half.norm());
            }
        }
    }
}
