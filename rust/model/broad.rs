//! Broad phase: the candidate pairs of one pose that may touch, found from the body frames
//! alone, before any geom frame or bounding box is computed.
//!
//! Two levels of bounding spheres, fixed in the body frames:
//! - pairs are grouped by body pair, and a group is dropped with one test when the spheres
//!   holding each body's geoms are apart (most of the ~60 body pairs of an arm, most poses);
//!   the world's geoms (a scene's obstacles, which never move) are split first into clusters of
//!   at most [`CLUSTER`] neighbours (`clusters`), each a *group body* of its own with its own
//!   sphere, so that a link is tested against the few obstacles near it, not against one sphere
//!   around the whole scene (which every link is inside);
//! - in a group that survives, each pair is dropped when its geoms' own spheres (about their box
//!   centre, out to the farthest hull vertex) are apart;
//! - four poses at a time (`near_pairs4`, the batches), a pair left is dropped in the poses where
//!   one geom's sphere lies beyond a face of the other's box (`boxes_close`).
//!
//! Every test is inflated by a relative and absolute 1e-9, far above the rounding of the sphere
//! centres (~1e-15 m), and by [`MAX_CLEARANCE`], so a dropped pair is separated by more than its
//! margin plus the certification clearance, and the narrow phase (exact for such pairs: GJK
//! never reports an intersection, nor a distance below the margin, for shapes that far apart)
//! would have reported it apart, and clear, too. Labels do not depend on this file; it only
//! decides how few pairs reach `collide::Scratch::in_contact` and `clear_of`.
//!
//! Pairs with a plane (a half-space) are tested against the plane by the geom's sphere.

use nalgebra::{Isometry3, Matrix3, Vector3};

use crate::model::geom::Geom;
use crate::model::lanes::{Frames4, Reg, F4, M4, V4};
use crate::model::pairs::CandidatePair;
use crate::model::sphere_pairs::{has_avx2, Centres, PairList, LANES};

/// Most world geoms in one group body (`clusters`). On MotionBenchMaker's scenes (7-15 boxes and
/// cylinders around a Panda; 40 problems' second `plan_path` calls, one thread, callgrind)
/// `near_pairs` took 174 M instructions with one sphere around the world, 154 M with clusters of
/// one geom, 141 M with two or four.
pub(crate) const CLUSTER: usize = 4;

/// Metres: the largest clearance a certification may ask for (`fastpath::certified_pose`). The
/// broad phase keeps every pair that may come this close, so a pair it drops is clear of it.
pub const MAX_CLEARANCE: f64 = 1e-6;

/// Relative and absolute (metres) rounding slack the certificates take off every measured
/// distance (`planning/motion.rs`, `planning/spans.rs`).
pub(crate) const DISTANCE_SLACK: f64 = 1e-9;

/// How far the measured distance `d` (metres) proves a pair above `need`, after the rounding
/// slack: positive when it does.
#[inline]
pub(crate) fn slack_above(d: f64, need: f64) -> f64 {
    d - DISTANCE_SLACK * (1.0 + d.abs()) - need
}

/// `Ok` for a clearance a certification may ask for, in (0, [`MAX_CLEARANCE`]] metres. (0 is
/// refused: "apart" at clearance 0 would be decided by distances, not by the intersection
/// tests the labels use for touching shapes.)
pub(crate) fn check_clearance(clearance: f64) -> crate::error::Result<()> {
    if clearance > 0.0 && clearance <= MAX_CLEARANCE {
        Ok(())
    } else {
        crate::error::invalid_input(format!("clearance must be in (0, {MAX_CLEARANCE}] m; got {clearance}"))
    }
}

/// `reach` inflated for rounding and by [`MAX_CLEARANCE`]: the distance between two sphere
/// centres (or a sphere centre and a plane) beyond which spheres whose radii and margin sum to
/// `reach` are more than `MAX_CLEARANCE` apart.
fn inflated(reach: f64) -> f64 {
    reach * (1.0 + 1e-9) + 1e-9 + MAX_CLEARANCE
}

/// `inflated(reach)^2`: the squared centre distance beyond which two spheres whose radii and
/// margin sum to `reach` are more than `MAX_CLEARANCE` apart, with slack for rounding.
fn reach2(reach: f64) -> f64 {
    let r = inflated(reach);
    r * r
}

/// One pair inside a body-pair group.
#[derive(Clone, Copy, Debug)]
struct Member {
    pair: u32,
    g1: u32,
    g2: u32,
    reach2: f64,
}

/// One member's box tests (`near_pairs4`), beside it: each geom's sphere against the other's
/// box, on the box's three axes. Geom 1's box axes are `geom_rot[g1]`'s columns in its body's
/// frame (body `b1`); `lim1[i]` is the reach along axis `i` beyond which geom 2's sphere is
/// clear of the box (half extent, sphere radius and margin summed, `inflated`); and the same
/// with 1 and 2 swapped.
#[derive(Clone, Copy, Debug)]
struct MemberBox {
    b1: u32,
    b2: u32,
    lim1: [f64; 3],
    lim2: [f64; 3],
}

/// The pairs between two group bodies, `members[start..end]`, and the squared reach of the two
/// group bodies' spheres (plus the largest margin among the pairs). A group body is a body, or a
/// cluster of the world's geoms (`clusters`: ids from the number of bodies up).
#[derive(Clone, Copy, Debug)]
struct Group {
    b1: u32,
    b2: u32,
    reach2: f64,
    start: u32,
    end: u32,
}

/// The body-pair groups and their members without padding, for `near_pairs4`, which tests
/// four poses a member rather than four members a pose: all of them (`Broad`), or those left
/// once the pairs proven apart over the whole sampling box are dropped (`RobotModel::pruned4`).
#[derive(Clone, Debug, Default)]
pub(crate) struct Lists4 {
    /// `(b1, b2, reach2, members[start..end])`, as `Group`.
    groups: Vec<Group>,
    members: Vec<Member>,
    /// Member by member, its box tests.
    boxes: Vec<MemberBox>,
    /// The numbers of group bodies (`Group`) and geoms of the broad phase they come from: every index they hold
    /// is below them (`near_pairs4` reads the centres unchecked).
    nbody: usize,
    ngeom: usize,
}

