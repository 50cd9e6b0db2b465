//! Forward kinematics over the flat body tree, as MuJoCo's `mj_kinematics` computes it.
//!
//! For body `b` with parent `p`: `X_b = X_p * (pos_b, quat_b)`, then each joint of `b` in order:
//! - hinge: rotate about the joint anchor, `R <- R * exp(axis * (q - qpos0))`,
//!   `x <- anchor_world - R * anchor_local`;
//! - slide: translate along the world axis, `x <- x + R * axis * (q - qpos0)`.

use nalgebra::{Isometry3, Point3, Quaternion, UnitQuaternion, Vector3};

use crate::model::lanes::{Frames4, Iso4, F4, Q4, V4};
use rayon::prelude::*;

use crate::error::Result;
use crate::model::trig;
use crate::model::RobotModel;

/// Computes every body's world pose for one pose vector `q` (length K) into `out` (nbody).
///
/// # Example
/// ```
/// use profrobot::{ModelDesc, RobotModel, model::kinematics::body_poses};
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
        out[b] = body_pose(model, q, out, b);
    }
}

/// `body_poses` for the bodies `b` with `marks[b] == mark` only, which must include every
/// marked body's parent (the world aside): their frames are `body_poses`' bit for bit; the
/// others keep what `out` held.
pub(crate) fn marked_body_poses(model: &RobotModel, q: &[f64], out: &mut [Isometry3<f64>], marks: &[u32], mark: u32) {
    debug_assert_eq!(q.len(), model.njoint());
    out[0] = Isometry3::identity();
    for b in 1..model.body_parent.len() {
        if marks[b] == mark {
            debug_assert!(model.body_parent[b] == 0 || marks[model.body_parent[b]] == mark);
            out[b] = body_pose(model, q, out, b);
        }
    }
}

/// Body `b`'s world frame from its parent's (already in `out`) and its joints' values in `q`.
#[inline(always)]
fn body_pose(model: &RobotModel, q: &[f64], out: &[Isometry3<f64>], b: usize) -> Isometry3<f64> {
    let mut x = out[model.body_parent[b]] * model.body_local[b];
    let (j0, j1) = model.body_joints[b];
    for (jnt, &qj) in model.joints[j0..j1].iter().zip(&q[j0..j1]) {
        let angle = qj - jnt.qpos0;
        if jnt.hinge {
            let mut rot = x.rotation * axis_rotation(jnt.axis.into_inner(), angle);
            rot.renormalize_fast();
            // A hinge at the body origin (every bundled robot's) leaves the translation
            // as it is, bit for bit: the rotated zero anchor is +-0 in every component, and
            // t + (+-0) - (+-0) == t for t != 0. (A zero component could change sign, so
            // it takes the general formula.)
            if jnt.anchor != Vector3::zeros() || x.translation.vector.iter().any(|&t| t == 0.0) {
                let anchor_world: Point3<f64> = x * Point3::from(jnt.anchor);
                x.translation.vector = anchor_world.coords - rot * jnt.anchor;
            }
            x.rotation = rot;
        } else {
            x.translation.vector += x.rotation * (jnt.axis.into_inner() * angle);
        }
    }
    x
}

/// The rotation by `angle` radians about the unit `axis`: nalgebra's `from_axis_angle`,
/// `(cos(angle/2), axis sin(angle/2))`, with this crate's `sin_cos` (`model/trig.rs`: the same bits
/// on every platform and in every lane).
#[inline(always)]
pub(crate) fn axis_rotation(axis: Vector3<f64>, angle: f64) -> UnitQuaternion<f64> {
    let (s, c) = trig::sin_cos(angle / 2.0);
    UnitQuaternion::new_unchecked(Quaternion::from_parts(c, axis * s))
}

