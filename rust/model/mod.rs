//! The validated robot: a [`ModelDesc`] checked once and turned into the flat, derived arrays
//! the hot paths index into (joint frames, shapes, candidate pairs, broad-phase spheres).
//!
//! The folder holds the robot as the labeller sees it, below collision: the description
//! ([`desc`]), the geoms on their bodies ([`geom`]), the candidate pairs ([`pairs`]) and their
//! broad-phase spheres (`broad`, `sphere_pairs`), derived once here, forward kinematics
//! ([`kinematics`], with `trig` and `lanes`), and the straight motions the model has proven
//! (`proven`, written by the planning layer).

pub(crate) mod broad;
pub mod desc;
pub mod geom;
pub mod kinematics;
pub(crate) mod lanes;
pub mod pairs;
pub(crate) mod proven;
mod sphere_pairs;
mod trig;

use nalgebra::{Isometry3, Point3, Translation3, Unit, UnitQuaternion, Vector3};

use std::collections::HashMap;
use std::sync::Arc;

use crate::error::{invalid_input, invalid_model, Result};
use crate::geometry::cloud::Cloud;
use crate::geometry::shapes::{GeomShape, GeomType};
use crate::joints::couplings::{feasible, Couplings};
use crate::model::broad::Broad;
/// (Also reachable here, where it lived before `model/desc.rs`.)
pub use crate::model::desc::ModelDesc;
use crate::model::desc::{JOINT_HINGE, JOINT_SLIDE};
use crate::model::geom::Geom;
use crate::model::pairs::{candidate_pairs, CandidatePair};

/// One joint, ready for forward kinematics.
#[derive(Clone, Debug)]
pub struct Joint {
    pub hinge: bool,
    pub body: usize,
    pub anchor: Vector3<f64>,
    pub axis: Unit<Vector3<f64>>,
    pub qpos0: f64,
}

/// How fast each candidate pair's distance can change per joint (`planning::motion::Levers`,
/// which builds and reads it): plain data, computed once per model.
#[derive(Debug, Default)]
pub(crate) struct LeverTable {
    /// Pair-major `(npairs, K)`: the pair's lever per joint (0 off its chain).
    pub rows: Vec<f64>,
    /// `npairs + 1` offsets, then every pair's chain entries.
    pub chains: Vec<u32>,
    /// Per pair, the geom whose branch from the world is its whole chain, or `u32::MAX`.
    pub solo: Vec<u32>,
    /// Per pair, how many of its chain's entries lie on each geom's side: each side is the
    /// last that many entries of its geom's branch (`branches`).
    pub sides: Vec<[u32; 2]>,
    /// `ngeom + 1` offsets, then each geom's branch: the chain entries of every joint from the
    /// world down to the geom's body, top down.
    pub branches: Vec<u32>,
    /// Geom-major `(ngeom, K)`: each branch joint's lever to the geom (NaN off its branch).
    pub reach: Vec<f64>,
    /// Geom-major `(ngeom, K)`: each branch joint's lever to the geom's bounding-sphere centre
    /// (its `reach` without the sphere's radius; NaN off its branch).
    pub centre: Vec<f64>,
    /// Per geom, the first geom on its body (the same branch: `motion::side_sum` sums a body's
    /// terms once per state, for every geom on it).
    pub twin: Vec<u32>,
}

