//! Collision queries of one pose over the model's candidate pairs: labelling and its narrow phase
//! ([`collide`], with `sat` and `capsules`), the booleans-only fast path ([`fastpath`]) and the
//! self-filter of a sensor's points ([`filter`]).

mod capsules;
pub mod collide;
pub mod fastpath;
pub mod filter;
mod sat;
