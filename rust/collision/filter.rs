//! The robot's own points: which points of a sensor's cloud lie within a margin of the model's
//! geoms at a known pose (a robot self-filter, MoveIt's `robot_self_filter` done exactly).
//!
//! The points go into a tree (`geometry/cloud.rs`, radius 0); each geom is placed at the pose and marks
//! the points whose signed distance to it is at most the margin (`Cloud::mark_within`: exact,
//! the tree skipping only what is farther). Planes mark the points at most the margin above
//! them.

use nalgebra::Vector3;

use crate::collision::collide::Scratch;
use crate::error::{invalid_input, Result};
use crate::geometry::cloud::{Cloud, Probe};
use crate::geometry::shapes::Solid;
use crate::model::RobotModel;

/// What a point of a sensor's cloud is to the model at a pose.
pub const KEEP: u8 = 0;
/// Within the margin of a robot geom.
pub const ROBOT: u8 = 1;
/// Within the static margin of another geom (floor, table, modelled obstacles), not of the robot.
pub const STATIC: u8 = 2;

/// Per point of `points` (world frame, metres): [`ROBOT`] when it lies within `margin` metres of
/// a robot geom of `model` at pose `q` (inside included); else, with `static_margin`, [`STATIC`]
/// when it lies that close to another geom (the model's point cloud excepted); else [`KEEP`].
///
/// Planes go first, by a scan (a floor holds most of a camera's pixels); the points they leave
/// go into a tree that every convex geom then queries.
pub fn points_near_model(model: &RobotModel, q: &[f64], points: &[[f64; 3]], margin: f64, static_margin: Option<f64>) -> Result<Vec<u8>> {
    if model.check_poses(q)? != 1 {
        return invalid_input(format!("pose must be one pose of {} joints", model.njoint()));
    }
    for (name, m) in [("margin", Some(margin)), ("static margin", static_margin)] {
        if let Some(m) = m {
            if !(m.is_finite() && m >= 0.0) {
                return invalid_input(format!("{name} must be a finite number of metres >= 0; got {m}"));
            }
        }
    }
    if let Some(i) = points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
        return invalid_input(format!("point {i} is not finite ({:?})", points[i]));
    }
    let mut s = Scratch::new(model);
    s.place(model, q, true);
    let margin_of = |g: &crate::model::geom::Geom| if g.on_robot { Some(margin) } else { static_margin };
    let mut kind = vec![KEEP; points.len()];
    for (g, geom) in model.geoms().iter().enumerate() {
        let (Solid::HalfSpace, Some(m)) = (&geom.shape.solid, margin_of(geom)) else { continue };
        let x = s.geom_frame(g);
        let n = x.rotation * Vector3::z();
        let offset = n.dot(&x.translation.vector);
        let code = if geom.on_robot { ROBOT } else { STATIC };
        for (i, p) in points.iter().enumerate() {
            if n.dot(&Vector3::from(*p)) - offset <= m && (kind[i] == KEEP || code == ROBOT) {
                kind[i] = code;
            }
        }
    }
    let rest: Vec<usize> = (0..points.len()).filter(|&i| kind[i] == KEEP).collect();
    let centres: Vec<[f64; 3]> = rest.iter().map(|&i| points[i]).collect();
    let cloud = Cloud::new(&centres, &vec![0.0; centres.len()])?;
    // Robot geoms first, so that a point near both is the robot's.
    let mut near = vec![false; centres.len()];
    for robot in [true, false] {
        near.fill(false);
        for (g, geom) in model.geoms().iter().enumerate() {
            let (Solid::Convex { convex, .. }, Some(m)) = (&geom.shape.solid, margin_of(geom)) else { continue };
            if geom.on_robot != robot {
                continue;
            }
            let shape = &geom.shape;
            cloud.mark_within(&Probe::new(convex, *s.geom_frame(g), shape.obb_center, shape.obb_half, shape.radius), m, &mut near);
        }
        for (j, &i) in rest.iter().enumerate() {
            if near[j] && kind[i] == KEEP {
                kind[i] = if robot { ROBOT } else { STATIC };
            }
        }
    }
    Ok(kind)
}