/// A pair of a plane geom with a non-plane geom.
#[derive(Clone, Copy, Debug)]
struct PlanePair {
    pair: u32,
    plane: u32,
    geom: u32,
    /// The geom's sphere radius plus the pair's margin, inflated.
    reach: f64,
}

/// The model's broad-phase data, built once from the geoms and candidate pairs.
#[derive(Debug, Default)]
pub(crate) struct Broad {
    /// Bodies other than the world that carry a geom in `geoms` (their rotation matrices are
    /// needed per pose).
    bodies: Vec<u32>,
    /// Per group body (a body, by its id, then the world's clusters, `clusters`): centre of the
    /// sphere holding its geoms, in its body's frame (the world's, for a cluster).
    body_centre: Vec<Vector3<f64>>,
    /// Per group body: the radius of its sphere (read by tests; the groups' tests hold it).
    #[cfg(test)]
    body_radius: Vec<f64>,
    /// Per geom: centre of its sphere (its box's centre) in its body's frame, its rotation in
    /// its body's frame as a matrix, and its body.
    geom_centre: Vec<Vector3<f64>>,
    geom_rot: Vec<Matrix3<f64>>,
    geom_body: Vec<u32>,
    /// Non-plane geoms of some pair on a moving body, whose world sphere centres are needed per
    /// pose, each with its body.
    geoms: Vec<(u32, u32)>,
    /// Non-plane geoms of some pair on the world body: their sphere centres never move, and
    /// `scratch` places them once.
    static_geoms: Vec<u32>,
    /// The world's clusters' group bodies (`clusters`; every world geom of a non-plane pair is in
    /// one, so the world body itself is in no group): their spheres never move, and `scratch`
    /// places them once.
    clusters: std::ops::Range<usize>,
    groups: Vec<Group>,
    /// The groups' body-sphere tests (`model/sphere_pairs.rs`), in group order, padded at the end.
    group_tests: PairList,
    /// Each group's members start on a lane boundary; the gaps are padding members that never
    /// pass (pair `NONE`).
    members: Vec<Member>,
    /// Per member, its two geoms' sphere radii summed (`sphere_gap`, which reads no geom then).
    member_radii: Vec<f64>,
    /// The members' geom-sphere tests, entry for entry.
    member_tests: PairList,
    /// The members' box tests, entry for entry (`near_pairs4`).
    member_boxes: Vec<MemberBox>,
    /// The groups and members without padding (`near_pairs4`).
    all4: Lists4,
    /// Whether `sphere_pairs`' AVX2 kernel runs here.
    avx2: bool,
    planes: Vec<PlanePair>,
    /// The plane geoms of `planes`, once each.
    plane_geoms: Vec<u32>,
    /// Per candidate pair: its index in `members`, or in `planes` with the `PLANE` bit set
    /// (`NONE` for a plane-plane pair, which is never a candidate).
    of_pair: Vec<u32>,
}

impl Lists4 {
    /// The members of `groups` (padded, in `members`) that are real pairs and `keep`, group by
    /// group in order; groups left empty are dropped.
    fn of(groups: &[Group], members: &[Member], boxes: &[MemberBox], nbody: usize, ngeom: usize, keep: impl Fn(u32) -> bool) -> Self {
        let mut out = Lists4 { nbody, ngeom, ..Lists4::default() };
        for g in groups {
            let start = out.members.len() as u32;
            for (m, b) in members[g.start as usize..g.end as usize].iter().zip(&boxes[g.start as usize..g.end as usize]) {
                if m.pair != NONE && keep(m.pair) {
                    out.members.push(*m);
                    out.boxes.push(*b);
                }
            }
            if out.members.len() as u32 > start {
                out.groups.push(Group { start, end: out.members.len() as u32, ..*g });
            }
        }
        out
    }

    /// `broad`'s lists without the pairs `dead` (in their original order).
    pub(crate) fn without(broad: &Broad, dead: impl Fn(u32) -> bool) -> Self {
        let (nbody, ngeom) = (broad.body_centre.len(), broad.geom_centre.len());
        Lists4::of(&broad.groups, &broad.members, &broad.member_boxes, nbody, ngeom, |k| !dead(k))
    }

    /// Number of members (pairs) the lists test.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.members.len()
    }
}

/// One cluster of the world's geoms as `Broad::world_clusters` reports it (for tests): its
/// sphere, and the geoms it holds, each with whether it lies inside the sphere.
#[cfg(test)]
#[derive(Debug)]
pub(crate) struct WorldCluster {
    pub centre: Vector3<f64>,
    pub radius: f64,
    pub held: Vec<(usize, bool)>,
}

/// Tag of an `of_pair` entry that indexes `planes`.
const PLANE: u32 = 1 << 31;
/// An `of_pair` entry for a pair in neither list.
const NONE: u32 = u32::MAX;

/// Per-thread buffers of the broad phase (world sphere centres of one pose).
#[derive(Clone, Debug)]
pub(crate) struct BroadScratch {
    rot: Vec<Matrix3<f64>>,
    body_world: Centres,
    geom_world: Centres,
    /// Per plane geom: world normal and `normal . origin`.
    plane: Vec<(Vector3<f64>, f64)>,
    /// Room for every pair.
    buf: Vec<u32>,
}

