//! A robot scene as plain data: the flat arrays Python copies out of MuJoCo's compiled
//! `mjModel`. Nothing here is validated; [`crate::RobotModel::new`] does that once.
//!
//! `ModelDesc` derives serde: the benches read it from JSON, and the Python `RobotModel`
//! pickles it (`bindings/model.rs`).

use serde::{Deserialize, Serialize};

use crate::error::{invalid_input, Result};
use crate::joints::couplings::Coupling;

/// MuJoCo's `mjtJoint` codes for the joints we accept.
pub const JOINT_SLIDE: i32 = 2;
pub const JOINT_HINGE: i32 = 3;

/// A robot scene exactly as MuJoCo compiled it, in flat arrays.
///
/// Body 0 is the world; bodies are ordered parents first (MuJoCo guarantees it). Quaternions
/// are `(w, x, y, z)`. Only *collidable* geoms are listed (those with a non-zero contype or
/// conaffinity, or named by an explicit pair); `geom_id` keeps their MuJoCo ids so that
/// pairs and reports speak MuJoCo's language.
///
/// # Example
/// A single hinge that swings a unit sphere above a floor plane:
/// ```
/// use profrobot::{ModelDesc, RobotModel};
/// let desc = ModelDesc::example_pendulum();
/// let model = RobotModel::new(desc).unwrap();
/// assert_eq!(model.njoint(), 1);
/// assert_eq!(model.pairs().len(), 1); // the bob against the floor
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModelDesc {
    pub body_parent: Vec<i32>,
    pub body_weld: Vec<i32>,
    pub body_pos: Vec<[f64; 3]>,
    pub body_quat: Vec<[f64; 4]>,

    pub jnt_type: Vec<i32>,
    pub jnt_body: Vec<i32>,
    pub jnt_pos: Vec<[f64; 3]>,
    pub jnt_axis: Vec<[f64; 3]>,
    pub jnt_qpos0: Vec<f64>,
    pub jnt_range: Vec<[f64; 2]>,
    pub jnt_limited: Vec<bool>,

    pub geom_id: Vec<i32>,
    pub geom_type: Vec<i32>,
    pub geom_body: Vec<i32>,
    pub geom_pos: Vec<[f64; 3]>,
    pub geom_quat: Vec<[f64; 4]>,
    pub geom_size: Vec<[f64; 3]>,
    pub geom_contype: Vec<u32>,
    pub geom_conaffinity: Vec<u32>,
    pub geom_margin: Vec<f64>,
    /// Index into `mesh_vert_adr`/`mesh_vert_num` for mesh geoms, -1 otherwise.
    pub geom_mesh: Vec<i32>,

    /// Convex-hull vertices of each mesh, in the mesh frame MuJoCo compiled.
    pub mesh_vert_adr: Vec<u32>,
    pub mesh_vert_num: Vec<u32>,
    pub mesh_vert: Vec<[f64; 3]>,

    /// `<exclude>` body pairs (MuJoCo body ids).
    pub exclude: Vec<[i32; 2]>,
    /// Explicit `<pair>` geom pairs (MuJoCo geom ids) and their margins.
    pub pair_geom: Vec<[i32; 2]>,
    pub pair_margin: Vec<f64>,

    /// `!mjDSBL_FILTERPARENT`.
    pub filter_parent: bool,
    /// `!mjDSBL_CONTACT && !mjDSBL_CONSTRAINT`.
    pub contact_enabled: bool,

    /// Per joint: whether it is a *scene joint* (it moves an obstacle of a family of scenes, not
    /// the robot); empty means none. Bodies moved by scene joints only are scene, not robot, so
    /// robot–obstacle contacts count as scene contacts. Stored after the fields above (format 2).
    #[serde(skip)]
    pub jnt_scene: Vec<bool>,

    /// Joint equalities (`joints/couplings.rs`), MuJoCo's active `<equality><joint>`s; empty means
    /// none. Stored after `jnt_scene` (format 3).
    #[serde(skip)]
    pub couplings: Vec<Coupling>,

    /// A point cloud fixed to the world (`geometry/cloud.rs`), or none. Stored after `couplings`
    /// (format 4).
    #[serde(skip)]
    pub cloud: Option<CloudDesc>,
}