/// A validated robot: flat arrays of bodies, joints, geoms and candidate pairs.
#[derive(Debug)]
pub struct RobotModel {
    pub(crate) body_parent: Vec<usize>,
    pub(crate) body_local: Vec<Isometry3<f64>>,
    /// Joints of body `b` are `joints[body_joints[b].0 .. body_joints[b].1]`.
    pub(crate) body_joints: Vec<(usize, usize)>,
    pub(crate) joints: Vec<Joint>,
    pub(crate) limits: Vec<[f64; 2]>,
    pub(crate) limited: Vec<bool>,
    /// The joint equalities, in dependency order.
    pub(crate) couplings: Couplings,
    pub(crate) geoms: Vec<Geom>,
    pub(crate) pairs: Vec<CandidatePair>,
    /// Bounding spheres by body pair and by pair, for the per-pose broad phase.
    pub(crate) broad: Broad,
    /// The pairs the booleans-only fast path tries first, likeliest first, and the seeded
    /// sample they were drawn from: on first use by `collision/fastpath.rs` (a heuristic: no
    /// answer depends on it).
    pub(crate) likely: std::sync::OnceLock<Likely>,
    /// The levers of `motion::Levers` (`LeverTable`), on first use.
    pub(crate) lever_rows: std::sync::OnceLock<LeverTable>,
    /// Per candidate pair whose distance one joint alone changes: that joint and the spans of
    /// its values over which the pair is proven clear (`planning/spans.rs`); `u32::MAX` and none for
    /// the other pairs. On first use by `planning/motion.rs`.
    pub(crate) joint_spans: std::sync::OnceLock<Vec<PairSpans>>,
    /// Per candidate pair: a box of one or two joints' values over which the pair is proven
    /// clear (a one-joint pair's widest of `joint_spans`, or a two-joint pair's whole sampling
    /// box; `Apart::NONE` for the others), so that labelling, the fast paths and motion
    /// certificates skip the pair in any pose (or motion) inside it (`Apart::holds`). Set by
    /// `motion::prove_apart`; unset, nothing is skipped.
    pub(crate) apart: std::sync::OnceLock<Vec<Apart>>,
    /// The broad phase's four-pose lists without the pairs `apart` proves clear over the whole
    /// sampling box, and that box: for four poses inside it (`collide::Scratch4`). Set with
    /// `apart`, where the sampling box exists.
    pub(crate) pruned4: std::sync::OnceLock<Pruned4>,
    /// For a model rebuilt from another (`RobotModel::rebuilt`): the proofs of `joint_spans` and
    /// `apart` that model had made, for the pairs both models share, so that an edit of the
    /// world proves only its own pairs again.
    pub(crate) inherited: Option<Inherited>,
    /// Straight motions this model has proven free, written down by the calls that proved them
    /// (`proven::ProvenLines`): a timed path's parts on a planned path's segments are not proven
    /// twice.
    pub(crate) proven_lines: proven::ProvenLines,
    /// This model among those built in the process (never 0, never reused): the model spare
    /// certificate buffers are kept for (`motion::Spare`).
    pub(crate) id: u64,
}

/// The next `RobotModel::id`.
static NEXT_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// The fast path's likely pairs (`RobotModel::likely`) and what they were drawn from: which
/// pairs are in contact in each pose of a seeded sample (`collision/fastpath.rs`).
#[derive(Debug, Default)]
pub(crate) struct Likely {
    /// The pairs, likeliest first.
    pub order: Vec<u32>,
    /// Poses of the sample (the first `n` of the seeded sequence).
    pub n: usize,
    /// Per candidate pair, the sample poses it is in contact in.
    pub contacts: Vec<Vec<u32>>,
    /// The sample poses the narrow phase could not decide, each with the pair it stopped at
    /// (left out of the cover, their other contacts unknown).
    pub undecided: Vec<(u32, u32)>,
}

/// What a rebuilt model takes over of the old model's sample (`Likely`): per pair, the old
/// contacts of the same pair (None: a pair to test again), and the old sample's undecided
/// poses, each with the same pair in this model (None: a pair this model lacks, so the pose's
/// other contacts must be found again).
#[derive(Debug)]
pub(crate) struct InheritedLikely {
    pub n: usize,
    pub contacts: Vec<Option<Vec<u32>>>,
    pub undecided: Vec<(u32, Option<u32>)>,
}

/// A pair's joint and its spans of `planning/spans.rs` (`u32::MAX` and none: not one joint's pair).
pub(crate) type PairSpans = (u32, Vec<[f64; 2]>);

/// A geom or pair with nothing to inherit.
const NOT_INHERITED: usize = usize::MAX;

/// What a rebuilt model takes over from the model it was rebuilt from (`RobotModel::inherited`):
/// per pair of the new model, the old model's `joint_spans` and `apart` entries of the same
/// pair, or None (proved again on first use), and of its likely pairs' sample, the same pairs'
/// contacts (`InheritedLikely`). Where the old model had made none of them, None.
///
/// Exactness: a pair is the same when both its geoms share their shapes (the same bits,
/// `shape_key`), it joins the same two old geoms in the same order with the same margin, kind
/// and explicitness, and the bodies, joints, their ranges and couplings are the same in both
/// descriptions. A pair's spans and box (`planning/spans.rs`, `motion::prove_apart`) are
/// functions of that pair, its bodies' chain and the joints' ranges alone, so the entries taken
/// over are those the new model would prove (tested: byte-identical labels and proofs). So are
/// its contacts in the sample poses, drawn from the same joints' ranges with the same seed.
#[derive(Debug)]
pub(crate) struct Inherited {
    pub(crate) spans: Option<Vec<Option<PairSpans>>>,
    pub(crate) apart: Option<Vec<Option<Apart>>>,
    pub(crate) likely: Option<InheritedLikely>,
}

