//! parry shapes from MuJoCo geom descriptions.
//!
//! MuJoCo collides primitives exactly and meshes as their convex hulls; planes are half-spaces
//! (`z <= 0` in the plane's frame). Each geom becomes one of these, plus a fixed rotation where
//! parry's axis convention differs from MuJoCo's (cylinders: parry's axis is y, MuJoCo's z).

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use parry3d_f64::shape::{Ball, Capsule, ConvexPolyhedron, Cuboid, Cylinder, Shape};

use crate::error::{invalid_model, Result};

/// MuJoCo's `mjtGeom` codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GeomType {
    Plane,
    Sphere,
    Capsule,
    Cylinder,
    Box,
    Mesh,
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

/// A collision shape in its geom frame, with the data the broad phase needs.
pub struct GeomShape {
    pub kind: GeomType,
    /// `None` for planes, which are handled as half-spaces by `collide`.
    pub shape: Option<Box<dyn Shape>>,
    /// Centre and half extents of a box bounding the shape in its own frame (OBB culling).
    pub obb_center: Vector3<f64>,
    pub obb_half: Vector3<f64>,
    /// Radius of a sphere about the shape-frame origin that holds the shape (sphere culling).
    pub rbound: f64,
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
        let shape: Option<Box<dyn Shape>> = match kind {
            GeomType::Plane => None,
            GeomType::Sphere => Some(Box::new(Ball::new(positive(geom_id, "radius", size[0])?))),
            GeomType::Capsule => {
                let r = positive(geom_id, "radius", size[0])?;
                let h = positive(geom_id, "half-length", size[1])?;
                Some(Box::new(Capsule::new_z(h, r)))
            }
            GeomType::Cylinder => {
                let r = positive(geom_id, "radius", size[0])?;
                let h = positive(geom_id, "half-length", size[1])?;
                // parry's cylinder runs along y; rotate +90 degrees about x to run along z.
                axis_fix = Isometry3::from_parts(
                    nalgebra::Translation3::identity(),
                    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
                );
                Some(Box::new(Cylinder::new(h, r)))
            }
            GeomType::Box => {
                let h = Vector3::new(
                    positive(geom_id, "half-size x", size[0])?,
                    positive(geom_id, "half-size y", size[1])?,
                    positive(geom_id, "half-size z", size[2])?,
                );
                Some(Box::new(Cuboid::new(h)))
            }
            GeomType::Mesh => {
                if points.len() < 4 {
                    return invalid_model(format!("mesh geom {geom_id} has {} hull vertices; at least 4 are needed", points.len()));
                }
                match ConvexPolyhedron::from_convex_hull(points) {
                    Some(hull) => Some(Box::new(hull)),
                    None => return invalid_model(format!("mesh geom {geom_id}: its vertices do not span a 3-D convex hull")),
                }
            }
        };
        let (obb_center, obb_half, rbound) = match &shape {
            None => (Vector3::zeros(), Vector3::repeat(f64::INFINITY), f64::INFINITY),
            Some(s) => {
                // Bounds in the shape's own frame, the one `Geom::local` places in the body.
                let aabb = s.compute_local_aabb();
                let sphere = s.compute_local_bounding_sphere();
                (aabb.center().coords, aabb.half_extents(), sphere.center.coords.norm() + sphere.radius)
            }
        };
        Ok((GeomShape { kind, shape, obb_center, obb_half, rbound }, axis_fix))
    }
}
