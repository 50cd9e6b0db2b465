//! Interpolation on SO(2)^K: continuous joints take the shortest arc, limited ones the straight
//! segment (which stays inside the limits when both ends do). The short arc is `angles::wrap` of
//! the difference, the planner's (`planning/plan.rs`): a half turn, exactly ±π, moves the negative way.

use crate::error::{invalid_input, Result};
use crate::joints::angles::wrap;

/// Interpolates `B` start/goal pairs (`(B, K)` row-major each) at `steps` evenly spaced times
/// including both ends; returns `(B, steps, K)` row-major. `continuous[k]` marks joints that wrap.
///
/// # Example
/// ```
/// use std::f64::consts::PI;
/// // A continuous joint from 3.0 to -3.0 rad goes the short way, through pi.
/// let path = profrobot::interpolate_so2(&[3.0], &[-3.0], 3, &[true]).unwrap();
/// assert!((path[1] - (3.0 + (2.0 * PI - 6.0) / 2.0)).abs() < 1e-12);
/// ```
pub fn interpolate_so2(start: &[f64], goal: &[f64], steps: usize, continuous: &[bool]) -> Result<Vec<f64>> {
    let k = continuous.len();
    if k == 0 || start.is_empty() || start.len() % k != 0 {
        return invalid_input(format!("start must be a non-empty (B, {k}) array; got {} values", start.len()));
    }
    if goal.len() != start.len() {
        return invalid_input(format!("goal has {} values but start has {}", goal.len(), start.len()));
    }
    if steps < 2 {
        return invalid_input(format!("steps must be at least 2 (both end points); got {steps}"));
    }
    if let Some(i) = start.iter().chain(goal).position(|v| !v.is_finite()) {
        return invalid_input(format!("start/goal value {i} is not finite"));
    }
    let b = start.len() / k;
    let mut out = Vec::with_capacity(crate::budget::check("steps", &[b, steps, k], 8)?);
    for p in 0..b {
        let (s, g) = (&start[p * k..(p + 1) * k], &goal[p * k..(p + 1) * k]);
        let delta: Vec<f64> = (0..k).map(|j| if continuous[j] { wrap(g[j] - s[j]) } else { g[j] - s[j] }).collect();
        for t in 0..steps {
            let a = t as f64 / (steps - 1) as f64;
            out.extend((0..k).map(|j| if t == steps - 1 && !continuous[j] { g[j] } else { s[j] + a * delta[j] }));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use std::f64::consts::PI;

    use super::*;

    #[test]
    fn limited_joints_go_straight_and_hit_the_goal_exactly() {
        let path = interpolate_so2(&[0.0, 1.0], &[1.0, -1.0], 5, &[false, false]).unwrap();
        assert_eq!(&path[0..2], &[0.0, 1.0]);
        assert_eq!(&path[8..10], &[1.0, -1.0]);
        assert!((path[4] - 0.5).abs() < 1e-15 && path[5].abs() < 1e-15);
    }

    #[test]
    fn continuous_joints_take_the_short_way_round() {
        let path = interpolate_so2(&[-3.0], &[3.0], 11, &[true]).unwrap();
        let step = path[1] - path[0];
        assert!(step < 0.0 && (step * 10.0 + (2.0 * PI - 6.0)).abs() < 1e-12);
        let end = path[10].rem_euclid(2.0 * PI);
        assert!((end - 3.0_f64.rem_euclid(2.0 * PI)).abs() < 1e-12);
    }

    #[test]
    fn a_half_turn_moves_the_negative_way_from_either_end() {
        // From 0 to ±π, and from π to 0: the difference is -π (`angles::wrap`), both ways.
        for goal in [PI, -PI] {
            let path = interpolate_so2(&[0.0], &[goal], 3, &[true]).unwrap();
            assert_eq!(path, vec![0.0, -PI / 2.0, -PI]);
        }
        let path = interpolate_so2(&[PI], &[0.0], 3, &[true]).unwrap();
        assert_eq!(path, vec![PI, PI / 2.0, 0.0]);
    }

    #[test]
    fn bad_arguments_are_errors() {
        assert!(interpolate_so2(&[0.0], &[0.0], 1, &[false]).is_err());
        assert!(interpolate_so2(&[0.0, 1.0], &[0.0], 3, &[false]).is_err());
        assert!(interpolate_so2(&[f64::NAN], &[0.0], 3, &[false]).is_err());
    }
}