/// A point cloud as plain data: balls fixed in the world frame, one static obstacle geom with
/// MuJoCo's contact filter and margin (the cross-check places the same balls as sphere geoms
/// with these values).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CloudDesc {
    /// Ball centres, metres, world frame.
    pub points: Vec<[f64; 3]>,
    /// Ball radii, metres (one per point).
    pub radius: Vec<f64>,
    /// The geom margin of every ball (metres): a pair is in contact below its geom margins' sum.
    pub margin: f64,
    pub contype: u32,
    pub conaffinity: u32,
}

/// Leads every [`ModelDesc::to_bytes`] buffer: names the format and its version.
const MAGIC: &[u8; 8] = b"PRDESC04";
/// Format 3: the same without `cloud` (read as "none").
const MAGIC_V3: &[u8; 8] = b"PRDESC03";
/// Format 2: the same without `couplings` (read as "none").
const MAGIC_V2: &[u8; 8] = b"PRDESC02";
/// Format 1: the same without `jnt_scene` either (read as "no scene joints").
const MAGIC_V1: &[u8; 8] = b"PRDESC01";

/// FNV-1a, 64 bits: catches corrupted bytes in a stored description (not an adversary).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

impl ModelDesc {
    /// Whether `other` has this description's bodies, joints, ranges and couplings, bit for bit:
    /// the kinematics a pair's proofs of clearance depend on (`RobotModel::rebuilt` takes them
    /// over only then).
    pub fn same_kinematics(&self, other: &ModelDesc) -> bool {
        self.body_parent == other.body_parent
            && self.body_weld == other.body_weld
            && self.body_pos == other.body_pos
            && self.body_quat == other.body_quat
            && self.jnt_type == other.jnt_type
            && self.jnt_body == other.jnt_body
            && self.jnt_pos == other.jnt_pos
            && self.jnt_axis == other.jnt_axis
            && self.jnt_qpos0 == other.jnt_qpos0
            && self.jnt_range == other.jnt_range
            && self.jnt_limited == other.jnt_limited
            && self.jnt_scene == other.jnt_scene
            && self.couplings == other.couplings
    }

