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
//! q ──model::kinematics::body_poses──▶ body frames ──▶ geom frames ──collision::collide::label_pose──▶ Label
//! ```
//!
//! # Layout
//!
//! The crate root keeps four crate-wide leaves (`error`, `budget`, `threads`, `cancel`); every other
//! module sits in a folder by concern (`folder/mod.rs`). The table below has one row per module,
//! lowest layer first: the leaves, then each folder followed by its modules. A top-level row (a
//! leaf or a folder) lists the top-level modules its code uses, all in earlier rows (lower
//! layers), so there is no cycle. The layers, top to bottom:
//!
//! ```text
//! bindings          (feature `python`: pyo3 over the rest)
//! render            (apart from the labeller: uses only error and budget)
//! ik
//! planning
//! collision
//! model
//! geometry
//! joints
//! budget, threads, cancel
//! error
//! ```
//!
//! Unit tests may use more (`tests also use`), higher up too, for cross-checks: the labeller's
//! tests run the planners on a model it cannot decide, IK's reuse the motion tests' arm, the
//! rasterizer's and the timed paths' pick thread counts. `tests/test_rust_layout.py` holds the
//! code to this table.
//!
//! | module | concern | uses | tests also use |
//! |---|---|---|---|
//! | [`error`] | the one error type | | |
//! | [`budget`] | sizes checked against the memory available before they are allocated | `error` | |
//! | [`threads`] | one rayon pool per thread count, fork-safe; one work item on the calling thread; a call run on its own thread with a thread count; a few unequal items shared, the sleeping workers steered off the busy CPU | `error` | |
//! | `threads::crew` | helper threads kept awake between one call's few-item sections, off the caller's CPU, fork-safe | | |
//! | [`cancel`] | the flag long loops read between items: a call stopped part-way (Ctrl-C) | `error` | |
//! | [`joints`] | joint space: poses and what holds of them before any geometry | `error`, `budget` | |
//! | [`joints::angles`] | the one angle wrap (SO(2), shortest arcs) | | |
//! | [`joints::couplings`] | joint equalities: dependent joints, feasible poses, coupled motions | | |
//! | [`joints::validate`] | caller input checked in one pass (finite poses within limits) | | |
//! | [`joints::sample`] | seeded uniform pose sampling, the same whatever the thread count | | |
//! | [`joints::interpolate`] | interpolation on SO(2)^K (short arcs, straight segments) | | |
//! | [`geometry`] | solids, knowing nothing of robots | `error` | |
//! | [`geometry::hull`] | convex hulls: support points by hill climbing, the cube map, face planes | | |
//! | `geometry::inner` | balls inside each convex shape: overlaps proven without GJK | | |
//! | [`geometry::cloud`] | point clouds: balls in a tree, exact queries against one convex shape, voxel downsampling | | |
//! | [`geometry::shapes`] | `GeomType`, `GeomShape`, `Solid` (half-space, convex or cloud), `Convex` | | |
//! | [`model`] | `RobotModel`: the validated, derived robot, its pairs, broad phase and kinematics | `error`, `budget`, `threads`, `joints`, `geometry` | |
//! | [`model::desc`] | `ModelDesc`: the robot as plain serde data | | |
//! | [`model::geom`] | `Geom`: a shape on a body | | |
//! | [`model::pairs`] | candidate pairs with MuJoCo's filters | | |
//! | `model::sphere_pairs` | many sphere-pair tests at once (structure of arrays, AVX2): the broad phase's inner loop | | |
//! | `model::broad` | the per-pose broad phase (bounding spheres), built with the model | | |
//! | `model::trig` | sin and cos of hinge half angles: libm's (msun), one pose or four lanes, bit for bit | | |
//! | `model::lanes` | four poses at once: nalgebra's quaternion and matrix arithmetic lane for lane, bit for bit | | |
//! | [`model::kinematics`] | forward kinematics, one pose or a batch | | |
//! | `model::proven` | the straight motions a model has proven, so that none is proven twice | | |
//! | [`collision`] | collision queries of one pose over the candidate pairs | `error`, `threads`, `cancel`, `joints`, `geometry`, `model` | `planning` |
//! | [`collision::collide`] | labelling: narrow phase and batches | | |
//! | `collision::sat` | remembered separating axes, tried before GJK; GJK's axis, stopped when good enough | | |
//! | `collision::capsules` | two capsules in closed form, as MuJoCo measures them | | |
//! | [`collision::fastpath`] | the booleans-only fast path: first pair in contact, likeliest first | | |
//! | [`collision::filter`] | a sensor's points within a margin of the model at a pose (the self-filter) | | |
//! | [`planning`] | joint-space motion over the exact labeller | `error`, `budget`, `cancel`, `threads`, `joints`, `geometry`, `model`, `collision` | |
//! | `planning::spans` | pairs one joint alone moves, certified once over that joint's values | | |
//! | [`planning::motion`] | straight joint-space motions certified continuously (conservative advancement) | | |
//! | [`planning::oracle`] | the nearest free pose found by rays and bisection (the Δθ yardstick) | | |
//! | [`planning::plan`] | global paths: RRT-Connect on the exact labeller, shortcutting | | |
//! | [`planning::timing`] | paths in time: parabolic blends and corner cuts, each proven by the certificate | | |
//! | [`ik`] | inverse kinematics: Levenberg–Marquardt on the SE(3) error, seeds, certified answers | `error`, `cancel`, `joints`, `model`, `collision` | `planning` |
//! | [`render`] | the renderer after FK: EWA projection, SH colour, rasterization, fused backward | `error`, `budget` | `threads` |
//! | [`render::real`] | `f32`/`f64`: the float types the renderer computes in | | |
//! | [`render::splat`] | Gaussian-splat tile rasterizer: forward compositing and its exact backward | | |
//! | [`render::images`] | rendered images finished (background, expected depth) and compared (the image loss), with gradients | | |
//! | `bindings` | the pyo3 module `profrobot._core` (feature `python`), the only code that knows Python | `error`, `threads`, `cancel`, `joints`, `geometry`, `model`, `collision`, `planning`, `ik`, `render` | |
//! | `bindings::errors` | the Python error classes, and the core's errors mapped onto them | | |
//! | `bindings::interrupt` | long calls stop on Ctrl-C: run off the calling thread, which watches meanwhile, or on it, its loops watching | | |
//! | `bindings::arrays` | numpy arguments read in any memory layout | | |
//! | `bindings::model` | `RobotModel`: built from MuJoCo's arrays, pickled, and all its methods | | |
//! | `bindings::joints` | `interpolate`, `first_bad_entries` | | |
//! | `bindings::clouds` | point-cloud arguments, `voxel_downsample` | | |
//! | `bindings::render` | `render_forward`, `render_backward` and the state between them | | |
//! | `bindings::images` | `finish_images`, `image_loss` and their backwards | | |
//! | `bindings::threads` | `crew_awake`: the crew's helpers woken ahead of a call | | |

pub mod budget;
pub mod cancel;
pub mod error;
pub mod threads;

pub mod collision;
pub mod geometry;
pub mod ik;
pub mod joints;
pub mod model;
pub mod planning;
pub mod render;

#[cfg(feature = "python")]
mod bindings;

pub use collision::collide::{label_batch, Label, LabelBatch, LabelOptions};
pub use collision::fastpath::collides_batch;
pub use error::{Error, Result};
pub use joints::interpolate::interpolate_so2;
pub use joints::sample::sample_uniform;
pub use model::desc::ModelDesc;
pub use model::geom::Geom;
pub use model::kinematics::forward_kinematics;
pub use model::pairs::{CandidatePair, PairKind};
pub use model::RobotModel;
pub use planning::oracle::{nearest_free, NearestFree, OracleOptions};
pub use planning::plan::{plan_path, PlanOptions, PlanResult, PlanStatus};
pub use threads::with_threads;