impl Inherited {
    fn of(model: &RobotModel, old: &ModelDesc, desc: &ModelDesc, geom_from: &[usize], pairs: &[CandidatePair]) -> Option<Self> {
        let same_kinematics = old.same_kinematics(desc);
        let (spans, apart, likely) = (model.joint_spans.get(), model.apart.get(), model.likely.get());
        if !same_kinematics || (spans.is_none() && apart.is_none() && likely.is_none()) {
            return None;
        }
        let index: HashMap<(usize, usize), usize> = model.pairs.iter().enumerate().map(|(q, p)| ((p.g1, p.g2), q)).collect();
        let same = |q: usize, p: &CandidatePair| {
            let o = &model.pairs[q];
            o.margin.to_bits() == p.margin.to_bits() && o.kind == p.kind && o.explicit == p.explicit
        };
        let old_geom = |g: usize| geom_from.get(g).copied().filter(|&o| o != NOT_INHERITED);
        let from: Vec<usize> = pairs
            .iter()
            .map(|p| match (old_geom(p.g1), old_geom(p.g2)) {
                (Some(a), Some(b)) => index.get(&(a, b)).copied().filter(|&q| same(q, p)).unwrap_or(NOT_INHERITED),
                _ => NOT_INHERITED,
            })
            .collect();
        let take = |q: usize| (q != NOT_INHERITED).then_some(q);
        // (a model without a sample, no sampling box, has no contacts to give)
        let likely = likely.filter(|l| l.contacts.len() == model.pairs.len()).map(|l| {
            let mut to_new = vec![None; model.pairs.len()];
            for (p, &q) in from.iter().enumerate() {
                if let Some(q) = take(q) {
                    to_new[q] = Some(p as u32);
                }
            }
            InheritedLikely {
                n: l.n,
                contacts: from.iter().map(|&q| take(q).map(|q| l.contacts[q].clone())).collect(),
                undecided: l.undecided.iter().map(|&(i, q)| (i, to_new[q as usize])).collect(),
            }
        });
        Some(Self {
            spans: spans.map(|s| from.iter().map(|&q| take(q).map(|q| s[q].clone())).collect()),
            apart: apart.map(|a| from.iter().map(|&q| take(q).map(|q| a[q])).collect()),
            likely,
        })
    }

    /// Pair `p`'s spans, when taken over.
    pub(crate) fn spans(&self, p: usize) -> Option<&PairSpans> {
        self.spans.as_ref()?.get(p)?.as_ref()
    }

    /// Pair `p`'s box, when taken over.
    pub(crate) fn apart(&self, p: usize) -> Option<Apart> {
        *self.apart.as_ref()?.get(p)?
    }
}

/// `RobotModel::pruned4`.
#[derive(Debug)]
pub(crate) struct Pruned4 {
    pub lists: crate::model::broad::Lists4,
    /// Per joint, the sampling range (`RobotModel::sampling_ranges`).
    pub ranges: Vec<[f64; 2]>,
}

impl Pruned4 {
    /// Whether pose `q` (length K) lies inside the sampling box.
    #[inline]
    pub(crate) fn inside(&self, q: &[f64]) -> bool {
        q.iter().zip(&self.ranges).all(|(&v, r)| r[0] <= v && v <= r[1])
    }
}

/// A candidate pair proven clear while `lo[i] <= q[joints[i]] <= hi[i]` for both entries
/// (`RobotModel::apart`); an entry with joint `u32::MAX` holds for every pose (a pair one joint
/// alone moves uses one entry, and so does a longer chain's pair proven by its swept ball, over
/// its first joint).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Apart {
    pub joints: [u32; 2],
    pub lo: [f64; 2],
    pub hi: [f64; 2],
}

impl Apart {
    /// For a pair with no proof.
    pub(crate) const NONE: Apart = Apart { joints: [u32::MAX; 2], lo: [f64::NAN; 2], hi: [f64::NAN; 2] };

    /// Whether this proves anything.
    #[inline]
    pub(crate) fn some(&self) -> bool {
        self.joints[0] != u32::MAX
    }

