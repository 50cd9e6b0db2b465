//! Candidate pairs: the geom pairs every pose is tested on, derived once per model with
//! `mj_collision`'s filters.
//!
//! - explicit `<pair>`s are always tested, with their own margin, and replace any dynamic pair
//!   over the same two geoms;
//! - dynamic pairs skip geoms on the same weld body, a weld body and its weld parent (unless
//!   either is welded to the world or `filterparent` is disabled), `<exclude>`d body pairs, and
//!   pairs whose contype/conaffinity bitmasks do not match; plane-plane has no collider (nor
//!   does an explicit plane-plane pair).
//!
//! A pair is in contact when its signed distance is below its margin (sum of the geom margins,
//! or the explicit pair's own).

use std::collections::{HashMap, HashSet};

use crate::error::{invalid_model, Result};
use crate::model::desc::ModelDesc;
use crate::model::geom::Geom;

/// Whether a pair is robot against robot or robot against the static scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PairKind {
    SelfCollision,
    Scene,
}

/// Two collidable geoms (indices into `RobotModel::geoms`) tested on every pose.
#[derive(Clone, Debug)]
pub struct CandidatePair {
    pub g1: usize,
    pub g2: usize,
    pub margin: f64,
    pub kind: PairKind,
    pub explicit: bool,
}

