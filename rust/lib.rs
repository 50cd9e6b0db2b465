//! # profrobot core
//!
//! Exact, parallel collision labelling of robot joint configurations.
//!
//! A robot arrives as a [`ModelDesc`]: flat, index-based arrays copied from MuJoCo's compiled
//! model (bodies, joints, collision geoms, convex-hull vertices, excludes, explicit pairs).
//! [`RobotModel::new`] validates it once and derives the candidate geom pairs with MuJoCo's
//! filters. From then on a pose `q` (radians for hinges, metres for slides, MuJoCo joint order)
//! becomes a label in one pass:
//!
//! ```text
//! q ──kinematics::body_poses──▶ body frames ──▶ geom frames ──collide::label_pose──▶ Label
//! ```
//!
//! Modules, each importing only those above it (no cycle):
//!
//! | module | concern |
//! |---|---|
//! | [`error`] | the one error type |
//! | [`budget`] | sizes checked against the memory available before they are allocated |
//! | [`angles`] | the one angle wrap (SO(2), shortest arcs) |
//! | `trig` | sin and cos of hinge half angles: libm's (msun), one pose or four lanes, bit for bit |
//! | [`validate`] | caller input checked in one pass (finite poses within limits) |
//! | `lanes` | four poses at once: nalgebra's quaternion and matrix arithmetic lane for lane, bit for bit |
//! | [`couplings`] | joint equalities: dependent joints, feasible poses, coupled motions |
//! | [`desc`] | `ModelDesc`: the robot as plain serde data |
//! | [`hull`] | convex hulls: support points by hill climbing, the cube map, face planes |
//! | [`cloud`] | point clouds: balls in a tree, exact queries against one convex shape, voxel downsampling |
//! | `inner` | balls inside each convex shape: overlaps proven without GJK |
//! | [`shapes`] | `GeomType`, `GeomShape`, `Solid` (half-space, convex or cloud), `Convex` |
//! | `sat` | remembered separating axes, tried before GJK |
//! | [`geom`] | `Geom`: a shape on a body |
//! | [`pairs`] | candidate pairs with MuJoCo's filters |
//! | `broad` | the per-pose broad phase (bounding spheres) |
//! | [`model`] | `RobotModel`: the validated, derived robot |
//! | [`kinematics`] | forward kinematics, one pose or a batch |
//! | [`collide`] | labelling: narrow phase and batches |
//! | [`filter`] | a sensor's points within a margin of the model at a pose (the self-filter) |
//! | [`fastpath`] | the booleans-only fast path: first pair in contact, likeliest first |
//! | [`motion`] | straight joint-space motions certified continuously (conservative advancement) |
//! | [`ik`] | inverse kinematics: Levenberg–Marquardt on the SE(3) error, seeds, certified answers |
//! | [`oracle`] | the nearest free pose found by rays and bisection (the Δθ yardstick) |
//! | [`sample`], [`interpolate`] | poses |
//! | [`plan`] | global paths: RRT-Connect on the exact labeller, shortcutting |
//! | [`real`] | `f32`/`f64`: the float types the renderer computes in |
//! | [`splat`] | Gaussian-splat tile rasterizer: forward compositing and its exact backward |
//! | [`render`] | the renderer after FK: EWA projection, SH colour, rasterization, fused backward |
//! | [`images`] | rendered images finished (background, expected depth) and compared (the image loss), with gradients |
//! | [`threads`] | one rayon pool per thread count, fork-safe |
//!
//! Nothing here knows Python; `python.rs` (feature `python`) is the only binding layer.

pub mod angles;
mod broad;
pub mod budget;
mod capsules;
pub mod cloud;
pub mod collide;
pub mod couplings;
pub mod desc;
pub mod error;
pub mod fastpath;
pub mod filter;
pub mod geom;
pub mod hull;
pub mod ik;
pub mod images;
mod inner;
pub mod interpolate;
pub mod kinematics;
mod lanes;
pub mod model;
pub mod motion;
pub mod oracle;
pub mod pairs;
pub mod plan;
pub mod real;
pub mod render;
pub mod sample;
mod sat;
pub mod shapes;
mod spans;
mod sphere_pairs;
pub mod splat;
pub mod threads;
mod trig;
pub mod validate;

#[cfg(feature = "python")]
mod python;

pub use collide::{label_batch, Label, LabelBatch, LabelOptions};
pub use desc::ModelDesc;
pub use error::{Error, Result};
pub use fastpath::collides_batch;
pub use geom::Geom;
pub use interpolate::interpolate_so2;
pub use kinematics::forward_kinematics;
pub use model::RobotModel;
pub use oracle::{nearest_free, NearestFree, OracleOptions};
pub use pairs::{CandidatePair, PairKind};
pub use plan::{plan_path, PlanOptions, PlanResult, PlanStatus};
pub use sample::sample_uniform;
pub use threads::with_threads;
