//! An oracle for the smallest joint-space move that frees a colliding pose: the yardstick for
//! Δθ of collision resolution (`profrobot.optim.resolve`).
//!
//! For a colliding pose `q0` (within its joint limits), the nearest free pose in the L2 norm
//! lies on the boundary of the free space. We search it along rays `q0 + t u` (unit `u`), every
//! state decided by the exact labeller (the `collides` fast path):
//!
//! 1. **march**: `directions` seeded uniform directions; each ray is walked in steps of `step`
//!    up to the best distance found so far (or `max_distance`); the first free state is
//!    bisected against the last colliding one down to `tolerance`. This finds the first exit of
//!    each ray (up to free gaps thinner than `step`).
//! 2. **refine**: `refine` perturbations of good directions, each probed at the best distance
//!    so far and, when free there, bisected from `q0`: (1+1) random searches on the sphere of
//!    directions, with a step size that grows on success and shrinks on failure, started from
//!    the march's last few improvements (distinct basins), the best last.
//!
//! The result is an upper bound on the true nearest distance (a free pose at that distance is
//! returned, free per the labeller), tight to about `tolerance` along the best ray; more
//! directions and refinements tighten it. Limited joints stay within their ranges: a ray
//! that reaches a limit slides along it (the joint is clamped, so the state's distance from
//! `q0`, which is what is minimised, grows no faster than the ray parameter). Continuous
//! hinges move freely (not wrapped). A free `q0` is its own answer, at distance 0.
//!
//! Deterministic: pose `i` draws its directions from ChaCha8 seeded with `seed` on stream `i`,
//! and its search runs on one thread, so the answer does not depend on the thread count.
//!
//! A state whose pair the narrow phase cannot decide (`collision/collide.rs`: never "free") ends the
//! search of its pose, and the call fails naming that input pose, the state and the pair.

use std::borrow::Cow;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use rayon::prelude::*;

use crate::collision::collide::{first_error, Scratch, Undecided};
use crate::collision::fastpath::{collides_pose, likely_pairs};
use crate::error::{invalid_input, Result};
use crate::model::RobotModel;

/// Local searches after the march, from its last improvements.
const RESTARTS: usize = 4;

/// How hard to search (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct OracleOptions {
    /// Random rays marched from each colliding pose (at least 1).
    pub directions: usize,
    /// Marching step along a ray (radians / metres, L2).
    pub step: f64,
    /// Bisection tolerance on the distance (at most `step`).
    pub tolerance: f64,
    /// Perturbations of the best direction tried after the march.
    pub refine: usize,
    /// No move longer than this is considered (`INFINITY`: the diagonal of the sampling
    /// ranges, the longest move between two poses within them).
    pub max_distance: f64,
    pub seed: u64,
}

impl Default for OracleOptions {
    fn default() -> Self {
        OracleOptions { directions: 256, step: 0.02, tolerance: 1e-4, refine: 1024, max_distance: f64::INFINITY, seed: 0 }
    }
}

/// The oracle's answer for a batch of B poses.
#[derive(Clone, Debug, Default)]
pub struct NearestFree {
    /// `(B,)`: L2 length of the move to `poses` (0 for a free pose; `INFINITY` when no free
    /// pose was found within `max_distance`).
    pub distance: Vec<f64>,
    /// `(B, K)` row-major: the free pose found (the input pose itself when free; NaN rows
    /// when none was found).
    pub poses: Vec<f64>,
    /// `(B,)`: states labelled for each pose.
    pub checks: Vec<u64>,
}

