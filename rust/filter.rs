//! The robot's own points: which points of a sensor's cloud lie within a margin of the model's
//! geoms at a known pose (a robot self-filter, MoveIt's `robot_self_filter` done exactly).
//!
//! The points go into a tree (`cloud.rs`, radius 0); each geom is placed at the pose and marks
//! the points whose signed distance to it is at most the margin (`Cloud::mark_within`: exact,
//! the tree skipping only what is farther). Planes mark the points less than the margin above
//! them.

use nalgebra::Vector3;

use crate::cloud::{Cloud, Probe};
use crate::collide::Scratch;
use crate::error::{invalid_input, Result};
use crate::model::RobotModel;
use crate::shapes::Solid;

/// Per point of `points` (world frame, metres): whether it lies within `margin` metres of a geom
/// of `model` at pose `q` (inside included): the robot's geoms only with `robot_only`, else the
/// static scene's too (floor, table). The point cloud of the model itself is never a filter.
pub fn points_near_model(model: &RobotModel, q: &[f64], points: &[[f64; 3]], margin: f64, robot_only: bool) -> Result<Vec<bool>> {
    if model.check_poses(q)? != 1 {
        return invalid_input(format!("pose must be one pose of {} joints", model.njoint()));
    }
    if !(margin.is_finite() && margin >= 0.0) {
        return invalid_input(format!("margin must be a finite number of metres >= 0; got {margin}"));
    }
    let cloud = Cloud::new(points, &vec![0.0; points.len()])?;
    let mut near = vec![false; points.len()];
    let mut s = Scratch::new(model);
    s.place(model, q, true);
    for (g, geom) in model.geoms().iter().enumerate() {
        if robot_only && !geom.on_robot {
            continue;
        }
        let x = s.geom_frame(g);
        let shape = &geom.shape;
        match &shape.solid {
            Solid::Convex { convex, .. } => {
                cloud.mark_within(&Probe::new(convex, *x, shape.obb_center, shape.obb_half, shape.radius), margin, &mut near);
            }
            Solid::HalfSpace => {
                let n = x.rotation * Vector3::z();
                let offset = n.dot(&x.translation.vector);
                for (i, p) in points.iter().enumerate() {
                    near[i] |= n.dot(&Vector3::from(*p)) - offset <= margin;
                }
            }
            Solid::Cloud(_) => {}
        }
    }
    Ok(near)
}