    /// Whether pose `q` (length K) is inside the proven box: the pair is then clear in it.
    #[inline]
    pub(crate) fn holds(&self, q: &[f64]) -> bool {
        self.covers(q, q)
    }

    /// Whether the box holds every pose with each joint `j` in `[lo[j], hi[j]]` (a motion's
    /// sweep, `motion::certify_motion`).
    #[inline]
    pub(crate) fn covers(&self, lo: &[f64], hi: &[f64]) -> bool {
        // (NONE's joints are never read: its comparisons with NaN fail first)
        let inside = |i: usize| {
            let j = self.joints[i];
            j == u32::MAX || (self.lo[i] <= lo[j as usize] && hi[j as usize] <= self.hi[i])
        };
        self.lo[0] <= self.hi[0] && inside(0) && inside(1)
    }
}

fn check_len(name: &str, got: usize, want: usize) -> Result<()> {
    if got != want {
        return invalid_model(format!("{name} has {got} entries, expected {want}"));
    }
    Ok(())
}

fn finite(name: &str, values: &[f64]) -> Result<()> {
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return invalid_model(format!("{name} holds a non-finite value at flat index {i}"));
    }
    Ok(())
}

fn quat(q: [f64; 4]) -> Result<UnitQuaternion<f64>> {
    let q = nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]);
    let norm = q.norm();
    if norm.is_nan() || norm <= 1e-12 {
        return invalid_model("zero quaternion");
    }
    Ok(UnitQuaternion::from_quaternion(q))
}

fn iso(pos: [f64; 3], q: [f64; 4]) -> Result<Isometry3<f64>> {
    Ok(Isometry3::from_parts(Translation3::new(pos[0], pos[1], pos[2]), quat(q)?))
}

/// MuJoCo's `mjGEOM_MESH`.
const MJGEOM_MESH: i32 = 7;

/// What builds geom `g`'s shape and frame in `desc`, bit for bit: its type, body, frame and
/// size, and a mesh's vertices (None for a mesh index out of range: built, and refused, as new).
fn shape_key(desc: &ModelDesc, g: usize) -> Option<Vec<u64>> {
    let mut key = vec![desc.geom_type[g] as u64, desc.geom_body[g] as u64];
    let floats = desc.geom_pos.get(g)?.iter().chain(desc.geom_quat.get(g)?).chain(desc.geom_size.get(g)?);
    key.extend(floats.map(|v| v.to_bits()));
    if desc.geom_type[g] == MJGEOM_MESH {
        let m = usize::try_from(*desc.geom_mesh.get(g)?).ok()?;
        let adr = *desc.mesh_vert_adr.get(m)? as usize;
        let num = *desc.mesh_vert_num.get(m)? as usize;
        key.extend(desc.mesh_vert.get(adr..adr + num)?.iter().flatten().map(|v| v.to_bits()));
    }
    Some(key)
}

impl RobotModel {
    /// Validates `desc` and derives everything the labeller needs (shapes, candidate pairs).
    ///
    /// A point cloud (`desc.cloud`) becomes one more geom, after the MuJoCo geoms: on the world
    /// body, MuJoCo id -1, its balls in the world frame (`geometry/cloud.rs`); an empty cloud adds nothing.
    pub fn new(desc: ModelDesc) -> Result<Self> {
        Self::build(desc, None)
    }

    /// The model of `desc`, a scene edited from `old`, the description this model was built
    /// from (obstacles added, removed or replaced, another point cloud). A geom whose entries in
    /// `desc` (type, body, frame, size, margin aside; a mesh's vertices) are bit for bit those of
    /// a geom of `old` shares that geom's shape (its hull and inner balls) instead of building it
    /// again, so an edit of the world costs its own geoms, the candidate pairs and the broad phase
    /// (`Robot.with_obstacles`: milliseconds where building a Panda's hulls takes ten).
    ///
    /// Exactness: a shared shape is the one `GeomShape::new` builds from the same bits, so the
    /// result labels as `RobotModel::new(desc)` would, byte for byte (tested).
    pub fn rebuilt(&self, old: &ModelDesc, desc: ModelDesc) -> Result<Self> {
        Self::build(desc, Some((self, old)))
    }