/// The nearest free pose found for each of a `(B, K)` row-major batch of poses, in parallel on
/// rayon's current pool; identical for any thread count.
pub fn nearest_free(model: &RobotModel, poses: &[f64], opts: &OracleOptions) -> Result<NearestFree> {
    let b = model.check_poses(poses)?;
    let k = model.njoint();
    if opts.directions == 0 {
        return invalid_input("directions must be at least 1");
    }
    if !(opts.step > 0.0 && opts.step.is_finite()) {
        return invalid_input(format!("step must be positive and finite; got {}", opts.step));
    }
    if !(opts.tolerance > 0.0 && opts.tolerance <= opts.step) {
        return invalid_input(format!("tolerance must be positive and at most step ({}); got {}", opts.step, opts.tolerance));
    }
    if opts.max_distance.is_nan() || opts.max_distance <= 0.0 {
        return invalid_input(format!("max_distance must be positive; got {}", opts.max_distance));
    }
    let limits: Vec<Option<[f64; 2]>> = (0..k).map(|j| model.limited[j].then_some(model.limits[j])).collect();
    for (i, q) in poses.chunks_exact(k).enumerate() {
        for (j, (&v, lim)) in q.iter().zip(&limits).enumerate() {
            if let Some([lo, hi]) = *lim {
                if !(lo..=hi).contains(&v) {
                    return invalid_input(format!("pose {i} joint {j} is {v}, outside its limits [{lo}, {hi}]"));
                }
            }
        }
    }
    let max_distance = if opts.max_distance.is_finite() {
        opts.max_distance
    } else {
        model.sampling_ranges()?.iter().map(|[lo, hi]| (hi - lo) * (hi - lo)).sum::<f64>().sqrt().max(opts.step)
    };
    likely_pairs(model); // once, before the workers need it
    let search = Search { model, limits: &limits, opts, max_distance };
    // Each pose first put on its couplings: the search runs among poses the robot can take.
    let coupled: Cow<[f64]> = if model.couplings().is_empty() {
        Cow::Borrowed(poses)
    } else {
        let mut owned = poses.to_vec();
        owned.chunks_exact_mut(k).for_each(|q| model.couplings().apply(q));
        Cow::Owned(owned)
    };
    let found: Vec<Result<(f64, Vec<f64>, u64)>> = coupled
        .par_chunks(k)
        .enumerate()
        .map_init(
            || Scratch::new(model),
            |s, (i, q0)| {
                crate::cancel::check()?;
                search.pose(q0, i as u64, s)
            },
        )
        .collect();
    let found = first_error(found)?;
    let mut out = NearestFree { distance: Vec::with_capacity(b), poses: Vec::with_capacity(b * k), checks: Vec::with_capacity(b) };
    for (d, q, c) in found {
        out.distance.push(d);
        out.poses.extend(q);
        out.checks.push(c);
    }
    Ok(out)
}

/// One batch's search settings.
struct Search<'a> {
    model: &'a RobotModel,
    /// Per joint: its range when limited.
    limits: &'a [Option<[f64; 2]>],
    opts: &'a OracleOptions,
    max_distance: f64,
}

/// The rays of one pose: `q0` and its labelling scratch.
struct Rays<'a, 's> {
    search: &'a Search<'a>,
    q0: &'a [f64],
    scratch: &'s mut Scratch,
    q: Vec<f64>,
    checks: u64,
}

impl Rays<'_, '_> {
    /// Places `q0 + t u` in `self.q`, limited joints clamped into their ranges and dependent
    /// joints put on their couplings, and returns its distance from `q0` (nondecreasing in `t`
    /// for a linear coupling or none).
    fn at(&mut self, u: &[f64], t: f64) -> f64 {
        for (((q, &q0), &u), lim) in self.q.iter_mut().zip(self.q0).zip(u).zip(self.search.limits) {
            *q = q0 + t * u;
            if let Some([lo, hi]) = *lim {
                *q = q.clamp(lo, hi);
            }
        }
        self.search.model.couplings().apply(&mut self.q);
        self.q.iter().zip(self.q0).map(|(q, q0)| (q - q0) * (q - q0)).sum::<f64>().sqrt()
    }

    /// Whether the pose `at(u, t)` placed is free.
    fn free(&mut self) -> std::result::Result<bool, Undecided> {
        self.checks += 1;
        Ok(!collides_pose(self.search.model, &self.q, self.scratch)?)
    }