impl Broad {
    pub(crate) fn new(nbody: usize, geoms: &[Geom], pairs: &[CandidatePair]) -> Self {
        let is_plane = |g: usize| geoms[g].shape.is_half_space();
        let geom_centre: Vec<Vector3<f64>> = geoms.iter().map(|g| (g.local * nalgebra::Point3::from(g.shape.obb_center)).coords).collect();
        let geom_body: Vec<u32> = geoms.iter().map(|g| g.body as u32).collect();
        let geom_rot: Vec<Matrix3<f64>> = geoms.iter().map(|g| g.local.rotation.to_rotation_matrix().into_inner()).collect();

        // Non-plane pairs by body pair (ordered ids), planes apart.
        let mut by_bodies: std::collections::BTreeMap<(u32, u32), Vec<u32>> = Default::default();
        let mut planes = Vec::new();
        // Geoms of non-plane pairs (they shape their body's sphere), and geoms whose world
        // sphere centre is needed (those and the non-plane geoms of plane pairs).
        let mut used = vec![false; geoms.len()];
        let mut sphere = vec![false; geoms.len()];
        for (k, p) in pairs.iter().enumerate() {
            match (is_plane(p.g1), is_plane(p.g2)) {
                // Never a candidate (`model/pairs.rs` drops them), and nothing to test if it were.
                (true, true) => {}
                (true, false) | (false, true) => {
                    let (plane, geom) = if is_plane(p.g1) { (p.g1, p.g2) } else { (p.g2, p.g1) };
                    // (a negative margin counts as 0: the pair must still be measured when it
                    // comes within MAX_CLEARANCE, for certification)
                    let reach = inflated(geoms[geom].shape.radius + p.margin.max(0.0));
                    planes.push(PlanePair { pair: k as u32, plane: plane as u32, geom: geom as u32, reach });
                    sphere[geom] = true;
                }
                (false, false) => {
                    used[p.g1] = true;
                    used[p.g2] = true;
                    sphere[p.g1] = true;
                    sphere[p.g2] = true;
                }
            }
        }

        // The group bodies: each body, then the world's geoms of non-plane pairs in clusters.
        let world: Vec<usize> = (0..geoms.len()).filter(|&g| used[g] && geom_body[g] == 0).collect();
        let world_clusters = clusters(world, &|g| geom_centre[g]);
        let nb = nbody + world_clusters.len();
        let mut group_body = geom_body.clone();
        for (c, members) in world_clusters.iter().enumerate() {
            for &g in members {
                group_body[g] = (nbody + c) as u32;
            }
        }
        // Each group body's sphere: centred in the box around its geoms' spheres, out to the
        // farthest.
        let mut lo = vec![Vector3::repeat(f64::INFINITY); nb];
        let mut hi = vec![Vector3::repeat(f64::NEG_INFINITY); nb];
        for g in (0..geoms.len()).filter(|&g| used[g]) {
            let (b, r) = (group_body[g] as usize, geoms[g].shape.radius);
            lo[b] = lo[b].inf(&geom_centre[g].add_scalar(-r));
            hi[b] = hi[b].sup(&geom_centre[g].add_scalar(r));
        }
        let body_centre: Vec<Vector3<f64>> =
            (0..nb).map(|b| if lo[b].x.is_finite() { (lo[b] + hi[b]) * 0.5 } else { Vector3::zeros() }).collect();
        let mut body_radius = vec![0.0f64; nb];
        for g in (0..geoms.len()).filter(|&g| used[g]) {
            let b = group_body[g] as usize;
            let r = ((geom_centre[g] - body_centre[b]).norm() + geoms[g].shape.radius) * (1.0 + 1e-12);
            body_radius[b] = body_radius[b].max(r);
        }

        for (k, p) in pairs.iter().enumerate().filter(|(_, p)| !is_plane(p.g1) && !is_plane(p.g2)) {
            let (b1, b2) = (group_body[p.g1], group_body[p.g2]);
            by_bodies.entry((b1.min(b2), b1.max(b2))).or_default().push(k as u32);
        }
        let mut groups = Vec::new();
        let mut members = Vec::new();
        let padding = Member { pair: NONE, g1: 0, g2: 0, reach2: -1.0 };
        for ((b1, b2), ks) in by_bodies {
            let mut margin = 0.0f64;
            for &k in &ks {
                margin = margin.max(pairs[k as usize].margin);
            }
            let reach = reach2(body_radius[b1 as usize] + body_radius[b2 as usize] + margin);
            // At most 64 members a group, so that a group's survivors fit one bit mask.
            for chunk in ks.chunks(64) {
                while members.len() % LANES != 0 {
                    members.push(padding);
                }
                let start = members.len() as u32;
                for &k in chunk {
                    let p = &pairs[k as usize];
                    let r = geoms[p.g1].shape.radius + geoms[p.g2].shape.radius + p.margin.max(0.0);
                    members.push(Member { pair: k, g1: p.g1 as u32, g2: p.g2 as u32, reach2: reach2(r) });
                }
                groups.push(Group { b1, b2, reach2: reach, start, end: members.len() as u32 });
            }
        }
        while members.len() % LANES != 0 {
            members.push(padding);
        }
        let member_boxes: Vec<MemberBox> = members
            .iter()
            .map(|m| {
                if m.pair == NONE {
                    return MemberBox { b1: 0, b2: 0, lim1: [0.0; 3], lim2: [0.0; 3] };
                }
                let (a, b, margin) = (&geoms[m.g1 as usize].shape, &geoms[m.g2 as usize].shape, pairs[m.pair as usize].margin.max(0.0));
                MemberBox {
                    b1: geom_body[m.g1 as usize],
                    b2: geom_body[m.g2 as usize],
                    lim1: std::array::from_fn(|i| inflated(a.obb_half[i] + b.radius + margin)),
                    lim2: std::array::from_fn(|i| inflated(b.obb_half[i] + a.radius + margin)),
                }
            })
            .collect();
        let all4 = Lists4::of(&groups, &members, &member_boxes, nb, geoms.len(), |_| true);
        let mut member_tests = PairList::default();
        for m in &members {
            member_tests.push(m.g1, m.g2, m.reach2);
        }
        let mut group_tests = PairList::default();
        for g in &groups {
            group_tests.push(g.b1, g.b2, g.reach2);
        }
        group_tests.pad();
        let mut bodies: Vec<u32> = (0..geoms.len()).filter(|&g| sphere[g]).map(|g| geom_body[g]).collect();
        bodies.sort_unstable();
        bodies.dedup();
        bodies.retain(|&b| b != 0);
        let static_geoms = (0..geoms.len() as u32).filter(|&g| sphere[g as usize] && geom_body[g as usize] == 0).collect();
        let member_radii = members
            .iter()
            .map(|m| if m.pair == NONE { f64::NAN } else { geoms[m.g1 as usize].shape.radius + geoms[m.g2 as usize].shape.radius })
            .collect();
        let geoms = (0..geoms.len() as u32)
            .filter(|&g| sphere[g as usize] && geom_body[g as usize] != 0)
            .map(|g| (g, geom_body[g as usize]))
            .collect();
        let mut plane_geoms: Vec<u32> = planes.iter().map(|p| p.plane).collect();
        plane_geoms.sort_unstable();
        plane_geoms.dedup();
        let mut of_pair = vec![NONE; pairs.len()];
        for (i, m) in members.iter().enumerate().filter(|(_, m)| m.pair != NONE) {
            of_pair[m.pair as usize] = i as u32;
        }
        for (i, p) in planes.iter().enumerate() {
            of_pair[p.pair as usize] = i as u32 | PLANE;
        }
        Broad {
            bodies,
            body_centre,
            #[cfg(test)]
            body_radius,
            geom_centre,
            geom_rot,
            geom_body,
            geoms,
            static_geoms,
            clusters: nbody..nb,
            groups,
            group_tests,
            member_radii,
            members,
            member_tests,
            member_boxes,
            all4,
            avx2: has_avx2(),
            planes,
            plane_geoms,
            of_pair,
        }
    }

