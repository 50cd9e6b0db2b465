//! Joint space: poses and what holds of them before any geometry, the crate's lowest folder
//! (it uses only `error` and `budget`).
//!
//! The one angle wrap ([`angles`]), joint equalities ([`couplings`]), caller poses checked in
//! one pass ([`validate`]), seeded sampling ([`sample`]) and SO(2) interpolation ([`interpolate`]).

pub mod angles;
pub mod couplings;
pub mod interpolate;
pub mod sample;
pub mod validate;
