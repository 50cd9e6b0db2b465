//! Joint couplings: MuJoCo's joint equalities (a URDF `<mimic>` becomes one), each a dependent
//! joint given by a polynomial of an independent one,
//!
//! ```text
//! q[dep] = y0 + c0 + c1·d + c2·d² + c3·d³ + c4·d⁴,   d = q[indep] − x0
//! ```
//!
//! (`indep = -1`: `q[dep] = y0 + c0`, a locked joint). `y0`, `x0` are the joints' `qpos0`, as
//! MuJoCo's `mj_equality` reads them. A pose the mechanism can take is on every coupling and
//! within every limit ([`Couplings::feasible`]); a certificate about any other pose certifies
//! nothing, so certification refuses them.
//!
//! **Motions.** The robot executes a straight joint-space motion of its independent joints with
//! the dependent ones following: `q(t) = project(a + t·Δ)`. For a linear coupling between two
//! coupled poses that *is* the straight line; for a nonlinear one it is a curve. The continuous
//! certificate (`planning/motion.rs`) places `q(t)` itself and bounds each dependent joint's speed by
//! `max |f'(x)|` over the interval its independent joint sweeps, times that joint's speed
//! ([`Couplings::speeds`]): the rate bounds it proves with stay upper bounds, so what is
//! certified is the motion the robot makes.

use serde::{Deserialize, Serialize};

use crate::error::{invalid_model, Result};

/// Tolerance (radians or metres, absolute) of "on its couplings" and "within its limits".
pub const FEASIBLE_TOL: f64 = 1e-9;

/// One joint equality, as MuJoCo compiled it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Coupling {
    pub dep: u32,
    /// The independent joint, or -1 (the dependent joint is locked at `y0 + c0`).
    pub indep: i32,
    pub coef: [f64; 5],
    pub y0: f64,
    pub x0: f64,
}

impl Coupling {
    /// `q[dep]` as the coupling gives it, from `q[indep]` = `x`.
    #[inline]
    pub fn value(&self, x: f64) -> f64 {
        let c = &self.coef;
        if self.indep < 0 {
            return self.y0 + c[0];
        }
        let d = x - self.x0;
        self.y0 + c[0] + d * (c[1] + d * (c[2] + d * (c[3] + d * c[4])))
    }

    /// `d q[dep] / d q[indep]` at `q[indep]` = `x` (0 for a locked joint).
    #[inline]
    pub fn slope(&self, x: f64) -> f64 {
        if self.indep < 0 {
            return 0.0;
        }
        let c = &self.coef;
        let d = x - self.x0;
        c[1] + d * (2.0 * c[2] + d * (3.0 * c[3] + d * 4.0 * c[4]))
    }

    fn linear(&self) -> bool {
        self.coef[2] == 0.0 && self.coef[3] == 0.0 && self.coef[4] == 0.0
    }

    /// `(lo, hi)` bounding `value(x)` for `x` in `[xlo, xhi]` (interval arithmetic, term by term).
    fn value_range(&self, xlo: f64, xhi: f64) -> (f64, f64) {
        if self.indep < 0 {
            let v = self.value(0.0);
            return (v, v);
        }
        let (dlo, dhi) = (xlo - self.x0, xhi - self.x0);
        let (mut lo, mut hi) = (self.y0 + self.coef[0], self.y0 + self.coef[0]);
        for i in 1..5 {
            let (plo, phi) = pow_range(dlo, dhi, i as i32);
            let c = self.coef[i];
            let (a, b) = (c * plo, c * phi);
            lo += a.min(b);
            hi += a.max(b);
        }
        (lo, hi)
    }

    /// An upper bound of `|f'(x)|` for `x` in `[xlo, xhi]`.
    fn slope_bound(&self, xlo: f64, xhi: f64) -> f64 {
        if self.indep < 0 {
            return 0.0;
        }
        let big = (xlo - self.x0).abs().max((xhi - self.x0).abs());
        let c = &self.coef;
        c[1].abs() + big * (2.0 * c[2].abs() + big * (3.0 * c[3].abs() + big * 4.0 * c[4].abs()))
    }
}

