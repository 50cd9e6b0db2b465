//! Point clouds: a static obstacle that is the union of balls (a sensor's points, each with the
//! sensor's resolution as radius), labelled exactly against the robot's convex geoms.
//!
//! # The tree
//! The balls are kept in a bounding-volume tree over their centres: median splits along the
//! longest axis down to leaves of at most [`LEAF`] balls, nodes in depth-first order with a
//! `skip` link past their subtree (traversal without a stack), each node holding the box of its
//! centres and its largest radius. Centres and radii are stored apart (`x`, `y`, `z`, `r`: one
//! array each, in tree order) so that a leaf's tests run over contiguous lanes.
//!
//! # The query: one robot geom against every ball
//! For a convex geom `G` placed in the cloud's frame, the pair's signed distance is
//! `min_i sd(c_i, G) − r_i`, with `sd` the signed distance of a point to `G` (negative inside):
//! a ball of centre `c` and radius `r` is `sd(c, G) − r` from `G` (the nearest point of `G`
//! lies `sd` from `c`), and penetrates it by `r − sd(c, G)` when that is positive (the least
//! translation that separates a ball from a convex set moves its centre out to `r`).
//!
//! A [`Probe`] (the geom in the cloud frame) finds that minimum, or a ball below a threshold,
//! visiting only what may be below a bound:
//! - **nodes** are skipped on a lower bound of every ball below them: the distance from the
//!   geom's bounding sphere to the node's box, and the separation of the geom's oriented box from
//!   the node's box along the six face axes, less the node's largest radius;
//! - **balls** are skipped on the bounding sphere, then on the signed distance to the geom's box
//!   in its own frame (`G ⊂ box`, so the box's signed distance is at most `G`'s, inside too);
//! - what remains gets the exact signed distance: closed forms for spheres, boxes, capsules and
//!   cylinders; for a mesh's hull, the largest face-plane distance, which is exact inside and a
//!   lower bound outside, then GJK's projection (parry) where that bound is below the bound.
//!
//! Every bound is taken down by `SLACK` (relative and absolute 1e-9 m) for rounding, so what
//! is skipped is farther than the bound in exact arithmetic too: the minimum is exact whenever
//! it is below the bound, and otherwise the result is a lower bound above it.
//!
//! A leaf module: it knows nalgebra and the error type only; a shape enters through
//! [`PointDistance`] (`geometry/shapes.rs` implements it for the geoms' convex shapes).

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use crate::error::{invalid_input, Result};

/// A convex shape's signed distance from a point, what the queries need of a geom.
pub trait PointDistance {
    /// Signed distance from `p` (the shape's frame) to the shape, negative inside: `Ok(exact)`,
    /// or `Err(lower bound)` when a cheap bound already exceeds `bound`. Without `exact`, `Ok`
    /// may hold a lower bound instead (whatever is cheap and at most the distance).
    fn point_sd(&self, p: &Vector3<f64>, bound: f64, exact: bool) -> std::result::Result<f64, f64>;
}

/// Most balls a leaf holds.
pub const LEAF: usize = 8;

/// Relative and absolute (metres) slack taken off every lower bound before it skips anything.
const SLACK: f64 = 1e-9;

#[inline]
fn slacked(lb: f64) -> f64 {
    lb - SLACK * (1.0 + lb.abs())
}

/// One node of the tree: the box of its balls' centres, their largest radius, its balls
/// `start..end` (tree order) and the index of the node after its subtree.
#[derive(Clone, Copy, Debug)]
struct Node {
    centre: [f64; 3],
    half: [f64; 3],
    rmax: f64,
    start: u32,
    end: u32,
    skip: u32,
}

impl Node {
    #[inline]
    fn is_leaf(&self) -> bool {
        (self.end - self.start) as usize <= LEAF
    }
}

/// A point cloud as a union of balls, in a tree (module docs). Immutable once built.
#[derive(Debug)]
pub struct Cloud {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
    r: Vec<f64>,
    /// Input index of each ball in tree order.
    index: Vec<u32>,
    nodes: Vec<Node>,
}