    /// Per cluster of the world's geoms (`clusters`): its sphere's centre
    /// and radius, and the world geoms its groups' pairs hold, each with whether it lies inside
    /// that sphere (for tests, on models without a pair of two world geoms: both would be
    /// credited to each of their clusters).
    #[cfg(test)]
    pub(crate) fn world_clusters(&self, geoms: &[Geom]) -> Vec<WorldCluster> {
        self.clusters
            .clone()
            .map(|c| {
                let (centre, radius) = (self.body_centre[c], self.body_radius[c]);
                let mut held: Vec<usize> = self
                    .groups
                    .iter()
                    .filter(|gr| gr.b1 as usize == c || gr.b2 as usize == c)
                    .flat_map(|gr| self.members[gr.start as usize..gr.end as usize].iter())
                    .filter(|m| m.pair != NONE)
                    .flat_map(|m| [m.g1 as usize, m.g2 as usize])
                    .filter(|&g| geoms[g].body == 0)
                    .collect();
                held.sort_unstable();
                held.dedup();
                let inside = |g: usize| (centre - self.geom_centre[g]).norm() + geoms[g].shape.radius <= radius;
                WorldCluster { centre, radius, held: held.into_iter().map(|g| (g, inside(g))).collect() }
            })
            .collect()
    }

    /// Whether the CPU has AVX2 (found once, when the model was built).
    #[inline]
    pub(crate) fn avx2(&self) -> bool {
        self.avx2
    }

    /// Every group and member, for `near_pairs4`.
    pub(crate) fn all4(&self) -> &Lists4 {
        &self.all4
    }

    /// The plane geoms whose world frames `near_pairs` needs.
    pub(crate) fn plane_geoms(&self) -> &[u32] {
        &self.plane_geoms
    }

    pub(crate) fn scratch(&self) -> BroadScratch {
        let (nb, ng) = (self.body_centre.len(), self.geom_centre.len());
        let mut s = BroadScratch {
            rot: vec![Matrix3::identity(); nb],
            body_world: Centres::zeros(nb),
            geom_world: Centres::zeros(ng),
            plane: vec![(Vector3::zeros(), 0.0); ng],
            buf: vec![0; self.members.len() + self.planes.len()],
        };
        // The world body's frame is the identity in every pose (`kinematics::body_poses`): its
        // spheres (its own, its clusters' and its geoms') are placed here, once, as `place`
        // would place them (bit for bit: the identity's rotation matrix is exact, and adding its
        // zero translation is too).
        let world = Isometry3::identity();
        let r = world.rotation.to_rotation_matrix().into_inner();
        s.rot[0] = r;
        for b in self.clusters.clone() {
            s.body_world.set(b, &(world.translation.vector + r * self.body_centre[b]));
        }
        for &g in &self.static_geoms {
            self.set_geom_centre(&world, &r, g as usize, &mut s.geom_world);
        }
        s
    }

    /// Places the spheres for the pose whose body frames are `bodies` (`geom_poses` must hold
    /// the world frames of the plane geoms): what `near_pairs` and `may_touch` test.
    ///
    /// The world's spheres (its own, its clusters' and its geoms') were placed with the scratch (`scratch`): `bodies[0]`
    /// must be the identity, as `kinematics::body_poses` makes it.
    pub(crate) fn place(&self, bodies: &[Isometry3<f64>], geom_poses: &[Isometry3<f64>], s: &mut BroadScratch) {
        debug_assert!(bodies[0] == Isometry3::identity());
        for &b in &self.bodies {
            let b = b as usize;
            let x = &bodies[b];
            let r = x.rotation.to_rotation_matrix().into_inner();
            s.rot[b] = r;
            s.body_world.set(b, &(x.translation.vector + r * self.body_centre[b]));
        }
        for &(g, b) in &self.geoms {
            let (g, b) = (g as usize, b as usize);
            self.set_geom_centre(&bodies[b], &s.rot[b], g, &mut s.geom_world);
        }
        self.place_planes(geom_poses, s);
    }

    /// `place`'s planes alone, from the plane geoms' world frames in `geom_poses`.
    pub(crate) fn place_planes(&self, geom_poses: &[Isometry3<f64>], s: &mut BroadScratch) {
        for &g in &self.plane_geoms {
            self.place_plane(&geom_poses[g as usize], g as usize, s);
        }
    }