    /// Bisects `[lo, hi]` along `u` (`lo` colliding, `hi` free) to `tolerance`; the free end.
    fn bisect(&mut self, u: &[f64], mut lo: f64, mut hi: f64) -> std::result::Result<f64, Undecided> {
        while hi - lo > self.search.opts.tolerance {
            let mid = 0.5 * (lo + hi);
            self.at(u, mid);
            if self.free()? {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Ok(hi)
    }

    /// The first free state along `u` (marching by `step`) nearer than `bound`: its ray
    /// parameter and distance.
    fn march(&mut self, u: &[f64], bound: f64) -> std::result::Result<Option<(f64, f64)>, Undecided> {
        let step = self.search.opts.step;
        let (mut lo, mut last) = (0.0, 0.0);
        for n in 1.. {
            let t = n as f64 * step;
            let d = self.at(u, t);
            // Beyond the bound, or every moving joint pinned at a limit (nothing new ahead).
            if d >= bound || t > self.search.max_distance || d == last {
                return Ok(None);
            }
            if self.free()? {
                let t = self.bisect(u, lo, t)?;
                return Ok(Some((t, self.at(u, t))));
            }
            (lo, last) = (t, d);
        }
        Ok(None)
    }
}

impl Search<'_> {
    /// The search from one pose (see the module docs): `(distance, pose, checks)`; the error
    /// names input pose `index`, the state and the pair when a state cannot be decided.
    fn pose(&self, q0: &[f64], index: u64, scratch: &mut Scratch) -> Result<(f64, Vec<f64>, u64)> {
        let mut rays = Rays { search: self, q0, scratch, q: q0.to_vec(), checks: 1 };
        match self.search_from(&mut rays, index) {
            Ok(found) => Ok(found),
            Err(e) => {
                let at = if rays.q == q0 { format!("pose {index}") } else { format!("pose {index} (its search state {:?})", rays.q) };
                Err(e.error(self.model, at))
            }
        }
    }

    fn search_from(&self, rays: &mut Rays, index: u64) -> std::result::Result<(f64, Vec<f64>, u64), Undecided> {
        let (q0, k) = (rays.q0, rays.q0.len());
        if !collides_pose(self.model, q0, rays.scratch)? {
            return Ok((0.0, q0.to_vec(), 1));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.opts.seed);
        rng.set_stream(index);
        // The free states the march found, each the best so far when found: (distance,
        // direction, ray parameter), in order, so the last is the best.
        let mut found: Vec<(f64, Vec<f64>, f64)> = Vec::new();
        let mut best_d = self.max_distance;
        let mut u = vec![0.0; k];
        for _ in 0..self.opts.directions {
            random_unit(&mut rng, &mut u);
            if let Some((t, d)) = rays.march(&u, best_d)? {
                best_d = d;
                found.push((d, u.clone(), t));
            }
        }
        let Some((_, mut best_u, mut best_t)) = found.last().cloned() else {
            return Ok((f64::INFINITY, vec![f64::NAN; k], rays.checks));
        };
        // (1+1) searches around the last RESTARTS improvements of the march (the best last),
        // `refine / RESTARTS` probes each; `sigma` is the perturbation's length. A probe at ray
        // parameter `best_d` is no farther than `best_d` from `q0`.
        let starts = found.len().min(RESTARTS);
        let mut g = vec![0.0; k];
        for (r, (_, start_u, _)) in found[found.len() - starts..].iter().enumerate() {
            let mut centre = start_u.clone();
            let mut sigma = 0.3f64;
            let rounds = self.opts.refine / starts + usize::from(r < self.opts.refine % starts);
            for _ in 0..rounds {
                random_unit(&mut rng, &mut g);
                for ((u, &c), &g) in u.iter_mut().zip(&centre).zip(&g) {
                    *u = c + sigma * g;
                }
                let norm = u.iter().map(|v| v * v).sum::<f64>().sqrt();
                if norm == 0.0 {
                    continue;
                }
                u.iter_mut().for_each(|v| *v /= norm);
                rays.at(&u, best_d);
                if rays.free()? {
                    let t = rays.bisect(&u, 0.0, best_d)?;
                    let d = rays.at(&u, t);
                    if d < best_d {
                        (best_d, best_t) = (d, t);
                        best_u.copy_from_slice(&u);
                        centre.copy_from_slice(&u);
                        sigma = (sigma * 1.5).min(1.0);
                        continue;
                    }
                }
                sigma = (sigma * 0.9).max(1e-3);
            }
        }
        // The best state, labelled free by the bisection that found it.
        let d = rays.at(&best_u, best_t);
        Ok((d, rays.q.clone(), rays.checks))
    }
}

/// A uniform random unit vector (normalised Gaussian, by Box-Muller) into `u`.
fn random_unit(rng: &mut ChaCha8Rng, u: &mut [f64]) {
    loop {
        for v in u.iter_mut() {
            let (a, b): (f64, f64) = (rng.random(), rng.random());
            // 1 - a is in (0, 1]: the logarithm is finite.
            *v = (-2.0 * (1.0 - a).ln()).sqrt() * (std::f64::consts::TAU * b).cos();
        }
        let norm = u.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 1e-12 {
            u.iter_mut().for_each(|v| *v /= norm);
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::collide::{label_batch, LabelOptions};
    use crate::model::desc::ModelDesc;

    /// The pendulum lowered so that the bob (radius 0.1, 0.4 below the hinge at 0.45) dips 0.05
    /// below the floor when hanging: free once it swings by acos(0.35 / 0.4) ~ 0.505 rad.
    fn lowered_pendulum() -> RobotModel {
        let mut desc = ModelDesc::example_pendulum();
        desc.body_pos[1][2] = 0.45;
        RobotModel::new(desc).unwrap()
    }

    #[test]
    fn pendulum_swings_just_clear_of_the_floor() {
        let model = lowered_pendulum();
        let poses = [0.0, 0.2, -0.3, 1.0];
        let opts = OracleOptions { directions: 4, refine: 8, ..Default::default() };
        let r = nearest_free(&model, &poses, &opts).unwrap();
        let free = label_batch(&model, &r.poses, LabelOptions::default()).unwrap();
        assert!(free.labels.iter().all(|l| !l.collides()));
        // Along one joint the search is exact to the tolerance.
        let edge = (0.35f64 / 0.4).acos();
        for (q, d) in poses.iter().zip(&r.distance).take(3) {
            let want = edge - q.abs();
            assert!(*d >= want - 1e-12 && *d <= want + 1e-4, "{q}: {d} vs {want}");
        }
        assert_eq!((r.distance[3], r.poses[3], r.checks[3]), (0.0, 1.0, 1));
    }

    #[test]
    fn same_answer_on_one_and_two_threads() {
        let model = lowered_pendulum();
        let poses: Vec<f64> = (0..40).map(|i| -0.4 + 0.02 * i as f64).collect();
        let opts = OracleOptions { directions: 3, refine: 5, seed: 7, ..Default::default() };
        let run =
            |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(|| nearest_free(&model, &poses, &opts).unwrap());
        let (a, b) = (run(1), run(2));
        assert_eq!((a.distance, a.poses, a.checks), (b.distance, b.poses, b.checks));
    }

    #[test]
    fn bad_arguments_are_errors() {
        let model = lowered_pendulum();
        let ok = OracleOptions::default();
        assert!(nearest_free(&model, &[0.0], &OracleOptions { directions: 0, ..ok }).is_err());
        assert!(nearest_free(&model, &[0.0], &OracleOptions { step: 0.0, ..ok }).is_err());
        assert!(nearest_free(&model, &[0.0], &OracleOptions { tolerance: 0.1, ..ok }).is_err());
        assert!(nearest_free(&model, &[0.0], &OracleOptions { max_distance: f64::NAN, ..ok }).is_err());
        assert!(nearest_free(&model, &[f64::NAN], &ok).is_err());
        assert!(nearest_free(&model, &[], &ok).is_err());
        assert!(nearest_free(&model, &[4.0], &ok).is_err(), "outside the joint limits");
    }
}