    fn build(mut desc: ModelDesc, reuse: Option<(&RobotModel, &ModelDesc)>) -> Result<Self> {
        let nbody = desc.body_parent.len();
        if nbody == 0 {
            return invalid_model("no bodies (body 0 must be the world)");
        }
        check_len("body_weld", desc.body_weld.len(), nbody)?;
        check_len("body_pos", desc.body_pos.len(), nbody)?;
        check_len("body_quat", desc.body_quat.len(), nbody)?;
        finite("body_pos", desc.body_pos.as_flattened())?;
        finite("body_quat", desc.body_quat.as_flattened())?;
        let mut body_parent = Vec::with_capacity(nbody);
        for (b, &p) in desc.body_parent.iter().enumerate() {
            let ok = if b == 0 { p == 0 } else { p >= 0 && (p as usize) < b };
            if !ok {
                return invalid_model(format!("body {b} has parent {p}; parents must precede children"));
            }
            body_parent.push(p as usize);
        }
        for (b, &w) in desc.body_weld.iter().enumerate() {
            if w < 0 || w as usize > b {
                return invalid_model(format!("body {b} has weld id {w}"));
            }
        }
        let body_local = (0..nbody).map(|b| iso(desc.body_pos[b], desc.body_quat[b])).collect::<Result<Vec<_>>>()?;

        // Joints.
        let njnt = desc.jnt_type.len();
        check_len("jnt_body", desc.jnt_body.len(), njnt)?;
        check_len("jnt_pos", desc.jnt_pos.len(), njnt)?;
        check_len("jnt_axis", desc.jnt_axis.len(), njnt)?;
        check_len("jnt_qpos0", desc.jnt_qpos0.len(), njnt)?;
        check_len("jnt_range", desc.jnt_range.len(), njnt)?;
        check_len("jnt_limited", desc.jnt_limited.len(), njnt)?;
        finite("jnt_pos", desc.jnt_pos.as_flattened())?;
        finite("jnt_axis", desc.jnt_axis.as_flattened())?;
        finite("jnt_qpos0", &desc.jnt_qpos0)?;
        let mut joints = Vec::with_capacity(njnt);
        // Bodies without joints keep the empty range (0, 0).
        let mut body_joints = vec![(0usize, 0usize); nbody];
        let mut last_body = 0usize;
        for j in 0..njnt {
            let hinge = match desc.jnt_type[j] {
                JOINT_HINGE => true,
                JOINT_SLIDE => false,
                0 => return invalid_model(format!("joint {j} is a free joint; only hinge and slide joints are supported")),
                1 => return invalid_model(format!("joint {j} is a ball joint; only hinge and slide joints are supported")),
                t => return invalid_model(format!("joint {j} has unknown type {t}")),
            };
            let b = desc.jnt_body[j];
            if b <= 0 || b as usize >= nbody {
                return invalid_model(format!("joint {j} sits on body {b}"));
            }
            let b = b as usize;
            if b < last_body {
                return invalid_model("joints are not grouped by body in body order");
            }
            if b != last_body {
                body_joints[b].0 = j;
            }
            body_joints[b].1 = j + 1;
            last_body = b;
            let a = Vector3::from(desc.jnt_axis[j]);
            let norm = a.norm();
            if norm.is_nan() || norm <= 1e-12 {
                return invalid_model(format!("joint {j} has a zero axis"));
            }
            let [lo, hi] = desc.jnt_range[j];
            if desc.jnt_limited[j] && !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                return invalid_model(format!("joint {j} has an invalid range [{lo}, {hi}]"));
            }
            joints.push(Joint {
                hinge,
                body: b,
                anchor: Vector3::from(desc.jnt_pos[j]),
                axis: Unit::new_normalize(a),
                qpos0: desc.jnt_qpos0[j],
            });
        }
        // Which bodies belong to the robot: those whose root (child of the world) carries a
        // joint somewhere in its subtree. Everything else is static scene.
        let root_of: Vec<usize> = {
            let mut r = vec![0usize; nbody];
            for b in 1..nbody {
                r[b] = if body_parent[b] == 0 { b } else { r[body_parent[b]] };
            }
            r
        };
        if !desc.jnt_scene.is_empty() {
            check_len("jnt_scene", desc.jnt_scene.len(), njnt)?;
        }
        let mut root_moves = vec![false; nbody];
        for (j, jnt) in joints.iter().enumerate() {
            // scene joints move obstacles, not the robot
            if !desc.jnt_scene.get(j).copied().unwrap_or(false) {
                root_moves[root_of[jnt.body]] = true;
            }
        }
        let on_robot = |b: usize| b != 0 && root_moves[root_of[b]];

