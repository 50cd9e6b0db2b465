//! Solids, knowing nothing of robots: convex hulls ([`hull`]), balls inside each convex shape
//! (`inner`), point clouds ([`cloud`]) and the shapes geoms become ([`shapes`]).

pub mod cloud;
pub mod hull;
pub(crate) mod inner;
pub mod shapes;