/// What `Cloud::walk` hands its visitor: a node's lower bound, or a leaf's balls (tree positions).
enum Visit {
    Node(f64),
    Leaf(std::ops::Range<usize>),
}

/// The visitor's answer: skip the node's subtree, enter it (go on past a leaf), or stop.
enum Flow {
    Skip,
    Enter,
    Stop,
}

/// What [`Cloud::nearest`] found: `value` is the least `sd(c, G) − r` when it is below the
/// search's bound, else a lower bound above the bound; `ball` the ball that gave it, by its
/// position in the tree ([`Cloud::ball`]; `None` when the value is a bound).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    pub value: f64,
    pub ball: Option<u32>,
}

impl Cloud {
    /// The cloud of balls `centres[i]` (metres) of radius `radius[i]` (metres, ≥ 0). Refused:
    /// non-finite centres or radii, negative radii, lengths that differ, more than 2³² − 1 balls.
    /// An empty cloud is allowed (it is free space).
    pub fn new(centres: &[[f64; 3]], radius: &[f64]) -> Result<Self> {
        check_balls(centres, radius)?;
        let mut order: Vec<u32> = (0..centres.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * centres.len() / LEAF + 1);
        if !centres.is_empty() {
            build(&mut nodes, &mut order, centres, radius, 0);
        }
        let pick = |f: &dyn Fn(usize) -> f64| order.iter().map(|&i| f(i as usize)).collect::<Vec<f64>>();
        Ok(Cloud {
            x: pick(&|i| centres[i][0]),
            y: pick(&|i| centres[i][1]),
            z: pick(&|i| centres[i][2]),
            r: pick(&|i| radius[i]),
            index: order,
            nodes,
        })
    }

    pub fn len(&self) -> usize {
        self.r.len()
    }

    pub fn is_empty(&self) -> bool {
        self.r.is_empty()
    }

    /// Centre and half extents of the box holding every ball (zero for an empty cloud).
    pub fn bounds(&self) -> (Vector3<f64>, Vector3<f64>) {
        match self.nodes.first() {
            Some(n) => (Vector3::from(n.centre), Vector3::from(n.half).add_scalar(n.rmax)),
            None => (Vector3::zeros(), Vector3::zeros()),
        }
    }

    /// An upper bound on the distance from `c` to any point of any ball (rounded up by a
    /// relative 1e-12); 0 for an empty cloud.
    pub fn radius_about(&self, c: &Vector3<f64>) -> f64 {
        let far = (0..self.len())
            .map(|i| ((self.x[i] - c.x).powi(2) + (self.y[i] - c.y).powi(2) + (self.z[i] - c.z).powi(2)).sqrt() + self.r[i])
            .fold(0.0, f64::max);
        far * (1.0 + 1e-12)
    }

    /// The ball at tree position `t` (as [`Nearest::ball`] names it): centre, radius and its
    /// index in the input.
    pub fn ball(&self, t: u32) -> (Vector3<f64>, f64, u32) {
        let t = t as usize;
        (Vector3::new(self.x[t], self.y[t], self.z[t]), self.r[t], self.index[t])
    }

    /// The least `sd(c, G) − r` over the balls (module docs) for the geom of `probe`, visiting
    /// only what may be at most `bound`, and stopping at the first ball below `stop` (pass
    /// `-inf` for the minimum itself). Exact when the minimum is at most `bound` (and no ball
    /// was below `stop`); otherwise `value` is a lower bound above `bound`. `+inf` for an empty
    /// cloud.
    pub fn nearest<S: PointDistance>(&self, probe: &Probe<S>, bound: f64, stop: f64) -> Nearest {
        self.search(probe, bound, stop, true, None)
    }