        // Geoms.
        let ngeom = desc.geom_type.len();
        check_len("geom_id", desc.geom_id.len(), ngeom)?;
        check_len("geom_body", desc.geom_body.len(), ngeom)?;
        check_len("geom_pos", desc.geom_pos.len(), ngeom)?;
        check_len("geom_quat", desc.geom_quat.len(), ngeom)?;
        check_len("geom_size", desc.geom_size.len(), ngeom)?;
        check_len("geom_contype", desc.geom_contype.len(), ngeom)?;
        check_len("geom_conaffinity", desc.geom_conaffinity.len(), ngeom)?;
        check_len("geom_margin", desc.geom_margin.len(), ngeom)?;
        check_len("geom_mesh", desc.geom_mesh.len(), ngeom)?;
        check_len("mesh_vert_num", desc.mesh_vert_num.len(), desc.mesh_vert_adr.len())?;
        finite("geom_pos", desc.geom_pos.as_flattened())?;
        finite("geom_quat", desc.geom_quat.as_flattened())?;
        finite("geom_size", desc.geom_size.as_flattened())?;
        finite("geom_margin", &desc.geom_margin)?;
        finite("mesh_vert", desc.mesh_vert.as_flattened())?;
        let mut geoms = Vec::with_capacity(ngeom + 1);
        // per geom: the old model's geom whose shape it shares (`NOT_INHERITED` for none)
        let mut geom_from = Vec::with_capacity(ngeom + 1);
        // The old model's geoms by what builds their shapes (its MuJoCo geoms come first, in
        // `old`'s order; its cloud, if any, after them).
        let shared: HashMap<Vec<u64>, usize> = match reuse {
            Some((model, old)) if model.geoms.iter().filter(|g| g.mujoco_id >= 0).count() == old.geom_type.len() => {
                (0..old.geom_type.len()).filter_map(|g| Some((shape_key(old, g)?, g))).collect()
            }
            _ => HashMap::new(),
        };
        for g in 0..ngeom {
            let b = desc.geom_body[g];
            if b < 0 || b as usize >= nbody {
                return invalid_model(format!("geom {} sits on body {b}", desc.geom_id[g]));
            }
            if let (Some((model, _)), Some(&o)) = (reuse, shape_key(&desc, g).and_then(|k| shared.get(&k))) {
                geom_from.push(o);
                let o = &model.geoms[o];
                geoms.push(Geom {
                    mujoco_id: desc.geom_id[g],
                    body: o.body,
                    local: o.local,
                    shape: Arc::clone(&o.shape),
                    on_robot: on_robot(b as usize),
                });
                continue;
            }
            let gtype = GeomType::from_mujoco(desc.geom_type[g], desc.geom_id[g])?;
            let hull_points: Vec<Point3<f64>> = if gtype == GeomType::Mesh {
                let m = desc.geom_mesh[g];
                if m < 0 || m as usize >= desc.mesh_vert_adr.len() {
                    return invalid_model(format!("mesh geom {} names mesh {m}", desc.geom_id[g]));
                }
                let adr = desc.mesh_vert_adr[m as usize] as usize;
                let num = desc.mesh_vert_num[m as usize] as usize;
                let Some(verts) = desc.mesh_vert.get(adr..adr + num) else {
                    return invalid_model(format!("mesh {m} vertex range {adr}..{} is out of bounds", adr + num));
                };
                verts.iter().map(|v| Point3::from(*v)).collect()
            } else {
                Vec::new()
            };
            let (shape, axis_fix) = GeomShape::new(gtype, desc.geom_size[g], &hull_points, desc.geom_id[g])?;
            geom_from.push(NOT_INHERITED);
            geoms.push(Geom {
                mujoco_id: desc.geom_id[g],
                body: b as usize,
                local: iso(desc.geom_pos[g], desc.geom_quat[g])? * axis_fix,
                shape: Arc::new(shape),
                on_robot: on_robot(b as usize),
            });
        }
        if let Some(cloud) = desc.cloud.take() {
            if !cloud.margin.is_finite() {
                return invalid_model(format!("the point cloud's margin is {}", cloud.margin));
            }
            let built = Arc::new(Cloud::new(&cloud.points, &cloud.radius)?);
            if let Some(shape) = GeomShape::cloud(built) {
                // One more geom for `candidate_pairs`' filters: on the world, MuJoCo id -1.
                desc.geom_id.push(-1);
                desc.geom_body.push(0);
                desc.geom_contype.push(cloud.contype);
                desc.geom_conaffinity.push(cloud.conaffinity);
                desc.geom_margin.push(cloud.margin);
                geoms.push(Geom { mujoco_id: -1, body: 0, local: Isometry3::identity(), shape: Arc::new(shape), on_robot: false });
            }
        }
        if desc.pair_margin.len() != desc.pair_geom.len() {
            return invalid_model("pair_margin and pair_geom differ in length");
        }
        let couplings = Couplings::new(&desc.couplings, njnt)?;
        let pairs = candidate_pairs(&desc, &body_parent, &geoms)?;
        let broad = Broad::new(nbody, &geoms, &pairs);
        let inherited = reuse.and_then(|(model, old)| Inherited::of(model, old, &desc, &geom_from, &pairs));
        Ok(Self {
            body_parent,
            body_local,
            body_joints,
            joints,
            limits: desc.jnt_range.clone(),
            limited: desc.jnt_limited.clone(),
            couplings,
            geoms,
            pairs,
            broad,
            likely: std::sync::OnceLock::new(),
            lever_rows: std::sync::OnceLock::new(),
            joint_spans: std::sync::OnceLock::new(),
            apart: std::sync::OnceLock::new(),
            pruned4: std::sync::OnceLock::new(),
            inherited,
            proven_lines: Default::default(),
            id: NEXT_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        })
    }

    /// The pairs' spans of `motion::prove_apart`, once it has run (else None: no pair is
    /// skipped).
    #[inline]
    pub(crate) fn apart(&self) -> Option<&[Apart]> {
        self.apart.get().map(Vec::as_slice)
    }

    /// Number of joints, i.e. the length K of a pose vector.
    pub fn njoint(&self) -> usize {
        self.joints.len()
    }

    /// Number of bodies, the world included.
    pub fn nbody(&self) -> usize {
        self.body_parent.len()
    }

    /// The collidable geoms in `ModelDesc` order.
    pub fn geoms(&self) -> &[Geom] {
        &self.geoms
    }

    /// The geom pairs every pose is tested on (after MuJoCo's filters).
    pub fn pairs(&self) -> &[CandidatePair] {
        &self.pairs
    }

    /// Joint ranges `(K, 2)`; unlimited hinges report `[-pi, pi]` (one full turn).
    pub fn sampling_ranges(&self) -> Result<Vec<[f64; 2]>> {
        self.joints
            .iter()
            .enumerate()
            .map(|(j, jnt)| {
                if self.limited[j] {
                    Ok(self.limits[j])
                } else if jnt.hinge {
                    Ok([-std::f64::consts::PI, std::f64::consts::PI])
                } else {
                    invalid_model(format!("slide joint {j} is unlimited: no range to sample from"))
                }
            })
            .collect()
    }

    /// The joint equalities (`joints/couplings.rs`).
    pub fn couplings(&self) -> &Couplings {
        &self.couplings
    }

    /// Whether pose `q` (K,) is one the mechanism can take: within the limits and on the
    /// couplings, to `couplings::FEASIBLE_TOL`.
    pub fn feasible(&self, q: &[f64]) -> bool {
        feasible(q, &self.limits, &self.limited, &self.couplings)
    }

    /// Whether each joint is a continuous (unlimited) hinge, which wraps around.
    pub fn continuous(&self) -> Vec<bool> {
        self.joints.iter().zip(&self.limited).map(|(j, &l)| j.hinge && !l).collect()
    }

    /// Checks that `poses` is a non-empty, finite `(B, K)` row-major buffer for this model;
    /// returns B.
    pub fn check_poses(&self, poses: &[f64]) -> Result<usize> {
        let k = self.njoint();
        if k == 0 {
            return invalid_input("the model has no joints");
        }
        if poses.is_empty() || poses.len() % k != 0 {
            return invalid_input(format!("poses must be a non-empty (B, {k}) array; got {} values", poses.len()));
        }
        // (64 entries at a time without an early exit, which vectorises; then the entry)
        if let Some(c) = poses.chunks(64).position(|c| c.iter().fold(false, |bad, v| bad | !v.is_finite())) {
            let i = 64 * c + poses[64 * c..].iter().position(|v| !v.is_finite()).expect("the chunk holds one");
            return invalid_input(format!("pose {} joint {} is not finite ({})", i / k, i % k, poses[i]));
        }
        Ok(poses.len() / k)
    }
}