    /// `place`'s spheres (not its planes) for four poses at once, from their body frames in four
    /// lanes (`kinematics::body_poses4`, in `room`), into their four scratches, bit for bit
    /// (`model/lanes.rs`). Inlined into its caller, which compiles it for the vector width it has.
    #[inline(always)]
    pub(crate) fn place_spheres4(&self, room: &mut Frames4, mut out: [&mut BroadScratch; 4]) {
        let (nb, ng) = (self.body_centre.len(), self.geom_centre.len());
        // Each lane's destinations, written through pointers below: the loops write one
        // coordinate of four scratches per step, and indexing each would check its bounds.
        let mut rot = [std::ptr::null_mut::<Matrix3<f64>>(); 4];
        let mut body_world = [[std::ptr::null_mut::<f64>(); 3]; 4];
        let mut geom_world = [[std::ptr::null_mut::<f64>(); 3]; 4];
        let centres = |c: &mut Centres| [c.x.as_mut_ptr(), c.y.as_mut_ptr(), c.z.as_mut_ptr()];
        for (l, s) in out.iter_mut().enumerate() {
            let (bw, gw) = (&s.body_world, &s.geom_world);
            assert!(s.rot.len() == nb && [&bw.x, &bw.y, &bw.z].iter().all(|v| v.len() == nb), "a scratch of this broad phase");
            assert!([&gw.x, &gw.y, &gw.z].iter().all(|v| v.len() == ng), "a scratch of this broad phase");
            rot[l] = s.rot.as_mut_ptr();
            body_world[l] = centres(&mut s.body_world);
            geom_world[l] = centres(&mut s.geom_world);
        }
        let (bodies, rots) = (&room.bodies, &mut room.rots);
        if rots.len() != nb {
            // (the world's frame is the identity in every pose, and no body below writes it:
            // `near_pairs4`'s box tests read its rotation; the clusters' are never read)
            rots.clear();
            rots.resize(nb, M4([[F4::splat(0.0); 3]; 3]));
            rots[0] = M4::splat(&Matrix3::identity());
        }
        let zero = V4 { x: F4::splat(0.0), y: F4::splat(0.0), z: F4::splat(0.0) };
        let (body_centres, geom_centres) = (&mut room.body_centres, &mut room.geom_centres);
        body_centres.resize(nb, zero);
        geom_centres.resize(ng, zero);
        // (the world's spheres, placed once a scratch: lane 0's, the same in every scratch)
        for b in self.clusters.clone() {
            body_centres[b] = V4::splat(&out[0].body_world.get(b));
        }
        for &g in &self.static_geoms {
            geom_centres[g as usize] = V4::splat(&out[0].geom_world.get(g as usize));
        }
        for &b in &self.bodies {
            let b = b as usize;
            let x = &bodies[b];
            let r = M4::rotation(&x.r);
            let c = x.t.add(&r.mul_vec(&V4::splat(&self.body_centre[b])));
            rots[b] = r;
            body_centres[b] = c;
            for l in 0..4 {
                // SAFETY: `b < nb` (a body of the model), the length of every lane's `rot` and
                // `body_world` (asserted above); the pointers come from four distinct `&mut`
                // scratches, whose vectors are neither read nor resized while they live.
                unsafe {
                    rot[l].add(b).write(r.lane(l));
                    for (dst, v) in body_world[l].iter().zip([c.x, c.y, c.z]) {
                        dst.add(b).write(v.0[l]);
                    }
                }
            }
        }
        for &(g, b) in &self.geoms {
            let (g, b) = (g as usize, b as usize);
            let c = bodies[b].t.add(&rots[b].mul_vec(&V4::splat(&self.geom_centre[g])));
            geom_centres[g] = c;
            for (l, lane) in geom_world.iter().enumerate() {
                // SAFETY: `g < ng` (a geom of the model), the length of every lane's `geom_world`
                // (asserted above); as above.
                unsafe {
                    for (dst, v) in lane.iter().zip([c.x, c.y, c.z]) {
                        dst.add(g).write(v.0[l]);
                    }
                }
            }
        }
    }

    /// What `place` computes for the non-plane geom `g` of some pair (its body's rotation matrix
    /// and its sphere centre), alone, from its body's frame in `bodies`; the body's rotation
    /// matrix only when `rotation` (else it must be this pose's already: another geom of the
    /// body was placed).
    #[inline]
    pub(crate) fn place_geom(&self, bodies: &[Isometry3<f64>], g: usize, rotation: bool, s: &mut BroadScratch) {
        let b = self.geom_body[g] as usize;
        let x = &bodies[b];
        if rotation {
            s.rot[b] = x.rotation.to_rotation_matrix().into_inner();
        }
        self.set_geom_centre(x, &s.rot[b], g, &mut s.geom_world);
    }

    /// Geom `g`'s world sphere centre from its body's frame `x` and rotation matrix `r`.
    #[inline(always)]
    fn set_geom_centre(&self, x: &Isometry3<f64>, r: &Matrix3<f64>, g: usize, out: &mut Centres) {
        out.set(g, &(x.translation.vector + r * self.geom_centre[g]));
    }

    /// What `place` computes for the plane geom `g`, alone, from its world frame `x`.
    #[inline]
    pub(crate) fn place_plane(&self, x: &Isometry3<f64>, g: usize, s: &mut BroadScratch) {
        let normal = x.rotation * Vector3::z();
        s.plane[g] = (normal, normal.dot(&x.translation.vector));
    }

    /// The placed world box frame of geom `g` (a non-plane geom of some pair): its rotation,
    /// the body's rotation matrix times the geom's, and its centre, the sphere centre.
    #[inline]
    pub(crate) fn geom_box(&self, s: &BroadScratch, g: usize) -> (Matrix3<f64>, Vector3<f64>) {
        (s.rot[self.geom_body[g] as usize] * self.geom_rot[g], s.geom_world.get(g))
    }

    /// Whether candidate pair `k` passes its own sphere test in the placed pose (`near_pairs`
    /// keeps exactly the pairs that pass it and their group's test).
    #[inline]
    pub(crate) fn may_touch(&self, s: &BroadScratch, k: usize) -> bool {
        let i = self.of_pair[k];
        if i == NONE {
            false
        } else if i & PLANE != 0 {
            let p = &self.planes[(i & !PLANE) as usize];
            let (normal, offset) = s.plane[p.plane as usize];
            normal.dot(&s.geom_world.get(p.geom as usize)) - offset < p.reach
        } else {
            let m = &self.members[i as usize];
            (s.geom_world.get(m.g1 as usize) - s.geom_world.get(m.g2 as usize)).norm_squared() <= m.reach2
        }
    }