    /// A lower bound on what [`Cloud::nearest`] gives, cheaper: each ball's distance may be a
    /// lower bound of it (a hull's face planes rather than GJK), so `value` is at most the least
    /// distance, and above `bound` only when the least distance is too. The motion certificate
    /// needs no more (`planning/motion.rs`).
    pub fn lower_bound<S: PointDistance>(&self, probe: &Probe<S>, bound: f64, stop: f64) -> Nearest {
        self.search(probe, bound, stop, false, None)
    }

    /// [`Cloud::nearest`] (`exact`) or [`Cloud::lower_bound`], the ball at tree position `hint`
    /// measured first (the nearest one last time, say: the search then starts with a tight
    /// bound). An exact answer does not depend on the hint; a lower bound may.
    pub fn search<S: PointDistance>(&self, probe: &Probe<S>, bound: f64, stop: f64, exact: bool, hint: Option<u32>) -> Nearest {
        let mut best = Nearest { value: f64::INFINITY, ball: None };
        if let Some(t) = hint.map(|t| t as usize).filter(|&t| t < self.len()) {
            let c = Vector3::new(self.x[t], self.y[t], self.z[t]);
            if let Ok(d) = probe.ball_distance(&c, self.r[t], bound, exact) {
                best = Nearest { value: d, ball: Some(t as u32) };
                if d < stop {
                    return best;
                }
            }
        }
        let mut skipped = f64::INFINITY;
        self.walk(probe, |visit| match visit {
            Visit::Node(lb) if lb > best.value.min(bound) => {
                skipped = skipped.min(lb);
                Flow::Skip
            }
            Visit::Node(_) => Flow::Enter,
            Visit::Leaf(balls) => {
                for t in balls {
                    let limit = best.value.min(bound);
                    let c = Vector3::new(self.x[t], self.y[t], self.z[t]);
                    match probe.ball_distance(&c, self.r[t], limit, exact) {
                        Err(lb) => skipped = skipped.min(lb),
                        Ok(d) if d < best.value => {
                            best = Nearest { value: d, ball: Some(t as u32) };
                            if d < stop {
                                return Flow::Stop;
                            }
                        }
                        Ok(_) => {}
                    }
                }
                Flow::Enter
            }
        });
        if best.value < stop || skipped >= best.value {
            best
        } else {
            Nearest { value: skipped, ball: None }
        }
    }

    /// Sets `near[i]` for every ball `i` (input order) with `sd(c, G) − r ≤ bound`.
    pub fn mark_within<S: PointDistance>(&self, probe: &Probe<S>, bound: f64, near: &mut [bool]) {
        self.walk(probe, |visit| match visit {
            Visit::Node(lb) if lb > bound => Flow::Skip,
            Visit::Node(_) => Flow::Enter,
            Visit::Leaf(balls) => {
                for t in balls {
                    let j = self.index[t] as usize;
                    if !near[j] {
                        let c = Vector3::new(self.x[t], self.y[t], self.z[t]);
                        near[j] = probe.ball_distance(&c, self.r[t], bound, true).is_ok_and(|d| d <= bound);
                    }
                }
                Flow::Enter
            }
        });
    }

    /// Depth first over the tree: each node's lower bound (`Probe::node_bound`, slacked) goes to
    /// `f` as `Visit::Node`, whose `Flow::Skip` skips its subtree; each leaf entered goes to `f` as
    /// its balls' tree positions; `Flow::Stop` ends the walk.
    fn walk<S: PointDistance>(&self, probe: &Probe<S>, mut f: impl FnMut(Visit) -> Flow) {
        let mut i = 0usize;
        while i < self.nodes.len() {
            let node = &self.nodes[i];
            match f(Visit::Node(slacked(probe.node_bound(node)))) {
                Flow::Stop => return,
                Flow::Skip => i = node.skip as usize,
                Flow::Enter if !node.is_leaf() => i += 1,
                Flow::Enter => {
                    if let Flow::Stop = f(Visit::Leaf(node.start as usize..node.end as usize)) {
                        return;
                    }
                    i = node.skip as usize;
                }
            }
        }
    }