    /// The description as bytes: a magic tag, a checksum, then postcard (every `f64` as its
    /// 8 bytes, so the round trip is exact, NaN and infinities included). The Python
    /// `RobotModel` pickles this.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut body = postcard::to_allocvec(self).expect("serialising plain vectors into memory cannot fail");
        body.extend(postcard::to_allocvec(&self.jnt_scene).expect("serialising plain vectors into memory cannot fail"));
        body.extend(postcard::to_allocvec(&self.couplings).expect("serialising plain vectors into memory cannot fail"));
        body.extend(postcard::to_allocvec(&self.cloud).expect("serialising plain vectors into memory cannot fail"));
        let mut out = Vec::with_capacity(16 + body.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&fnv1a(&body).to_le_bytes());
        out.extend_from_slice(&body);
        out
    }

    /// Reads what [`ModelDesc::to_bytes`] wrote; anything else (truncated, altered, another
    /// format or version) is an `InvalidInput` error, never a panic.
    ///
    /// # Example
    /// ```
    /// use profrobot::ModelDesc;
    /// let desc = ModelDesc::example_pendulum();
    /// let bytes = desc.to_bytes();
    /// assert_eq!(ModelDesc::from_bytes(&bytes).unwrap(), desc);
    /// assert!(ModelDesc::from_bytes(&bytes[..bytes.len() - 1]).is_err());
    /// ```
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        const WHAT: &str = "not a profrobot model description";
        let Some((magic, rest)) = bytes.split_first_chunk::<8>() else {
            return invalid_input(format!("{WHAT}: {} bytes is too short", bytes.len()));
        };
        if magic != MAGIC && magic != MAGIC_V3 && magic != MAGIC_V2 && magic != MAGIC_V1 {
            return invalid_input(format!("{WHAT} (expected it to start with {:?})", String::from_utf8_lossy(MAGIC)));
        }
        let Some((sum, body)) = rest.split_first_chunk::<8>() else {
            return invalid_input(format!("{WHAT}: truncated after its tag"));
        };
        if u64::from_le_bytes(*sum) != fnv1a(body) {
            return invalid_input("corrupt model description: its checksum does not match (truncated or altered)");
        }
        let (mut desc, rest) = match postcard::take_from_bytes::<Self>(body) {
            Ok(ok) => ok,
            Err(e) => return invalid_input(format!("corrupt model description: {e}")),
        };
        let rest = if magic != MAGIC_V1 {
            match postcard::take_from_bytes::<Vec<bool>>(rest) {
                Ok((scene, rest)) => {
                    desc.jnt_scene = scene;
                    rest
                }
                Err(e) => return invalid_input(format!("corrupt model description: {e}")),
            }
        } else {
            rest
        };
        let rest = if magic == MAGIC || magic == MAGIC_V3 {
            match postcard::take_from_bytes::<Vec<Coupling>>(rest) {
                Ok((couplings, rest)) => {
                    desc.couplings = couplings;
                    rest
                }
                Err(e) => return invalid_input(format!("corrupt model description: {e}")),
            }
        } else {
            rest
        };
        let rest = if magic == MAGIC {
            match postcard::take_from_bytes::<Option<CloudDesc>>(rest) {
                Ok((cloud, rest)) => {
                    desc.cloud = cloud;
                    rest
                }
                Err(e) => return invalid_input(format!("corrupt model description: {e}")),
            }
        } else {
            rest
        };
        if !rest.is_empty() {
            return invalid_input(format!("corrupt model description: {} trailing bytes", rest.len()));
        }
        Ok(desc)
    }

    /// A one-joint pendulum: a sphere of radius 0.1 on a 0.5 m arm hinged about x at height 0.55,
    /// above a floor plane. At q = 0 the bob hangs 0.05 m above the floor; swinging it sideways
    /// lifts it. Used by doc tests and unit tests.
    pub fn example_pendulum() -> Self {
        ModelDesc {
            body_parent: vec![0, 0],
            body_weld: vec![0, 1],
            body_pos: vec![[0.0; 3], [0.0, 0.0, 0.55]],
            body_quat: vec![[1.0, 0.0, 0.0, 0.0]; 2],
            jnt_type: vec![JOINT_HINGE],
            jnt_body: vec![1],
            jnt_pos: vec![[0.0; 3]],
            jnt_axis: vec![[1.0, 0.0, 0.0]],
            jnt_qpos0: vec![0.0],
            jnt_range: vec![[-3.0, 3.0]],
            jnt_limited: vec![true],
            geom_id: vec![0, 1],
            geom_type: vec![0, 2],
            geom_body: vec![0, 1],
            geom_pos: vec![[0.0; 3], [0.0, 0.0, -0.4]],
            geom_quat: vec![[1.0, 0.0, 0.0, 0.0]; 2],
            geom_size: vec![[1.0, 1.0, 0.1], [0.1, 0.0, 0.0]],
            geom_contype: vec![1, 1],
            geom_conaffinity: vec![1, 1],
            geom_margin: vec![0.0, 0.0],
            geom_mesh: vec![-1, -1],
            mesh_vert_adr: vec![],
            mesh_vert_num: vec![],
            mesh_vert: vec![],
            exclude: vec![],
            pair_geom: vec![],
            pair_margin: vec![],
            filter_parent: true,
            contact_enabled: true,
            jnt_scene: vec![],
            couplings: vec![],
            cloud: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_round_trip_every_f64_exactly() {
        let mut desc = ModelDesc::example_pendulum();
        // Values a decimal format would round or refuse: unlimited ranges may hold anything.
        desc.jnt_range = vec![[f64::NEG_INFINITY, f64::from_bits(0x7ff8_dead_beef_0001)]];
        desc.body_pos[1] = [0.1 + 0.2, f64::MIN_POSITIVE / 3.0, -0.0];
        let mut back = ModelDesc::from_bytes(&desc.to_bytes()).unwrap();
        let bits =
            |d: &ModelDesc| d.jnt_range.as_flattened().iter().chain(d.body_pos.as_flattened()).map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&back), bits(&desc));
        (desc.jnt_range, back.jnt_range) = (vec![], vec![]); // (NaN != NaN)
        assert_eq!(back, desc);
    }

    #[test]
    fn scene_joints_round_trip_and_format_1_still_reads() {
        let mut desc = ModelDesc::example_pendulum();
        desc.jnt_scene = vec![true];
        assert_eq!(ModelDesc::from_bytes(&desc.to_bytes()).unwrap(), desc);
        // a description pickled before scene joints existed (format 1) reads as "none"
        let plain = ModelDesc::example_pendulum();
        let body = postcard::to_allocvec(&plain).unwrap();
        let mut v1 = MAGIC_V1.to_vec();
        v1.extend_from_slice(&fnv1a(&body).to_le_bytes());
        v1.extend_from_slice(&body);
        assert_eq!(ModelDesc::from_bytes(&v1).unwrap(), plain);
    }

    #[test]
    fn couplings_round_trip_and_format_2_reads_as_none() {
        let mut desc = ModelDesc::example_pendulum();
        desc.couplings = vec![Coupling { dep: 0, indep: -1, coef: [0.5, 0.0, 0.0, 0.0, 0.0], y0: 0.1, x0: 0.0 }];
        assert_eq!(ModelDesc::from_bytes(&desc.to_bytes()).unwrap(), desc);
        let plain = ModelDesc::example_pendulum();
        let mut body = postcard::to_allocvec(&plain).unwrap();
        body.extend(postcard::to_allocvec(&plain.jnt_scene).unwrap());
        let mut v2 = MAGIC_V2.to_vec();
        v2.extend_from_slice(&fnv1a(&body).to_le_bytes());
        v2.extend_from_slice(&body);
        assert_eq!(ModelDesc::from_bytes(&v2).unwrap(), plain);
    }

    #[test]
    fn clouds_round_trip_and_format_3_reads_as_none() {
        let mut desc = ModelDesc::example_pendulum();
        desc.cloud = Some(CloudDesc { points: vec![[0.1, 0.2, 0.3]], radius: vec![0.01], margin: 0.002, contype: 1, conaffinity: 1 });
        assert_eq!(ModelDesc::from_bytes(&desc.to_bytes()).unwrap(), desc);
        let plain = ModelDesc::example_pendulum();
        let mut body = postcard::to_allocvec(&plain).unwrap();
        body.extend(postcard::to_allocvec(&plain.jnt_scene).unwrap());
        body.extend(postcard::to_allocvec(&plain.couplings).unwrap());
        let mut v3 = MAGIC_V3.to_vec();
        v3.extend_from_slice(&fnv1a(&body).to_le_bytes());
        v3.extend_from_slice(&body);
        assert_eq!(ModelDesc::from_bytes(&v3).unwrap(), plain);
    }

    #[test]
    fn regression_corrupt_bytes_are_errors_not_panics() {
        let bytes = ModelDesc::example_pendulum().to_bytes();
        assert!(ModelDesc::from_bytes(&[]).is_err());
        assert!(ModelDesc::from_bytes(b"PRDESC01").is_err());
        assert!(ModelDesc::from_bytes(b"PRDESC02").is_err());
        assert!(ModelDesc::from_bytes(b"{\"body_parent\": []}").is_err());
        for cut in [9, 16, 17, bytes.len() / 2, bytes.len() - 1] {
            assert!(ModelDesc::from_bytes(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(ModelDesc::from_bytes(&longer).is_err());
        for i in 0..bytes.len() {
            let mut flipped = bytes.clone();
            flipped[i] ^= 0x10;
            assert!(ModelDesc::from_bytes(&flipped).is_err(), "flipped byte {i}");
        }
        // A huge announced length with no data behind it: an error, not an allocation.
        let mut body = vec![0xff, 0xff, 0xff, 0xff, 0x0f];
        body.extend_from_slice(&[0; 4]);
        let mut forged = MAGIC.to_vec();
        forged.extend_from_slice(&fnv1a(&body).to_le_bytes());
        forged.extend_from_slice(&body);
        assert!(ModelDesc::from_bytes(&forged).is_err());
    }
}
