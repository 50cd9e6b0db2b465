//! Joint-space motion over the exact labeller: straight motions certified continuously
//! ([`motion`], with `spans`), the nearest free pose ([`oracle`]) and global paths ([`plan`]).

pub mod motion;
pub mod oracle;
pub mod plan;
mod spans;