/// `[lo, hi]` of `d^i` for `d` in `[dlo, dhi]`.
fn pow_range(dlo: f64, dhi: f64, i: i32) -> (f64, f64) {
    let (a, b) = (dlo.powi(i), dhi.powi(i));
    if i % 2 == 0 && dlo <= 0.0 && dhi >= 0.0 {
        (0.0, a.max(b))
    } else {
        (a.min(b), a.max(b))
    }
}

/// A robot's couplings in dependency order (an independent joint that is itself dependent is
/// computed first), validated once.
#[derive(Clone, Debug, Default)]
pub struct Couplings {
    rows: Vec<Coupling>,
}

impl Couplings {
    /// Checks `rows` against `njoint` joints and orders them; a joint made dependent twice, a
    /// cycle, an index out of range or a non-finite coefficient is a model error.
    pub fn new(rows: &[Coupling], njoint: usize) -> Result<Couplings> {
        let mut by_dep: Vec<Option<Coupling>> = vec![None; njoint];
        for (e, c) in rows.iter().enumerate() {
            let dep = c.dep as usize;
            if dep >= njoint || c.indep >= njoint as i32 || c.indep < -1 || c.indep == c.dep as i32 {
                return invalid_model(format!("joint coupling {e} links joints {} and {}, of {njoint}", c.dep, c.indep));
            }
            if !(c.coef.iter().all(|v| v.is_finite()) && c.y0.is_finite() && c.x0.is_finite()) {
                return invalid_model(format!("joint coupling {e} (joint {dep}) has a non-finite coefficient"));
            }
            if by_dep[dep].is_some() {
                return invalid_model(format!("joint {dep} is the dependent joint of two couplings"));
            }
            by_dep[dep] = Some(*c);
        }
        // Depth-first, so that a dependent's independent joint comes before it.
        let mut order = Vec::with_capacity(rows.len());
        let mut state = vec![0u8; njoint]; // 0 new, 1 on the stack, 2 done
        for start in 0..njoint {
            let mut stack = vec![start];
            while let Some(&j) = stack.last() {
                let Some(c) = by_dep[j] else {
                    state[j] = 2;
                    stack.pop();
                    continue;
                };
                if state[j] == 2 {
                    stack.pop();
                    continue;
                }
                state[j] = 1;
                let up = c.indep;
                if up >= 0 && state[up as usize] != 2 {
                    if state[up as usize] == 1 {
                        return invalid_model(format!("joint couplings form a cycle through joint {j}"));
                    }
                    stack.push(up as usize);
                    continue;
                }
                state[j] = 2;
                order.push(c);
                stack.pop();
            }
        }
        Ok(Couplings { rows: order })
    }

