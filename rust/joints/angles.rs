//! The one angle wrap of the crate: every continuous hinge (SO(2)) is wrapped, and every
//! shortest-arc difference taken, by [`wrap`], so that the planner's edges are exactly the
//! motions `interpolate_so2` replays. A leaf module: it knows nothing else of the crate.
//!
//! Python has one twin, `profrobot.angles.wrap` (numpy; the torch one in `joints.py` is the same
//! formula), tested against this one bit for bit.

use std::f64::consts::{PI, TAU};

/// `x` wrapped into `[-π, π)`: the representative of `x` modulo 2π.
///
/// - Values already in `[-π, π)` come back unchanged, bit for bit (tiny values stay tiny, a
///   waypoint in range is not moved by an ulp, and `wrap(wrap(x)) == wrap(x)`).
/// - `π` goes to `-π` (so does every odd multiple of π that rounds there): a difference of exactly
///   half a turn, `wrap(b - a)`, moves the negative way.
/// - Otherwise `(x + π).rem_euclid(2π) - π`, where a remainder that rounds up to 2π (e.g. for
///   the float just below `-π`) gives `-π`, never `π`.
///
/// Non-finite `x` gives NaN.
///
/// # Example
/// ```
/// use std::f64::consts::PI;
/// use profrobot::joints::angles::wrap;
/// assert_eq!(wrap(PI), -PI);
/// assert_eq!(wrap(-PI), -PI);
/// assert_eq!(wrap(1e-300), 1e-300);
/// assert!((wrap(3.0 * PI + 0.5) - (0.5 - PI)).abs() < 1e-14);
/// ```
#[inline]
pub fn wrap(x: f64) -> f64 {
    if (-PI..PI).contains(&x) {
        return x;
    }
    let y = (x + PI).rem_euclid(TAU) - PI;
    if y >= PI {
        -PI
    } else {
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_maps_into_the_half_open_circle() {
        let below = f64::from_bits((-PI).to_bits() + 1); // the float just below -π
        for x in [-7.0, -PI, below, -1.0, -0.0, 0.0, 1e-300, 3.0, PI, 3.0 * PI, -3.0 * PI, 9.5, 1e6] {
            let y = wrap(x);
            assert!((-PI..PI).contains(&y), "{x} -> {y}");
            let turns = (x - y) / TAU;
            assert!((turns - turns.round()).abs() < 1e-9, "{x} -> {y}");
            assert_eq!(wrap(y).to_bits(), y.to_bits(), "idempotent at {x}");
        }
        assert_eq!(wrap(PI), -PI);
        assert_eq!(wrap(below), -PI);
        assert_eq!(wrap(0.3).to_bits(), 0.3f64.to_bits());
        assert!(wrap(f64::NAN).is_nan() && wrap(f64::INFINITY).is_nan());
    }
}