    /// A lower bound on candidate pair `k`'s distance in the placed pose, from its geoms'
    /// bounding spheres (a plane pair: the sphere's height above the plane), less a relative and
    /// absolute 1e-9 for rounding; and the spheres' radii summed (the distance itself is
    /// unlikely to exceed the bound by more). `+inf` for a plane-plane pair (never a candidate).
    #[inline]
    pub(crate) fn sphere_gap(&self, s: &BroadScratch, k: usize, geoms: &[Geom]) -> (f64, f64) {
        let i = self.of_pair[k];
        let (gap, reach) = if i == NONE {
            return (f64::INFINITY, 0.0);
        } else if i & PLANE != 0 {
            let p = &self.planes[(i & !PLANE) as usize];
            let (normal, offset) = s.plane[p.plane as usize];
            let r = geoms[p.geom as usize].shape.radius;
            (normal.dot(&s.geom_world.get(p.geom as usize)) - offset - r, r)
        } else {
            let m = &self.members[i as usize];
            let r = self.member_radii[i as usize];
            ((s.geom_world.get(m.g1 as usize) - s.geom_world.get(m.g2 as usize)).norm() - r, r)
        };
        (gap - 1e-9 * (1.0 + reach + gap.abs()), reach)
    }

    /// Geom `g`'s placed bounding-sphere centre (a non-plane geom of some pair).
    #[inline]
    pub(crate) fn sphere_centre(&self, s: &BroadScratch, g: usize) -> Vector3<f64> {
        s.geom_world.get(g)
    }

    /// The lanes of `hit` (bit `l`: pose `l`) in which member `m`'s geoms may come within its
    /// reach by their box tests (`bx`): neither geom's sphere centre lies beyond a face of the
    /// other's box by more than the sphere's radius, the margin and [`MAX_CLEARANCE`], with the
    /// broad phase's rounding slack (`inflated`). `c1`, `c2`: the geoms' sphere centres (their
    /// box centres), `rots`: the bodies' rotation matrices, of the four poses.
    ///
    /// Geom 1's box frame is its body's rotation `R` times its own fixed `L`, so the centre
    /// offset `d = c2 − c1` on its axes is `Lᵀ (Rᵀ d)`: two products by 3 x 3 matrices, four
    /// poses at a time. In a lane left out, one geom's sphere (which holds the geom) lies beyond
    /// a face of the other's box (which holds the other) by more than the margin plus
    /// [`MAX_CLEARANCE`], in exact arithmetic too: the centres' and products' rounding (~1e-15 m
    /// for geoms within metres of the origin) is far inside the 1e-9 slack, as for the sphere
    /// tests. The geoms are then apart by more than the margin (a negative one counts as 0) and
    /// the clearance, so the narrow phase would find the pair apart (`in_contact`'s own first box
    /// test, `obbs_overlap`, rejects it already) and clear (`clear_of`): labels do not change,
    /// only the work.
    ///
    /// # Safety
    /// With `AVX2`, the CPU has AVX2.
    #[inline(always)]
    unsafe fn boxes_may_touch<const AVX2: bool>(&self, m: &Member, bx: &MemberBox, rots: &[M4], c1: &V4, c2: &V4, hit: u32) -> u32 {
        let d = c2.sub(c1);
        // SAFETY: the bodies and geoms of the lists' members are below `rots.len()` (asserted
        // by the caller) and the number of geoms.
        let (r1, r2, l1, l2) = unsafe {
            (
                rots.get_unchecked(bx.b1 as usize),
                rots.get_unchecked(bx.b2 as usize),
                self.geom_rot.get_unchecked(m.g1 as usize),
                self.geom_rot.get_unchecked(m.g2 as usize),
            )
        };
        #[cfg(target_arch = "x86_64")]
        if AVX2 {
            // SAFETY: as the caller promises.
            return unsafe { boxes_close_avx2(r1, l1, r2, l2, bx, &d, hit) };
        }
        // SAFETY: portable registers.
        unsafe { boxes_close::<F4>(r1, l1, r2, l2, bx, &d, hit) }
    }

    /// `near_pairs` of the four poses whose bits `want` sets (bit `l`: pose `l`), into their
    /// `near` (each cleared first; the others' are left empty), in the order `near_pairs` gives,
    /// of the pairs in `lists` (`all4`, or a pruned list that holds every pair the four poses
    /// need tested): the sphere tests on the four poses' centres in lanes (`room`, as
    /// `place_spheres4` left them; the same values, the same sums, so the same bits), less the
    /// pairs the box tests drop (`boxes_may_touch`: `near_pairs` keeps them, the narrow phase
    /// finds them apart and clear), and the planes from each pose's scratch (placed by
    /// `place_planes`). Inlined into its caller, which compiles it for the vector width it has:
    /// `AVX2` where that is AVX2 (registers `lanes::Avx2`), the portable lanes elsewhere.
    ///
    /// # Safety
    /// With `AVX2`, the CPU has AVX2.
    #[inline(always)]
    pub(crate) unsafe fn near_pairs4<const AVX2: bool>(
        &self,
        lists: &Lists4,
        room: &Frames4,
        s: [&BroadScratch; 4],
        want: u32,
        near: [&mut Vec<u32>; 4],
    ) {
        let (bodies, geoms, rots) = (&room.body_centres, &room.geom_centres, &room.rots);
        // (every list names bodies and geoms of the model, whose centres and rotations
        // `place_spheres4` placed)
        assert!(lists.nbody == bodies.len() && lists.ngeom == geoms.len(), "lists and centres of the same broad phase");
        assert!(lists.nbody == self.body_centre.len() && lists.ngeom == self.geom_rot.len(), "lists of this broad phase");
        assert!(rots.len() == bodies.len() && lists.boxes.len() == lists.members.len(), "lists and rotations of the same broad phase");
        let mut near = near;
        for n in near.iter_mut() {
            n.clear();
            n.reserve(lists.members.len() + self.planes.len());
        }
        for gr in &lists.groups {
            // SAFETY (here and below): as the caller promises.
            let poses = want & unsafe { bodies[gr.b1 as usize].within_in::<AVX2>(&bodies[gr.b2 as usize], gr.reach2) };
            if poses == 0 {
                continue;
            }
            let (start, end) = (gr.start as usize, gr.end as usize);
            for (m, bx) in lists.members[start..end].iter().zip(&lists.boxes[start..end]) {
                // SAFETY: a member's geoms are below the `ngeom` of its lists (`Lists4::of`),
                // which is `geoms.len()` (asserted above).
                let (c1, c2) = unsafe { (geoms.get_unchecked(m.g1 as usize), geoms.get_unchecked(m.g2 as usize)) };
                let mut hit = poses & unsafe { c1.within_in::<AVX2>(c2, m.reach2) };
                if hit != 0 {
                    hit = unsafe { self.boxes_may_touch::<AVX2>(m, bx, rots, c1, c2, hit) };
                }
                while hit != 0 {
                    near[hit.trailing_zeros() as usize].push(m.pair);
                    hit &= hit - 1;
                }
            }
        }
        for (l, (s, near)) in s.iter().zip(near).enumerate() {
            if want & 1 << l == 0 {
                continue;
            }
            for p in &self.planes {
                let (normal, offset) = s.plane[p.plane as usize];
                if normal.dot(&s.geom_world.get(p.geom as usize)) - offset < p.reach {
                    near.push(p.pair);
                }
            }
        }
    }