/// `body_poses` of four poses `q` (each of length K) into `out` (each of length nbody), bit for
/// bit, the frames also left in `room`, four lanes a body (`model/lanes.rs`). Inlined into its caller,
/// which compiles it for the vector width it has (`collide::Scratch4`).
#[inline(always)]
pub(crate) fn body_poses4(model: &RobotModel, q: [&[f64]; 4], out: [&mut [Isometry3<f64>]; 4], room: &mut Frames4) {
    let nbody = model.body_parent.len();
    let bodies = &mut room.bodies;
    bodies.clear();
    bodies.push(Iso4::splat(&Isometry3::identity()));
    for b in 1..nbody {
        let mut x = bodies[model.body_parent[b]].mul(&Iso4::splat(&model.body_local[b]));
        let (j0, j1) = model.body_joints[b];
        for (j, jnt) in model.joints[j0..j1].iter().enumerate() {
            let j = j0 + j;
            let angle = F4([q[0][j], q[1][j], q[2][j], q[3][j]]) - F4::splat(jnt.qpos0);
            if jnt.hinge {
                // `axis_rotation`: `(sin, cos)` of half the angle (`model/trig.rs`, four lanes), the axis times
                // the sine.
                let (s, c) = trig::sin_cos4((angle * F4::splat(0.5)).0);
                let axis = jnt.axis.into_inner();
                let (s, c) = (F4(s), F4(c));
                let turn = Q4 { i: F4::splat(axis.x) * s, j: F4::splat(axis.y) * s, k: F4::splat(axis.z) * s, w: c };
                let rot = x.r.mul(&turn).renormalize_fast();
                // (as `kinematics::body_pose`: the general formula where the anchor is off the
                // body origin or a translation component is zero, lane by lane)
                let general = jnt.anchor != Vector3::zeros();
                // (`|`, not `||`: four lanes compared at once)
                let zero: [bool; 4] = std::array::from_fn(|l| (x.t.x.0[l] == 0.0) | (x.t.y.0[l] == 0.0) | (x.t.z.0[l] == 0.0));
                if general | zero[0] | zero[1] | zero[2] | zero[3] {
                    let anchor = V4::splat(&jnt.anchor);
                    let t = x.r.rotate(&anchor).add(&x.t).sub(&rot.rotate(&anchor));
                    for (l, &zero) in zero.iter().enumerate() {
                        if general || zero {
                            x.t.x.0[l] = t.x.0[l];
                            x.t.y.0[l] = t.y.0[l];
                            x.t.z.0[l] = t.z.0[l];
                        }
                    }
                }
                x.r = rot;
            } else {
                x.t = x.t.add(&x.r.rotate(&V4::splat(&jnt.axis.into_inner()).scale(angle)));
            }
        }
        bodies.push(x);
    }
    for (l, out) in out.into_iter().enumerate() {
        for (o, x) in out.iter_mut().zip(bodies.iter()) {
            *o = x.lane(l);
        }
    }
}

/// `body_poses4`, compiled for AVX2 where the CPU has it (as the broad phase found when the
/// model was built, `Broad::avx2`): the same bits either way.
pub(crate) fn body_poses4_wide(model: &RobotModel, q: [&[f64]; 4], out: [&mut [Isometry3<f64>]; 4], room: &mut Frames4) {
    #[cfg(target_arch = "x86_64")]
    if model.broad.avx2() {
        // SAFETY: the CPU has AVX2 (`Broad::avx2`).
        return unsafe { body_poses4_avx2(model, q, out, room) };
    }
    body_poses4(model, q, out, room)
}

/// `body_poses4` in AVX2 registers.
///
/// # Safety
/// The CPU has AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn body_poses4_avx2(model: &RobotModel, q: [&[f64]; 4], out: [&mut [Isometry3<f64>]; 4], room: &mut Frames4) {
    body_poses4(model, q, out, room)
}

/// Poses per parallel work item (`threads::POSE_CHUNK`).
const CHUNK: usize = crate::threads::POSE_CHUNK;

/// Forward kinematics of a `(B, K)` row-major batch of poses, in parallel on rayon's current
/// pool: `xpos` `(B, nbody, 3)` metres and `xquat` `(B, nbody, 4)` `(w, x, y, z)`, row-major,
/// as MuJoCo's `xpos`/`xquat`. Every pose is computed alone, so the result does not depend on
/// the number of threads.
///
/// # Example
/// ```
/// use profrobot::{ModelDesc, RobotModel, model::kinematics::forward_kinematics};
/// let model = RobotModel::new(ModelDesc::example_pendulum()).unwrap();
/// let (xpos, xquat) = forward_kinematics(&model, &[0.0, std::f64::consts::FRAC_PI_2]).unwrap();
/// assert_eq!((xpos.len(), xquat.len()), (2 * 2 * 3, 2 * 2 * 4));
/// assert_eq!(&xpos[3..6], &[0.0, 0.0, 0.55]); // pose 0, body 1: the hinge
/// assert!(forward_kinematics(&model, &[f64::NAN]).is_err());
/// ```
pub fn forward_kinematics(model: &RobotModel, poses: &[f64]) -> Result<(Vec<f64>, Vec<f64>)> {
    let b = model.check_poses(poses)?;
    let nb = model.nbody();
    crate::budget::check("poses (forward kinematics' frames)", &[b, nb, 7], 8)?;
    Ok(frames_of_poses(model, poses, b, nb, |q, frames, pos, quat| {
        body_poses(model, q, frames);
        for ((f, p), r) in frames.iter().zip(pos.chunks_exact_mut(3)).zip(quat.chunks_exact_mut(4)) {
            write_frame(f, p, r);
        }
    }))
}

