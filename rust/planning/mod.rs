//! Joint-space motion over the exact labeller: straight motions certified continuously
//! ([`motion`], with `spans`), the nearest free pose ([`oracle`]), global paths ([`plan`]) and
//! paths in time ([`timing`]).

pub mod motion;
pub mod oracle;
pub mod plan;
mod spans;
pub mod timing;