    /// Appends to `near` the candidate pairs that may touch in the placed pose (see `place`),
    /// in no particular order.
    pub(crate) fn near_pairs(&self, s: &mut BroadScratch, near: &mut Vec<u32>) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only where the CPU has AVX2 (`Broad::new`), and the lists
            // are laid out as `PairList::mask_avx2` asks: every group's members start on a lane
            // boundary and both lists are padded to one; their indices are bodies and geoms,
            // within the scratch's centres.
            return unsafe { self.near_pairs_avx2(s, near) };
        }
        self.near_pairs_with(s, near, |l, c, start, len| l.mask_portable(c, start, len))
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn near_pairs_avx2(&self, s: &mut BroadScratch, near: &mut Vec<u32>) {
        // SAFETY: as `near_pairs` says.
        self.near_pairs_with(s, near, |l, c, start, len| unsafe { l.mask_avx2(c, start, len) })
    }

    /// `near_pairs` with the sphere-pair kernel `mask` (`PairList::mask_portable` or its AVX2
    /// twin, which give the same bits).
    #[inline(always)]
    fn near_pairs_with(&self, s: &mut BroadScratch, near: &mut Vec<u32>, mask: impl Fn(&PairList, &Centres, usize, usize) -> u64) {
        // Without branches (few pass, unpredictably): one bit per group in 64-group words,
        // then one bit per member of each surviving group, then the survivors.
        let buf = &mut s.buf;
        let mut n = 0usize;
        for w in 0..self.groups.len().div_ceil(64) {
            let len = (self.groups.len() - w * 64).min(64);
            let mut bits = mask(&self.group_tests, &s.body_world, w * 64, len);
            while bits != 0 {
                let gr = &self.groups[w * 64 + bits.trailing_zeros() as usize];
                bits &= bits - 1;
                let (start, len) = (gr.start as usize, (gr.end - gr.start) as usize);
                let mut near_bits = mask(&self.member_tests, &s.geom_world, start, len);
                while near_bits != 0 {
                    buf[n] = self.members[start + near_bits.trailing_zeros() as usize].pair;
                    n += 1;
                    near_bits &= near_bits - 1;
                }
            }
        }
        for p in &self.planes {
            let (normal, offset) = s.plane[p.plane as usize];
            if normal.dot(&s.geom_world.get(p.geom as usize)) - offset < p.reach {
                buf[n] = p.pair;
                n += 1;
            }
        }
        near.extend_from_slice(&buf[..n]);
    }
}

/// The geoms `gs` split into clusters of at most [`CLUSTER`] neighbours: halved at the median of
/// their centres (`centre`) along the axis on which those spread most, until each part is small
/// enough. A function of the geoms and their centres alone (ties by geom index), so the groups
/// and their order, and with them `near_pairs`' order, are too.
fn clusters(mut gs: Vec<usize>, centre: &impl Fn(usize) -> Vector3<f64>) -> Vec<Vec<usize>> {
    if gs.len() <= CLUSTER {
        return if gs.is_empty() { Vec::new() } else { vec![gs] };
    }
    let (mut lo, mut hi) = (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY));
    for &g in &gs {
        lo = lo.inf(&centre(g));
        hi = hi.sup(&centre(g));
    }
    let axis = (hi - lo).imax();
    gs.sort_by(|&a, &b| centre(a)[axis].total_cmp(&centre(b)[axis]).then(a.cmp(&b)));
    let right = gs.split_off(gs.len() / 2);
    let mut out = clusters(gs, centre);
    out.extend(clusters(right, centre));
    out
}

/// `Broad::boxes_may_touch` in registers `R`, of the lanes `hit`: each geom's sphere against
/// the other's box (`sphere_beyond_box`). (A test of the boxes' own face axes after this one, in
/// four lanes too, was measured and dropped: it rejected few more pairs on the bundled scenes,
/// and cost more than it saved.)
///
/// # Safety
/// With `Avx2`, the CPU has AVX2 (and, to be fast, the caller is compiled with it:
/// `boxes_close_avx2`).
#[inline(always)]
unsafe fn boxes_close<R: Reg>(r1: &M4, l1: &Matrix3<f64>, r2: &M4, l2: &Matrix3<f64>, bx: &MemberBox, d: &V4, hit: u32) -> u32 {
    unsafe {
        let d = [R::load(&d.x), R::load(&d.y), R::load(&d.z)];
        hit & !(sphere_beyond_box::<R>(r1, l1, &bx.lim1, d) | sphere_beyond_box::<R>(r2, l2, &bx.lim2, d))
    }
}