/// Body `body`'s world frame at each of the poses (`B × K`, row-major): positions `B × 3` and
/// quaternions `B × 4` `(w, x, y, z)`, `forward_kinematics`' for that body bit for bit. Only
/// the body's ancestors are placed (`marked_body_poses`), so a hand's frame costs its chain,
/// not the whole tree (the fingers, a second arm).
pub fn body_frames(model: &RobotModel, poses: &[f64], body: usize) -> Result<(Vec<f64>, Vec<f64>)> {
    let b = model.check_poses(poses)?;
    let nb = model.nbody();
    if body >= nb {
        return crate::error::invalid_input(format!("body {body} is out of range: the model has {nb} bodies"));
    }
    crate::budget::check("poses (a body's frames)", &[b, 7], 8)?;
    let mut marks = vec![0u32; nb];
    let mut up = body;
    while up != 0 {
        marks[up] = 1;
        up = model.body_parent[up];
    }
    Ok(frames_of_poses(model, poses, b, 1, |q, frames, pos, quat| {
        marked_body_poses(model, q, frames, &marks, 1);
        write_frame(&frames[body], pos, quat);
    }))
}

/// `n` frames for each of the `b` poses (`B × K`, row-major): `place(q, scratch, pos, quat)`
/// writes pose `q`'s into its `n × 3` positions and `n × 4` quaternions (`scratch`: nbody
/// frames to place them in). In parallel on rayon's current pool, in work items of
/// [`CHUNK`] poses; one item runs on the calling thread, without rayon (as
/// `threads::map_chunks`). Every pose is computed alone: the result depends on neither.
fn frames_of_poses<F>(model: &RobotModel, poses: &[f64], b: usize, n: usize, place: F) -> (Vec<f64>, Vec<f64>)
where
    F: Fn(&[f64], &mut Vec<Isometry3<f64>>, &mut [f64], &mut [f64]) + Sync,
{
    let (k, nb) = (model.njoint(), model.nbody());
    let mut xpos = vec![0.0; b * n * 3];
    let mut xquat = vec![0.0; b * n * 4];
    let work = |frames: &mut Vec<Isometry3<f64>>, ((q, pos), quat): ((&[f64], &mut [f64]), &mut [f64])| {
        for ((qi, p), r) in q.chunks_exact(k).zip(pos.chunks_exact_mut(n * 3)).zip(quat.chunks_exact_mut(n * 4)) {
            place(qi, frames, p, r);
        }
    };
    if b <= CHUNK {
        work(&mut vec![Isometry3::identity(); nb], ((poses, &mut xpos), &mut xquat));
    } else {
        poses
            .par_chunks(CHUNK * k)
            .zip(xpos.par_chunks_mut(CHUNK * n * 3))
            .zip(xquat.par_chunks_mut(CHUNK * n * 4))
            .for_each_init(|| vec![Isometry3::identity(); nb], work);
    }
    (xpos, xquat)
}

