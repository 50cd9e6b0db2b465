//! Forward kinematics over the flat body tree, as MuJoCo's `mj_kinematics` computes it.
//!
//! For body `b` with parent `p`: `X_b = X_p * (pos_b, quat_b)`, then each joint of `b` in order:
//! - hinge: rotate about the joint anchor, `R <- R * exp(axis * (q - qpos0))`,
//!   `x <- anchor_world - R * anchor_local`;
//! - slide: translate along the world axis, `x <- x + R * axis * (q - qpos0)`.

use nalgebra::{Isometry3, Point3, UnitQuaternion};

use crate::model::RobotModel;

/// Computes every body's world pose for one pose vector `q` (length K) into `out` (nbody).
///
/// # Example
/// ```
/// use profrobot::{ModelDesc, RobotModel, kinematics::body_poses};
/// let model = RobotModel::new(ModelDesc::example_pendulum()).unwrap();
/// let mut poses = vec![nalgebra::Isometry3::identity(); model.nbody()];
/// body_poses(&model, &[std::f64::consts::FRAC_PI_2], &mut poses);
/// // The arm now points along +y... its origin stays on the hinge axis.
/// assert!((poses[1].translation.vector.z - 0.55).abs() < 1e-12);
/// ```
pub fn body_poses(model: &RobotModel, q: &[f64], out: &mut [Isometry3<f64>]) {
    debug_assert_eq!(q.len(), model.njoint());
    out[0] = Isometry3::identity();
    for b in 1..model.body_parent.len() {
        let mut x = out[model.body_parent[b]] * model.body_local[b];
        let (j0, j1) = model.body_joints[b];
        for j in j0..j1 {
            let jnt = &model.joints[j];
            let angle = q[j] - jnt.qpos0;
            if jnt.hinge {
                let anchor_world: Point3<f64> = x * Point3::from(jnt.anchor);
                let mut rot = x.rotation * UnitQuaternion::from_axis_angle(&jnt.axis, angle);
                rot.renormalize_fast();
                x.rotation = rot;
                x.translation.vector = anchor_world.coords - rot * jnt.anchor;
            } else {
                x.translation.vector += x.rotation * (jnt.axis.into_inner() * angle);
            }
        }
        out[b] = x;
    }
}

/// World poses of the collidable geoms (shape frames), given the body poses.
pub fn geom_poses(model: &RobotModel, bodies: &[Isometry3<f64>], out: &mut [Isometry3<f64>]) {
    for (o, g) in out.iter_mut().zip(&model.geoms) {
        *o = bodies[g.body] * g.local;
    }
}