/// Derives the candidate pairs of a model with MuJoCo's filters (see the module docs).
pub(crate) fn candidate_pairs(desc: &ModelDesc, body_parent: &[usize], geoms: &[Geom]) -> Result<Vec<CandidatePair>> {
    if !desc.contact_enabled {
        return Ok(Vec::new());
    }
    let index: HashMap<i32, usize> = geoms.iter().enumerate().map(|(i, g)| (g.mujoco_id, i)).collect();
    let weld = |b: usize| desc.body_weld[b] as usize;
    let kind = |a: usize, b: usize| {
        if geoms[a].on_robot && geoms[b].on_robot {
            PairKind::SelfCollision
        } else {
            PairKind::Scene
        }
    };
    let both_planes = |a: usize, b: usize| geoms[a].shape.is_half_space() && geoms[b].shape.is_half_space();

    let mut pairs = Vec::new();
    let mut explicit = HashSet::new();
    for (k, (&[a, b], &margin)) in desc.pair_geom.iter().zip(&desc.pair_margin).enumerate() {
        let (Some(&i), Some(&j)) = (index.get(&a), index.get(&b)) else {
            return invalid_model(format!("explicit pair {k} names geom {a} or {b}, which is not in the geom list"));
        };
        if !margin.is_finite() {
            return invalid_model(format!("explicit pair {k} has a non-finite margin"));
        }
        explicit.insert((i.min(j), i.max(j)));
        if i != j && !both_planes(i, j) {
            pairs.push(CandidatePair { g1: i, g2: j, margin, kind: kind(i, j), explicit: true });
        }
    }

    let excluded: HashSet<(usize, usize)> = desc.exclude.iter().map(|&[a, b]| (a.min(b) as usize, a.max(b) as usize)).collect();
    for i in 0..geoms.len() {
        for j in i + 1..geoms.len() {
            let (b1, b2) = (geoms[i].body, geoms[j].body);
            let (w1, w2) = (weld(b1), weld(b2));
            if w1 == w2 || both_planes(i, j) || explicit.contains(&(i, j)) {
                continue;
            }
            let (p1, p2) = (weld(body_parent[w1]), weld(body_parent[w2]));
            if desc.filter_parent && w1 != 0 && w2 != 0 && (w1 == p2 || w2 == p1) {
                continue;
            }
            if excluded.contains(&(b1.min(b2), b1.max(b2))) {
                continue;
            }
            let (t1, a1) = (desc.geom_contype[i], desc.geom_conaffinity[i]);
            let (t2, a2) = (desc.geom_contype[j], desc.geom_conaffinity[j]);
            if (t1 & a2) == 0 && (t2 & a1) == 0 {
                continue;
            }
            let margin = desc.geom_margin[i] + desc.geom_margin[j];
            pairs.push(CandidatePair { g1: i, g2: j, margin, kind: kind(i, j), explicit: false });
        }
    }
    Ok(pairs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::{GeomShape, GeomType};
    use nalgebra::Isometry3;

    /// The geoms of `desc` (primitives only), placed at their bodies' origins; `on_robot` for
    /// every body but the world.
    fn geoms(desc: &ModelDesc) -> Vec<Geom> {
        (0..desc.geom_id.len())
            .map(|g| {
                let kind = GeomType::from_mujoco(desc.geom_type[g], desc.geom_id[g]).unwrap();
                let (shape, _) = GeomShape::new(kind, desc.geom_size[g], &[], desc.geom_id[g]).unwrap();
                let body = desc.geom_body[g] as usize;
                Geom {
                    mujoco_id: desc.geom_id[g],
                    body,
                    local: Isometry3::identity(),
                    shape: std::sync::Arc::new(shape),
                    on_robot: body != 0,
                }
            })
            .collect()
    }

    fn parents(desc: &ModelDesc) -> Vec<usize> {
        desc.body_parent.iter().map(|&p| p as usize).collect()
    }

    #[test]
    fn pendulum_bob_against_floor_is_the_one_scene_pair() {
        let desc = ModelDesc::example_pendulum();
        let pairs = candidate_pairs(&desc, &parents(&desc), &geoms(&desc)).unwrap();
        assert_eq!(pairs.len(), 1);
        assert_eq!((pairs[0].g1, pairs[0].g2, pairs[0].kind, pairs[0].explicit), (0, 1, PairKind::Scene, false));
    }

    #[test]
    fn regression_same_weld_body_pairs_are_never_candidates() {
        let mut desc = ModelDesc::example_pendulum();
        desc.body_weld = vec![0, 0]; // the arm welded to the world: no pair left
        assert!(candidate_pairs(&desc, &parents(&desc), &geoms(&desc)).unwrap().is_empty());
    }

    #[test]
    fn regression_explicit_plane_plane_pair_is_dropped_not_tested() {
        // A half-space has no support map: a plane-plane candidate would reach the narrow phase
        // with nothing to test. MuJoCo has no such collider; the pair is dropped.
        let mut desc = ModelDesc::example_pendulum();
        desc.geom_type = vec![0, 0];
        desc.pair_geom = vec![[0, 1]];
        desc.pair_margin = vec![0.0];
        assert!(candidate_pairs(&desc, &parents(&desc), &geoms(&desc)).unwrap().is_empty());
    }

    #[test]
    fn explicit_pair_replaces_the_dynamic_one_and_keeps_its_margin() {
        let mut desc = ModelDesc::example_pendulum();
        desc.pair_geom = vec![[1, 0]];
        desc.pair_margin = vec![0.25];
        let pairs = candidate_pairs(&desc, &parents(&desc), &geoms(&desc)).unwrap();
        assert_eq!(pairs.len(), 1);
        assert!(pairs[0].explicit && pairs[0].margin == 0.25 && (pairs[0].g1, pairs[0].g2) == (1, 0));
    }

    #[test]
    fn contacts_disabled_leaves_no_pair() {
        let mut desc = ModelDesc::example_pendulum();
        desc.contact_enabled = false;
        assert!(candidate_pairs(&desc, &parents(&desc), &geoms(&desc)).unwrap().is_empty());
    }

    #[test]
    fn explicit_pair_naming_an_unknown_geom_is_a_model_error() {
        let mut desc = ModelDesc::example_pendulum();
        desc.pair_geom = vec![[0, 7]];
        desc.pair_margin = vec![0.0];
        assert!(candidate_pairs(&desc, &parents(&desc), &geoms(&desc)).is_err());
    }
}