    /// The least `n·c − offset − r` over the balls: their signed distance from the plane
    /// `n·x = offset` (`n` a unit normal; below it is inside), by a scan. `+inf` when empty.
    pub fn plane_distance(&self, n: &Vector3<f64>, offset: f64) -> Nearest {
        let mut best = Nearest { value: f64::INFINITY, ball: None };
        for t in 0..self.len() {
            let d = n.x * self.x[t] + n.y * self.y[t] + n.z * self.z[t] - offset - self.r[t];
            if d < best.value {
                best = Nearest { value: d, ball: Some(t as u32) };
            }
        }
        best
    }
}

/// `Ok` for balls a cloud can hold: as many radii as centres, fewer than 2³² − 1 of them, finite
/// centres, finite radii ≥ 0; else an error naming the first bad entry.
fn check_balls(centres: &[[f64; 3]], radius: &[f64]) -> Result<()> {
    if radius.len() != centres.len() {
        return invalid_input(format!("{} cloud points but {} radii", centres.len(), radius.len()));
    }
    if centres.len() >= u32::MAX as usize {
        return invalid_input(format!("{} cloud points is too many (at most {})", centres.len(), u32::MAX - 1));
    }
    if let Some(i) = centres.iter().position(|c| c.iter().any(|v| !v.is_finite())) {
        return invalid_input(format!("cloud point {i} is not finite ({:?})", centres[i]));
    }
    if let Some(i) = radius.iter().position(|r| !(r.is_finite() && *r >= 0.0)) {
        return invalid_input(format!("cloud radius {i} is {}; radii must be finite and >= 0", radius[i]));
    }
    Ok(())
}

/// Builds the subtree over `order` (balls `start..start + order.len()` in tree order).
fn build(nodes: &mut Vec<Node>, order: &mut [u32], c: &[[f64; 3]], r: &[f64], start: usize) {
    let me = nodes.len();
    let (mut lo, mut hi, mut rmax) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3], 0.0f64);
    for &i in order.iter() {
        let p = c[i as usize];
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
        rmax = rmax.max(r[i as usize]);
    }
    // The box's centre and half extents, the half extents rounded up so that the box holds
    // every centre in exact arithmetic too.
    let centre = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]));
    let half = [0, 1, 2].map(|a| ((hi[a] - centre[a]).max(centre[a] - lo[a])) * (1.0 + 1e-12) + 1e-15);
    nodes.push(Node { centre, half, rmax, start: start as u32, end: (start + order.len()) as u32, skip: 0 });
    if order.len() > LEAF {
        let axis = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
        let mid = order.len() / 2;
        order.select_nth_unstable_by(mid, |&a, &b| c[a as usize][axis].total_cmp(&c[b as usize][axis]).then(a.cmp(&b)));
        let (left, right) = order.split_at_mut(mid);
        build(nodes, left, c, r, start);
        build(nodes, right, c, r, start + mid);
    }
    nodes[me].skip = nodes.len() as u32;
}

/// One convex geom placed in a cloud's frame, with what the queries test it by (module docs).
pub struct Probe<'a, S: PointDistance> {
    convex: &'a S,
    /// The geom's frame in the cloud's frame.
    pose: Isometry3<f64>,
    rot: Matrix3<f64>,
    abs_rot: Matrix3<f64>,
    /// Its bounding sphere (cloud frame) and its box, centre (geom frame) and half extents.
    centre: Vector3<f64>,
    radius: f64,
    box_centre: Vector3<f64>,
    box_half: Vector3<f64>,
    /// The box's half extents along the cloud's axes.
    aabb_half: Vector3<f64>,
}

impl<'a, S: PointDistance> Probe<'a, S> {
    /// The geom `convex` (box `box_centre ± box_half` and bounding sphere of `radius` about the
    /// box centre, in its own frame) placed at `pose` in the cloud's frame.
    pub fn new(convex: &'a S, pose: Isometry3<f64>, box_centre: Vector3<f64>, box_half: Vector3<f64>, radius: f64) -> Self {
        let rot = pose.rotation.to_rotation_matrix().into_inner();
        let abs_rot = rot.abs();
        Probe {
            convex,
            centre: (pose * Point3::from(box_centre)).coords,
            pose,
            rot,
            abs_rot,
            radius,
            box_centre,
            box_half,
            aabb_half: abs_rot * box_half,
        }
    }