    /// The couplings in dependency order.
    pub fn rows(&self) -> &[Coupling] {
        &self.rows
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Whether every coupling is linear (then a straight motion between coupled poses stays
    /// coupled).
    pub fn linear(&self) -> bool {
        self.rows.iter().all(Coupling::linear)
    }

    /// Overwrites the dependent joints of `q` (one pose) from their independent ones.
    #[inline]
    pub fn apply(&self, q: &mut [f64]) {
        for c in &self.rows {
            let x = if c.indep >= 0 { q[c.indep as usize] } else { 0.0 };
            q[c.dep as usize] = c.value(x);
        }
    }

    /// The largest `|q[dep] − f(q[indep])|` over the couplings (0 with none).
    pub fn residual(&self, q: &[f64]) -> f64 {
        self.rows
            .iter()
            .map(|c| {
                let x = if c.indep >= 0 { q[c.indep as usize] } else { 0.0 };
                (q[c.dep as usize] - c.value(x)).abs()
            })
            .fold(0.0, f64::max)
    }

    /// Replaces, in dependency order, each dependent joint's `|Δ|` in `abs_delta` by a bound on
    /// its speed along the motion `project(a + t·Δ)`, `t ∈ [0, 1]`: `max |f'|` over the interval
    /// its independent joint sweeps (`lo`/`hi`: per joint, that interval, updated here for the
    /// dependent joints) times the independent joint's speed.
    pub fn speeds(&self, lo: &mut [f64], hi: &mut [f64], abs_delta: &mut [f64]) {
        for c in &self.rows {
            let dep = c.dep as usize;
            if c.indep < 0 {
                abs_delta[dep] = 0.0;
                (lo[dep], hi[dep]) = c.value_range(0.0, 0.0);
                continue;
            }
            let i = c.indep as usize;
            abs_delta[dep] = c.slope_bound(lo[i], hi[i]) * abs_delta[i];
            (lo[dep], hi[dep]) = c.value_range(lo[i], hi[i]);
        }
    }
}

/// Whether pose `q` is one the mechanism can take: every limited joint within `limits`
/// (tolerance [`FEASIBLE_TOL`]) and every coupling met to [`FEASIBLE_TOL`].
pub fn feasible(q: &[f64], limits: &[[f64; 2]], limited: &[bool], couplings: &Couplings) -> bool {
    q.iter().zip(limits).zip(limited).all(|((&v, &[lo, hi]), &l)| !l || (lo - FEASIBLE_TOL..=hi + FEASIBLE_TOL).contains(&v))
        && couplings.residual(q) <= FEASIBLE_TOL
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(dep: u32, indep: i32, coef: [f64; 5]) -> Coupling {
        Coupling { dep, indep, coef, y0: 0.1, x0: -0.2 }
    }

    #[test]
    fn chains_are_applied_in_dependency_order_and_cycles_refused() {
        // q0 = f(q1), q1 = g(q2): q2 first, then q1, then q0, whatever the listed order
        let c = Couplings::new(&[row(0, 1, [0.0, 2.0, 0.0, 0.0, 0.0]), row(1, 2, [0.5, -1.0, 0.3, 0.0, 0.0])], 3).unwrap();
        let mut q = [9.0, 9.0, 0.7];
        c.apply(&mut q);
        assert!(c.residual(&q) < 1e-15, "{q:?}");
        assert!(!c.linear());
        assert!(Couplings::new(&[row(0, 1, [0.0; 5]), row(1, 0, [0.0; 5])], 2).is_err());
        assert!(Couplings::new(&[row(0, 1, [0.0; 5]), row(0, 2, [0.0; 5])], 3).is_err());
        assert!(Couplings::new(&[row(0, 5, [0.0; 5])], 3).is_err());
        assert!(Couplings::new(&[row(0, 1, [f64::NAN, 0.0, 0.0, 0.0, 0.0])], 2).is_err());
    }

    /// The speed and range bounds hold along sampled motions of a nonlinear chain.
    #[test]
    fn speed_and_range_bounds_hold_along_motions() {
        use rand::{Rng, SeedableRng};
        let c = Couplings::new(&[row(0, 1, [0.1, 0.5, -0.8, 0.3, 0.2]), row(1, 2, [0.0, 1.5, 0.4, -0.2, 0.05])], 3).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for _ in 0..200 {
            let a2: f64 = rng.random_range(-1.0..1.0);
            let d2: f64 = rng.random_range(-1.0..1.0);
            let (mut lo, mut hi) = ([0.0; 3], [0.0; 3]);
            (lo[2], hi[2]) = (a2.min(a2 + d2), a2.max(a2 + d2));
            let mut speed = [0.0, 0.0, d2.abs()];
            c.speeds(&mut lo, &mut hi, &mut speed);
            let place = |t: f64| {
                let mut q = [0.0, 0.0, a2 + t * d2];
                c.apply(&mut q);
                q
            };
            let n = 400;
            for i in 0..n {
                let (q, r) = (place(i as f64 / n as f64), place((i + 1) as f64 / n as f64));
                for j in 0..3 {
                    assert!((r[j] - q[j]).abs() <= speed[j] / n as f64 * (1.0 + 1e-9) + 1e-15, "joint {j} speed");
                    assert!(q[j] >= lo[j] - 1e-12 && q[j] <= hi[j] + 1e-12, "joint {j} range");
                }
            }
        }
    }

    #[test]
    fn feasible_needs_limits_and_couplings() {
        let c = Couplings::new(&[Coupling { dep: 1, indep: 0, coef: [0.0, 1.0, 0.0, 0.0, 0.0], y0: 0.0, x0: 0.0 }], 2).unwrap();
        let lim = [[0.0, 0.04], [0.0, 0.04]];
        assert!(feasible(&[0.01, 0.01], &lim, &[true, true], &c));
        assert!(!feasible(&[0.01, 0.03], &lim, &[true, true], &c));
        assert!(!feasible(&[0.05, 0.05], &lim, &[true, true], &c));
        assert!(feasible(&[0.05, 0.05], &lim, &[false, false], &c));
    }
}