/// Frame `f` as a position `p` (3) and a quaternion `r` (4, `(w, x, y, z)`).
fn write_frame(f: &Isometry3<f64>, p: &mut [f64], r: &mut [f64]) {
    p.copy_from_slice(f.translation.vector.as_slice());
    let q = f.rotation.quaternion();
    r.copy_from_slice(&[q.w, q.i, q.j, q.k]);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One body's frames are `forward_kinematics`' for that body, bit for bit, on every bundled
    /// robot and every body.
    #[test]
    fn body_frames_are_forward_kinematics_of_that_body() {
        for scene in ["panda_blocks", "xarm7_table", "vx300s_clutter", "shadow_hand"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let desc: crate::model::ModelDesc = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            let model = RobotModel::new(desc).unwrap();
            let ranges = model.sampling_ranges().unwrap();
            let poses = crate::joints::sample::sample_uniform(&ranges, 300, 4).unwrap();
            let (xpos, xquat) = forward_kinematics(&model, &poses).unwrap();
            let nb = model.nbody();
            for body in 0..nb {
                let (p, q) = body_frames(&model, &poses, body).unwrap();
                for i in 0..300 {
                    assert_eq!(p[i * 3..i * 3 + 3], xpos[(i * nb + body) * 3..(i * nb + body) * 3 + 3], "{scene} body {body}");
                    assert_eq!(q[i * 4..i * 4 + 4], xquat[(i * nb + body) * 4..(i * nb + body) * 4 + 4], "{scene} body {body}");
                }
            }
            assert!(body_frames(&model, &poses, nb).is_err());
        }
    }

    /// Four lanes give `body_poses` bit for bit (every coordinate's bits, signs of zero
    /// included) on every bundled robot, at random poses within and beyond the limits and at
    /// each joint's `qpos0` (angles of exactly zero); compiled for the CPU's vector width too
    /// (`body_poses4_wide`, as the certificate places four states).
    #[test]
    fn four_lanes_are_body_poses_bit_for_bit() {
        for scene in ["panda_blocks", "xarm7_table", "ur5e_wall_box", "panda_shelf", "shadow_hand", "vx300s_clutter"] {
            let path = format!("{}/benches/data/{scene}.json", env!("CARGO_MANIFEST_DIR"));
            let desc: crate::model::desc::ModelDesc = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
            let model = RobotModel::new(desc).unwrap();
            let k = model.njoint();
            let ranges = model.sampling_ranges().unwrap();
            let wide: Vec<[f64; 2]> = ranges.iter().map(|r| [r[0] - 2.0, r[1] + 2.0]).collect();
            let mut poses = crate::joints::sample::sample_uniform(&ranges, 400, 3).unwrap();
            poses.extend(crate::joints::sample::sample_uniform(&wide, 400, 4).unwrap());
            poses.extend(model.joints.iter().map(|j| j.qpos0).cycle().take(4 * k));
            let nb = model.nbody();
            let bits = |x: &Isometry3<f64>| {
                let (t, r) = (x.translation.vector, x.rotation.coords);
                [t.x, t.y, t.z, r.x, r.y, r.z, r.w].map(f64::to_bits)
            };
            let mut room = Frames4::default();
            for quad in poses.chunks_exact(4 * k) {
                let q: Vec<&[f64]> = quad.chunks_exact(k).collect();
                let mut out = vec![vec![Isometry3::identity(); nb]; 4];
                let [o0, o1, o2, o3] = &mut out[..] else { unreachable!() };
                body_poses4(&model, [q[0], q[1], q[2], q[3]], [o0, o1, o2, o3], &mut room);
                let mut wide = vec![vec![Isometry3::identity(); nb]; 4];
                let [w0, w1, w2, w3] = &mut wide[..] else { unreachable!() };
                body_poses4_wide(&model, [q[0], q[1], q[2], q[3]], [w0, w1, w2, w3], &mut room);
                for l in 0..4 {
                    let mut want = vec![Isometry3::identity(); nb];
                    body_poses(&model, q[l], &mut want);
                    for b in 0..nb {
                        assert_eq!(bits(&out[l][b]), bits(&want[b]), "{scene}: lane {l}, body {b}");
                        assert_eq!(bits(&wide[l][b]), bits(&want[b]), "{scene}: wide lane {l}, body {b}");
                    }
                }
            }
        }
    }
    use crate::model::desc::ModelDesc;

    #[test]
    fn batched_fk_is_body_poses_pose_by_pose_on_any_thread_count() {
        let mut desc = ModelDesc::example_pendulum();
        desc.jnt_axis = vec![[0.3, -0.2, 0.9]];
        desc.jnt_pos = vec![[0.01, 0.02, -0.1]];
        let model = RobotModel::new(desc).unwrap();
        let poses: Vec<f64> = (0..1000).map(|i| -3.0 + 6.0 * i as f64 / 1000.0).collect();
        let run = |n: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(|| forward_kinematics(&model, &poses).unwrap())
        };
        let (xpos, xquat) = run(1);
        assert_eq!((xpos.clone(), xquat.clone()), run(2));
        let mut frames = vec![Isometry3::identity(); model.nbody()];
        for (i, q) in poses.iter().enumerate() {
            body_poses(&model, &[*q], &mut frames);
            for (b, f) in frames.iter().enumerate() {
                let o = (i * model.nbody() + b) * 3;
                assert_eq!(&xpos[o..o + 3], f.translation.vector.as_slice());
                let r = f.rotation.quaternion();
                let o = (i * model.nbody() + b) * 4;
                assert_eq!(&xquat[o..o + 4], &[r.w, r.i, r.j, r.k]);
            }
        }
    }
}