    /// A lower bound on `sd(c, G) − r` for every ball below `node` (module docs).
    #[inline]
    fn node_bound(&self, node: &Node) -> f64 {
        let (nc, nh) = (Vector3::from(node.centre), Vector3::from(node.half));
        let t = self.centre - nc;
        // The bounding sphere against the node's box: a lower bound on the signed distance too
        // (a point inside G is at most R − |p − centre| deep).
        let outside = (t.abs() - nh).sup(&Vector3::zeros());
        let sphere = outside.norm() - self.radius;
        // Face axes of both boxes: separations, counted only when positive (then every centre
        // in the node is that far from the geom's box, which holds G).
        let cloud_axes = (t.abs() - nh - self.aabb_half).max();
        let tl = self.rot.tr_mul(&t);
        let proj = self.abs_rot.tr_mul(&nh);
        let geom_axes = (tl.abs() - self.box_half - proj).max();
        let sep = cloud_axes.max(geom_axes);
        let lb = if sep > 0.0 { sphere.max(sep) } else { sphere };
        lb - node.rmax
    }

    /// `sd(c, G) − r` for the ball `(c, r)` (cloud frame) when it may be at most `bound`:
    /// `Ok(exact)`, or `Err(lower bound)` above `bound` (module docs).
    #[inline]
    fn ball_distance(&self, c: &Vector3<f64>, r: f64, bound: f64, exact: bool) -> std::result::Result<f64, f64> {
        let sphere = slacked((c - self.centre).norm() - self.radius - r);
        if sphere > bound {
            return Err(sphere);
        }
        let p = self.rot.tr_mul(&(c - self.pose.translation.vector));
        let in_box = slacked(box_sd(&(p - self.box_centre), &self.box_half) - r);
        if in_box > bound {
            return Err(in_box);
        }
        match self.convex.point_sd(&p, bound + r, exact) {
            Ok(d) => Ok(d - r),
            Err(lb) => Err(slacked(lb - r)),
        }
    }
}

/// Signed distance from `p` to the box `±h` (negative inside: minus the depth).
#[inline]
pub fn box_sd(p: &Vector3<f64>, h: &Vector3<f64>) -> f64 {
    let q = p.abs() - h;
    q.sup(&Vector3::zeros()).norm() + q.max().min(0.0)
}

