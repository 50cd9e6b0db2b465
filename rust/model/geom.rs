//! One collidable geom as the labeller sees it: its shape and where it sits on its body.

use std::sync::Arc;

use nalgebra::Isometry3;

use crate::geometry::shapes::GeomShape;

/// One collidable geom, its shape and its fixed pose in its body frame.
#[derive(Debug)]
pub struct Geom {
    pub mujoco_id: i32,
    pub body: usize,
    /// Geom frame in the body frame, with the shape's own axis convention folded in.
    pub local: Isometry3<f64>,
    /// Shared with the models derived from this one (`RobotModel::rebuilt`).
    pub shape: Arc<GeomShape>,
    /// Belongs to a body whose kinematic root carries joints (the robot), not the static scene.
    pub on_robot: bool,
}
