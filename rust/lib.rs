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
//! Nothing here knows Python; `python.rs` (feature `python`) is the only binding layer.

mod broad;
pub mod collide;
pub mod error;
pub mod interpolate;
pub mod kinematics;
pub mod model;
pub mod sample;
pub mod shapes;

#[cfg(feature = "python")]
mod python;

pub use collide::{label_batch, Label, LabelOptions, LabelBatch, PairKind};
pub use error::{Error, Result};
pub use interpolate::interpolate_so2;
pub use model::{ModelDesc, RobotModel};
pub use sample::sample_uniform;

/// Runs `f` on a rayon pool of `threads` workers (the global pool when `None`).
///
/// Results never depend on the count: work is split into fixed-size, independently seeded items.
pub fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> Result<T> {
    match threads {
        None => Ok(f()),
        Some(0) => error::invalid_input("threads must be at least 1"),
        Some(n) => match rayon::ThreadPoolBuilder::new().num_threads(n).build() {
            Ok(pool) => Ok(pool.install(f)),
            Err(e) => error::invalid_input(format!("could not start {n} threads: {e}")),
        },
    }
}