/// Conservative voxel downsampling: the balls `(centres, radius)` grouped by the cube of side
/// `voxel` (metres) their centre falls in, each group replaced by one ball about the group's mean
/// centre whose radius reaches every ball of the group (`max |c_i − mean| + r_i`, rounded up), so
/// that the kept balls cover every ball they replace. Groups are kept in order of their first
/// ball; the result depends on the input alone.
pub fn voxel_downsample(centres: &[[f64; 3]], radius: &[f64], voxel: f64) -> Result<(Vec<[f64; 3]>, Vec<f64>)> {
    if !(voxel.is_finite() && voxel > 0.0) {
        return invalid_input(format!("voxel must be a positive number of metres; got {voxel}"));
    }
    check_balls(centres, radius)?;
    let cell = |p: &[f64; 3]| p.map(|v| (v / voxel).floor() as i64);
    let mut group: std::collections::HashMap<[i64; 3], usize> = std::collections::HashMap::with_capacity(centres.len() / 4);
    let mut of = Vec::with_capacity(centres.len());
    let mut sum: Vec<[f64; 4]> = Vec::new();
    for p in centres {
        let next = sum.len();
        let g = *group.entry(cell(p)).or_insert(next);
        if g == next {
            sum.push([0.0; 4]);
        }
        let s = &mut sum[g];
        s[0] += p[0];
        s[1] += p[1];
        s[2] += p[2];
        s[3] += 1.0;
        of.push(g);
    }
    let mean: Vec<[f64; 3]> = sum.iter().map(|s| [s[0] / s[3], s[1] / s[3], s[2] / s[3]]).collect();
    let mut reach = vec![0.0f64; mean.len()];
    for (i, p) in centres.iter().enumerate() {
        let m = &mean[of[i]];
        let d = ((p[0] - m[0]).powi(2) + (p[1] - m[1]).powi(2) + (p[2] - m[2]).powi(2)).sqrt();
        reach[of[i]] = reach[of[i]].max(d + radius[i]);
    }
    // (rounded up: the mean, the distance and the sum each round at ~1e-16 relative)
    let reach = reach.into_iter().map(|r| r * (1.0 + 1e-12) + 1e-12).collect();
    Ok((mean, reach))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::{Convex, GeomShape, GeomType, Solid};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_cloud(n: usize, seed: u64, r: f64) -> (Vec<[f64; 3]>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let c: Vec<[f64; 3]> =
            (0..n).map(|_| [rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5), rng.random_range(-0.3..0.3)]).collect();
        let rad = (0..n).map(|_| rng.random::<f64>() * r).collect();
        (c, rad)
    }

    fn shapes() -> Vec<GeomShape> {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let hull: Vec<Point3<f64>> =
            (0..60).map(|_| Point3::new(rng.random_range(-0.1..0.1), rng.random_range(-0.2..0.2), rng.random_range(-0.05..0.05))).collect();
        [
            (GeomType::Sphere, [0.08, 0.0, 0.0]),
            (GeomType::Capsule, [0.04, 0.15, 0.0]),
            (GeomType::Cylinder, [0.05, 0.12, 0.0]),
            (GeomType::Box, [0.1, 0.05, 0.07]),
            (GeomType::Mesh, [0.0; 3]),
        ]
        .into_iter()
        .map(|(k, s)| GeomShape::new(k, s, &hull, 0).unwrap().0)
        .collect()
    }

    /// The brute-force minimum: parry's signed point distance for every ball.
    fn brute(shape: &GeomShape, pose: &Isometry3<f64>, c: &[[f64; 3]], r: &[f64]) -> f64 {
        let Solid::Convex { shape: s, .. } = &shape.solid else { panic!() };
        c.iter()
            .zip(r)
            .map(|(p, r)| {
                let pl = pose.inverse_transform_point(&Point3::from(*p));
                let proj = s.project_local_point(&pl, false);
                let d = (pl - proj.point).norm();
                (if proj.is_inside { -d } else { d }) - r
            })
            .fold(f64::INFINITY, f64::min)
    }

    fn probe<'a>(shape: &'a GeomShape, pose: Isometry3<f64>) -> Probe<'a, Convex> {
        let Solid::Convex { convex, .. } = &shape.solid else { panic!() };
        Probe::new(convex, pose, shape.obb_center, shape.obb_half, shape.radius)
    }

    #[test]
    fn nearest_is_the_brute_force_minimum_for_every_shape() {
        let (c, r) = random_cloud(3000, 1, 0.01);
        let cloud = Cloud::new(&c, &r).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let (mut inside, mut outside) = (0, 0);
        for shape in shapes() {
            for _ in 0..200 {
                let t = Vector3::new(rng.random_range(-0.7..0.7), rng.random_range(-0.7..0.7), rng.random_range(-0.5..0.5));
                let a = Vector3::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0));
                let pose = Isometry3::new(t, a);
                let want = brute(&shape, &pose, &c, &r);
                let got = cloud.nearest(&probe(&shape, pose), f64::INFINITY, f64::NEG_INFINITY);
                assert!((got.value - want).abs() < 1e-7, "{:?}: {} vs {want}", shape.kind, got.value);
                // Bounded: exact below the bound, a lower bound above it.
                for bound in [-0.02, 0.0, 0.01, 0.05] {
                    let b = cloud.nearest(&probe(&shape, pose), bound, f64::NEG_INFINITY);
                    if want <= bound - 1e-7 {
                        assert!((b.value - want).abs() < 1e-7 && b.ball.is_some());
                    } else {
                        assert!(b.value <= want + 1e-7 && b.value > bound - 1e-7, "{} {want} {bound}", b.value);
                    }
                }
                let lb = cloud.lower_bound(&probe(&shape, pose), 0.03, f64::NEG_INFINITY).value;
                assert!(lb <= want + 1e-7 && (want > 0.03 || lb <= 0.03 + 1e-7), "{lb} vs {want}");
                if want < 0.0 {
                    inside += 1;
                } else {
                    outside += 1;
                }
            }
        }
        assert!(inside > 100 && outside > 100, "{inside} {outside}");
    }

    #[test]
    fn mark_within_marks_exactly_the_balls_within_the_bound() {
        let (c, r) = random_cloud(2000, 4, 0.0);
        let cloud = Cloud::new(&c, &r).unwrap();
        let shapes = shapes();
        let pose = Isometry3::new(Vector3::new(0.1, -0.05, 0.02), Vector3::new(0.3, 0.2, 1.0));
        for shape in &shapes {
            let mut near = vec![false; c.len()];
            cloud.mark_within(&probe(shape, pose), 0.02, &mut near);
            for (i, p) in c.iter().enumerate() {
                let d = brute(shape, &pose, &[*p], &[0.0]);
                if (d - 0.02).abs() > 1e-7 {
                    assert_eq!(near[i], d <= 0.02, "{:?} point {i}: {d}", shape.kind);
                }
            }
            assert!(near.iter().any(|&b| b));
        }
    }

    #[test]
    fn voxel_downsampling_covers_every_ball_it_removes() {
        let (c, r) = random_cloud(20_000, 5, 0.004);
        let (m, mr) = voxel_downsample(&c, &r, 0.1).unwrap();
        assert!(m.len() < c.len() / 5, "{}", m.len());
        let kept = Cloud::new(&m, &mr).unwrap();
        // Each input ball lies inside some kept ball: its centre is within (kept r − its r).
        let tiny = GeomShape::new(GeomType::Sphere, [1e-9, 0.0, 0.0], &[], 0).unwrap().0;
        for (p, rad) in c.iter().zip(&r).step_by(7) {
            let pose = Isometry3::translation(p[0], p[1], p[2]);
            let mut covered = false;
            for (k, kr) in m.iter().zip(&mr) {
                let d = ((p[0] - k[0]).powi(2) + (p[1] - k[1]).powi(2) + (p[2] - k[2]).powi(2)).sqrt();
                covered |= d + rad <= *kr;
            }
            assert!(covered, "{p:?}");
            assert!(kept.nearest(&probe(&tiny, pose), 0.0, f64::NEG_INFINITY).value < 0.0);
        }
        // Deterministic, and bad input refused by name.
        assert_eq!(voxel_downsample(&c, &r, 0.1).unwrap(), (m, mr));
        assert!(voxel_downsample(&c, &r, 0.0).is_err());
        assert!(voxel_downsample(&[[f64::NAN, 0.0, 0.0]], &[0.0], 0.1).unwrap_err().to_string().contains("point 0"));
    }

    #[test]
    fn bad_clouds_are_refused_by_name_and_empty_is_free() {
        let e = Cloud::new(&[[0.0; 3], [0.0, f64::NAN, 0.0]], &[0.1, 0.1]).unwrap_err().to_string();
        assert!(e.contains("point 1"), "{e}");
        let e = Cloud::new(&[[0.0; 3]], &[-0.1]).unwrap_err().to_string();
        assert!(e.contains("radius 0") && e.contains("-0.1"), "{e}");
        assert!(Cloud::new(&[[0.0; 3]], &[]).is_err());
        let empty = Cloud::new(&[], &[]).unwrap();
        let shape = &shapes()[0];
        assert_eq!(empty.nearest(&probe(shape, Isometry3::identity()), 1.0, 0.0).value, f64::INFINITY);
    }
}