/// `boxes_close` in AVX2 registers.
///
/// # Safety
/// The CPU has AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn boxes_close_avx2(r1: &M4, l1: &Matrix3<f64>, r2: &M4, l2: &Matrix3<f64>, bx: &MemberBox, d: &V4, hit: u32) -> u32 {
    // SAFETY: compiled with AVX2, as `Reg` asks.
    unsafe { boxes_close::<crate::model::lanes::Avx2>(r1, l1, r2, l2, bx, d, hit) }
}

/// Column `c` of the four lanes' matrices `r`.
#[inline(always)]
unsafe fn column<R: Reg>(r: &M4, c: usize) -> [R; 3] {
    unsafe { [R::load(&r.0[0][c]), R::load(&r.0[1][c]), R::load(&r.0[2][c])] }
}

/// Column `c` of `l`, in every lane.
#[inline(always)]
unsafe fn splat_column<R: Reg>(l: &Matrix3<f64>, c: usize) -> [R; 3] {
    unsafe { [R::splat(l[(0, c)]), R::splat(l[(1, c)]), R::splat(l[(2, c)])] }
}

/// One side of `boxes_close`'s sphere tests: bit `l` set where, in lane `l`, the centre offset
/// `d` on the axes of a box (rotation `R L`: its body's `r`, its own fixed `l`) is beyond `lim`
/// on some axis, `|t_i| > lim[i]`, with `t = Lᵀ (Rᵀ d)`, each dot product `(a0 b0 + a1 b1) + a2 b2`.
#[inline(always)]
unsafe fn sphere_beyond_box<R: Reg>(r: &M4, l: &Matrix3<f64>, lim: &[f64; 3], d: [R; 3]) -> u32 {
    unsafe {
        let e = [R::dot3(column(r, 0), d), R::dot3(column(r, 1), d), R::dot3(column(r, 2), d)];
        let mut beyond = 0;
        for (i, lim) in lim.iter().enumerate() {
            beyond |= R::dot3(splat_column(l, i), e).abs().gt(R::splat(*lim));
        }
        beyond
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// `near_pairs4`'s AVX2 kernels give the portable ones' bits, lane by lane (so a batch's near
    /// pairs do not depend on the CPU); the box test is its definition, some axis with
    /// `|t_i| > lim[i]` for `t = (R L)ᵀ d` (up to rounding), and never true in a NaN lane.
    #[test]
    fn four_lane_box_and_sphere_tests_are_the_portable_ones_and_the_definition() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let vec3 = |rng: &mut rand_chacha::ChaCha8Rng| {
            Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0))
        };
        let rotation = |v: Vector3<f64>| nalgebra::UnitQuaternion::from_scaled_axis(v * 3.0).to_rotation_matrix().into_inner();
        let lanes = |vs: [Vector3<f64>; 4]| V4 { x: F4(vs.map(|v| v.x)), y: F4(vs.map(|v| v.y)), z: F4(vs.map(|v| v.z)) };
        let (mut beyond, mut close) = (0, 0);
        for trial in 0..4000 {
            let l = rotation(vec3(&mut rng));
            let rs: [Matrix3<f64>; 4] = std::array::from_fn(|_| rotation(vec3(&mut rng)));
            let r = M4(std::array::from_fn(|i| std::array::from_fn(|j| F4(rs.map(|m| m[(i, j)])))));
            let ds: [Vector3<f64>; 4] = std::array::from_fn(|_| vec3(&mut rng));
            let mut d = lanes(ds);
            let lim: [f64; 3] = std::array::from_fn(|_| rng.random_range(0.0..1.0));
            let nan = trial % 7 == 3;
            if nan {
                d.y.0[2] = f64::NAN;
            }
            // SAFETY: portable registers.
            let got = unsafe { sphere_beyond_box::<F4>(&r, &l, &lim, [d.x, d.y, d.z]) };
            for k in 0..4 {
                let bit = got >> k & 1 == 1;
                if nan && k == 2 {
                    assert!(!bit, "trial {trial}: a NaN lane beyond");
                    continue;
                }
                let t = (rs[k] * l).tr_mul(&ds[k]);
                let over = |slack: f64| (0..3).any(|i| t[i].abs() > lim[i] + slack);
                // (the definition, but within rounding of a tie)
                assert!(bit == over(0.0) || over(-1e-12) != over(1e-12), "trial {trial}, lane {k}");
                beyond += bit as usize;
                close += !bit as usize;
            }
            let (c1, c2) = (lanes(std::array::from_fn(|_| vec3(&mut rng))), lanes(std::array::from_fn(|_| vec3(&mut rng))));
            let reach2 = rng.random_range(0.0..3.0);
            let within = c1.within(&c2, reach2);
            for k in 0..4 {
                let (a, b) = (Vector3::new(c1.x.0[k], c1.y.0[k], c1.z.0[k]), Vector3::new(c2.x.0[k], c2.y.0[k], c2.z.0[k]));
                let dd = a - b;
                assert_eq!(within >> k & 1 == 1, (dd.x * dd.x + dd.y * dd.y) + dd.z * dd.z <= reach2, "trial {trial}, lane {k}");
            }
            // SAFETY: portable lanes.
            assert_eq!(unsafe { c1.within_in::<false>(&c2, reach2) }, within);
            #[cfg(target_arch = "x86_64")]
            if has_avx2() {
                // SAFETY: the CPU has AVX2.
                unsafe {
                    let bx = MemberBox { b1: 0, b2: 1, lim1: lim, lim2: [f64::INFINITY; 3] };
                    assert_eq!(boxes_close_avx2(&r, &l, &r, &l, &bx, &d, 0xf), !got & 0xf, "trial {trial}");
                    assert_eq!(boxes_close::<F4>(&r, &l, &r, &l, &bx, &d, 0xf), !got & 0xf, "trial {trial}");
                    assert_eq!(c1.within_avx2(&c2, reach2), within, "trial {trial}");
                    assert_eq!(c1.within_in::<true>(&c2, reach2), within, "trial {trial}");
                }
            }
        }
        assert!(beyond > 1000 && close > 1000, "{beyond} beyond, {close} close");
    }
}
