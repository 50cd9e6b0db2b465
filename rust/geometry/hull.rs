//! A mesh's convex hull for the hot path: support points by hill climbing over the hull's edge
//! graph, started (and often finished) by a cube map of directions.
//!
//! Support points are exactly parry's for the same hull (`ConvexPolyhedron`'s linear scan,
//! `scan_support` here): same vertex, ties to the lowest index, so GJK on a `Hull` is
//! bit-identical to GJK on parry's shape. A leaf module: it knows parry and nalgebra only.

use nalgebra::{Point3, Vector3};
use parry3d_f64::shape::ConvexPolyhedron;

/// A mesh's convex hull with vertex adjacency, for support points by hill climbing.
///
/// On a convex polytope a vertex no neighbour of which lies further along `dir` is a global
/// maximum, so climbing the hull's edge graph visits a handful of vertices instead of scanning
/// all of them. Ties are broken like parry's scan (lowest index among the maximal vertices).
pub struct Hull {
    /// The hull's vertices, exactly `ConvexPolyhedron::points()` of `poly`.
    points: Vec<Point3<f64>>,
    /// Neighbours of vertex `i` are `adj[adj_start[i]..adj_start[i + 1]]` (compressed rows).
    adj_start: Vec<u32>,
    adj: Vec<u32>,
    /// Starting vertex per cube-map cell of directions (the support along the cell's centre
    /// direction), so that the climb usually ends after checking one vertex's neighbours;
    /// flagged `SOLE` where that vertex is the answer for the whole cell and no climb is needed
    /// (about a third of GJK's calls on the Panda's hulls). u16 keeps the table in L1.
    start: Vec<u16>,
    /// Some vertex has no hull edge (never expected): fall back to the linear scan.
    scan: bool,
    /// parry's own hull (boxed: it is large, and only the cold paths use it).
    poly: Box<ConvexPolyhedron>,
    /// Each face's plane `n·x = d` (unit outward `n`): a point's largest `n·p − d` is its
    /// signed distance inside the hull and a lower bound on its distance outside.
    planes: Vec<(Vector3<f64>, f64)>,
    /// The mean of the vertices (inside the hull).
    centre: Vector3<f64>,
}

impl Hull {
    /// The convex hull of `points`, built exactly as `ConvexPolyhedron::from_convex_hull` does.
    pub fn new(points: &[Point3<f64>]) -> Option<Self> {
        let (vertices, triangles) = parry3d_f64::transformation::try_convex_hull(points).ok()?;
        let poly = ConvexPolyhedron::from_convex_mesh(vertices.clone(), &triangles)?;
        let n = vertices.len();
        let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); n];
        for t in &triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if !nbrs[a as usize].contains(&b) {
                    nbrs[a as usize].push(b);
                }
                if !nbrs[b as usize].contains(&a) {
                    nbrs[b as usize].push(a);
                }
            }
        }
        // (Cube-map entries hold 15-bit vertex indices; MuJoCo's hulls are far smaller.)
        let scan = n >= SOLE as usize || nbrs.iter().any(|v| v.is_empty());
        let mut adj_start = vec![0u32];
        let mut adj = Vec::new();
        for v in &nbrs {
            adj.extend_from_slice(v);
            adj_start.push(adj.len() as u32);
        }
        let start: Vec<u16> = (0..6 * CUBE * CUBE).map(|cell| cell_start(&vertices, cell)).collect();
        let adjacent = poly.vertices_adj_to_face();
        let planes = poly
            .faces()
            .iter()
            .map(|f| {
                let n = f.normal.into_inner();
                // The face's largest offset over its vertices (they agree up to rounding): the
                // plane never cuts into the hull, so the bounds it gives stay lower bounds.
                let first = f.first_vertex_or_edge as usize;
                let d = adjacent[first..first + f.num_vertices_or_edges as usize]
                    .iter()
                    .map(|&v| n.dot(&vertices[v as usize].coords))
                    .fold(f64::NEG_INFINITY, f64::max);
                (n, d + 1e-12 * (1.0 + d.abs()))
            })
            .collect();
        let centre = vertices.iter().map(|v| v.coords).sum::<Vector3<f64>>() / n as f64;
        Some(Hull { points: vertices, adj_start, adj, start, scan, poly: Box::new(poly), planes, centre })
    }

    /// The hull's vertices (those of `poly()`, in the same order).
    pub fn points(&self) -> &[Point3<f64>] {
        &self.points
    }

    /// The mean of the vertices: a point inside the hull.
    pub fn centre(&self) -> Vector3<f64> {
        self.centre
    }

    /// The face planes `(n, d)`: `n·x ≤ d` holds for every point of the hull.
    pub fn planes(&self) -> &[(Vector3<f64>, f64)] {
        &self.planes
    }

    /// parry's own hull, for the cold paths (exact distances, contacts, bounds).
    pub fn poly(&self) -> &ConvexPolyhedron {
        &self.poly
    }

    /// The support point along `dir`: `points()[support_index(dir)]`, parry's scan result.
    #[inline]
    pub fn support_point(&self, dir: &Vector3<f64>) -> Point3<f64> {
        self.points[self.support_index(dir)]
    }

    #[inline]
    fn neighbours(&self, i: usize) -> &[u32] {
        &self.adj[self.adj_start[i] as usize..self.adj_start[i + 1] as usize]
    }

    /// Index of the support vertex along `dir`: the lowest index among the vertices of
    /// maximal `p . dir`, as `scan_support` (parry's scan) returns.
    #[inline]
    pub fn support_index(&self, dir: &Vector3<f64>) -> usize {
        if self.scan {
            return scan_support(&self.points, dir);
        }
        let (cell, plain) = cube_cell_plain(dir);
        let start = self.start[cell];
        if plain && start & SOLE != 0 {
            return (start & !SOLE) as usize;
        }
        let mut cur = (start & !SOLE) as usize;
        let mut cur_dot = self.points[cur].coords.dot(dir);
        if cur_dot.is_nan() {
            return 0; // the scan never replaces vertex 0 when every dot is NaN
        }
        loop {
            let (mut next, mut next_dot, mut tie) = (cur, cur_dot, false);
            for &j in self.neighbours(cur) {
                let d = self.points[j as usize].coords.dot(dir);
                if d > next_dot {
                    (next, next_dot) = (j as usize, d);
                } else if d == cur_dot {
                    tie = true;
                }
            }
            if next == cur {
                return if tie { self.lowest_on_plateau(cur, cur_dot, dir) } else { cur };
            }
            (cur, cur_dot) = (next, next_dot);
        }
    }

    /// Lowest index among the vertices connected to `from` through vertices of the same
    /// (maximal) dot product: the tie the scan resolves by taking the first.
    #[cold]
    fn lowest_on_plateau(&self, from: usize, top: f64, dir: &Vector3<f64>) -> usize {
        let mut seen = vec![from];
        let mut stack = vec![from];
        while let Some(i) = stack.pop() {
            for &j in self.neighbours(i) {
                let j = j as usize;
                if !seen.contains(&j) && self.points[j].coords.dot(dir) == top {
                    seen.push(j);
                    stack.push(j);
                }
            }
        }
        seen.into_iter().min().unwrap_or(from)
    }
}

/// Cells per cube-map face side: 6 * CUBE^2 starting vertices per hull (3 KiB). Finer grids
/// certify more cells but fall out of L1 (32: 12 KiB a hull, no faster on the Panda).
const CUBE: usize = 16;

/// Flag on a cube-map cell's vertex: it is the support of every direction in the cell, with a
/// lead over every other vertex that rounding cannot overturn (see `cell_start`).
const SOLE: u16 = 1 << 15;

/// Cube-map cell of a direction: the face of its largest component, then a CUBE x CUBE grid
/// over the other two components divided by it. Any cell is a valid start (the climb is exact);
/// a zero or NaN direction just lands in some cell.
#[cfg(test)]
#[inline]
fn cube_cell(d: &Vector3<f64>) -> usize {
    cube_cell_plain(d).0
}

/// `cube_cell`, and whether `d` is a plain direction for which the cell's `SOLE` vertex may be
/// trusted: no NaN, largest component in [1e-100, 1e100] (so no product in a dot with a hull
/// vertex overflows, and underflow is negligible against the certified lead).
#[inline]
fn cube_cell_plain(d: &Vector3<f64>) -> (usize, bool) {
    let a = d.abs();
    let (m, u, v) = if a.x >= a.y && a.x >= a.z {
        (0, d.y, d.z)
    } else if a.y >= a.z {
        (1, d.z, d.x)
    } else {
        (2, d.x, d.y)
    };
    let face = 2 * m + (d[m] > 0.0) as usize;
    let scale = 0.5 * CUBE as f64 / a[m];
    // The grid index, truncated: the value clamped into [0, CUBE - 1] first (NaN to 0, as a
    // saturating cast gives it), so the conversion needs no range checks.
    let index = |w: f64| {
        let x = ((w * scale) + 0.5 * CUBE as f64).max(0.0).min((CUBE - 1) as f64);
        // SAFETY: `x` is finite and in [0, CUBE - 1] (`max` takes 0 over NaN).
        unsafe { x.to_int_unchecked::<u32>() as usize }
    };
    let (iu, iv) = (index(u), index(v));
    let plain = a[m] >= 1e-100 && a[m] <= 1e100 && !(u + v).is_nan();
    ((face * CUBE + iu) * CUBE + iv, plain)
}

/// The starting vertex of a cube-map cell: the support along the cell's centre direction, with
/// `SOLE` set when that vertex is provably what parry's scan returns for *every* direction
/// that `cube_cell_plain` maps to the cell, so that the climb can be skipped.
///
/// The directions of a cell, scaled to their largest component, fill the cell's square on the
/// cube face, up to rounding in `cube_cell` (~1e-15); we take the square grown by 1e-9 a side,
/// whose directions are the non-negative combinations of its four corners `c_i`. If
/// `(p_v - p_k) . c_i > t_k` at every corner for every other vertex `k`, then
/// `(p_v - p_k) . d > t_k |d|_inf` for every direction `d` of the cell, by linearity. With
/// `t_k = 2e-12 (|p_v|_1 + |p_k|_1)`, a thousand times the rounding error of any of these dot products,
/// `v`'s computed dot is strictly the largest: the scan (first maximum) returns `v`.
fn cell_start(points: &[Point3<f64>], cell: usize) -> u16 {
    let centre = cube_cell_centre(cell);
    let v = scan_support(points, &centre);
    let (face, iu, iv) = (cell / (CUBE * CUBE), (cell / CUBE) % CUBE, cell % CUBE);
    let (m, sign) = (face / 2, if face % 2 == 1 { 1.0 } else { -1.0 });
    let edge = |i: usize| (i as f64 / CUBE as f64) * 2.0 - 1.0;
    let grow = 1e-9;
    let mut corners = [Vector3::zeros(); 4];
    for (c, (u, w)) in corners.iter_mut().zip([(iu, iv), (iu + 1, iv), (iu, iv + 1), (iu + 1, iv + 1)]) {
        c[m] = sign;
        c[(m + 1) % 3] = edge(u) + if u == iu { -grow } else { grow };
        c[(m + 2) % 3] = edge(w) + if w == iv { -grow } else { grow };
    }
    // Half the square's side (plus growth): how far a corner lies from the centre, per axis.
    let half = 1.0 / CUBE as f64 + 2.0 * grow;
    let pv = points[v].coords;
    let sole = pv.abs().max() < 1e100
        && points.iter().enumerate().all(|(k, p)| {
            if k == v {
                return true;
            }
            let diff = pv - p.coords;
            let t = 2e-12 * (pv.abs().sum() + p.coords.abs().sum());
            // Lead at the centre, less what the corners can lose: enough for all four?
            let l1 = diff.abs().sum();
            diff.dot(&centre) - l1 * half > 2.0 * t || corners.iter().all(|c| diff.dot(c) > t)
        });
    v as u16 | if sole { SOLE } else { 0 }
}

/// The centre direction of a cube-map cell (inverse of `cube_cell`).
fn cube_cell_centre(cell: usize) -> Vector3<f64> {
    let (face, iu, iv) = (cell / (CUBE * CUBE), (cell / CUBE) % CUBE, cell % CUBE);
    let (m, sign) = (face / 2, if face % 2 == 1 { 1.0 } else { -1.0 });
    let coord = |i: usize| ((i as f64 + 0.5) / CUBE as f64) * 2.0 - 1.0;
    let mut d = Vector3::zeros();
    d[m] = sign;
    d[(m + 1) % 3] = coord(iu);
    d[(m + 2) % 3] = coord(iv);
    d
}

/// parry's point-cloud support (`utils::point_cloud_support_point_id`): first maximal vertex.
fn scan_support(points: &[Point3<f64>], dir: &Vector3<f64>) -> usize {
    let mut best = 0;
    let mut best_dot = points[0].coords.dot(dir);
    for (i, p) in points.iter().enumerate().skip(1) {
        let d = p.coords.dot(dir);
        if d > best_dot {
            (best, best_dot) = (i, d);
        }
    }
    best
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use parry3d_f64::shape::SupportMap;
    use rand::{Rng, SeedableRng};

    /// `n` seeded directions in the cube [-1, 1)³ (shared with the shape tests).
    pub(crate) fn random_dirs(n: usize, seed: u64) -> Vec<Vector3<f64>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0))).collect()
    }

    #[test]
    fn cube_cells_round_trip_their_centres() {
        for cell in 0..6 * CUBE * CUBE {
            assert_eq!(cube_cell(&cube_cell_centre(cell)), cell);
            assert_eq!(cube_cell(&(cube_cell_centre(cell) * 3.5)), cell);
        }
        assert!(cube_cell(&Vector3::zeros()) < 6 * CUBE * CUBE);
        assert!(cube_cell(&Vector3::repeat(f64::NAN)) < 6 * CUBE * CUBE);
    }

    #[test]
    fn sole_cube_cells_give_the_scan_vertex_up_to_their_corners() {
        // Directions pushed into the corners and edges of every certified cell, where a wrong
        // certificate would first show, and the cell's own corner directions.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let cloud: Vec<Point3<f64>> = (0..150)
            .map(|_| Point3::new(rng.random_range(-0.1..0.1), rng.random_range(-0.05..0.05), rng.random_range(-0.2..0.2)))
            .collect();
        let hull = Hull::new(&cloud).unwrap();
        let mut sole = 0;
        for cell in 0..6 * CUBE * CUBE {
            if hull.start[cell] & SOLE == 0 {
                continue;
            }
            sole += 1;
            let (face, iu, iv) = (cell / (CUBE * CUBE), (cell / CUBE) % CUBE, cell % CUBE);
            let (m, sign): (usize, f64) = (face / 2, if face % 2 == 1 { 1.0 } else { -1.0 });
            for _ in 0..20 {
                let t = |i: usize, r: f64| ((i as f64 + r) / CUBE as f64) * 2.0 - 1.0;
                let pick = |rng: &mut rand_chacha::ChaCha8Rng| [0.0, 1e-12, 0.5, 1.0 - 1e-12][rng.random_range(0..4)];
                let mut d: Vector3<f64> = Vector3::zeros();
                d[m] = sign * rng.random_range(0.1..10.0);
                d[(m + 1) % 3] = t(iu, pick(&mut rng)) * d[m].abs();
                d[(m + 2) % 3] = t(iv, pick(&mut rng)) * d[m].abs();
                if cube_cell(&d) == cell {
                    assert_eq!(hull.support_index(&d), scan_support(hull.points(), &d), "cell {cell} dir {d:?}");
                }
            }
        }
        assert!(sole > 6 * CUBE * CUBE / 4, "{sole}");
    }

    #[test]
    fn hull_support_matches_parry_scan_on_random_and_axis_directions() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        // A random cloud (interior points dropped by the hull) and a box with coplanar faces,
        // whose axis-aligned directions make ties that must resolve like the scan.
        let cloud: Vec<Point3<f64>> =
            (0..300).map(|_| Point3::new(rng.random_range(-1.0..1.0), rng.random_range(-0.5..0.5), rng.random_range(-0.2..0.3))).collect();
        let mut boxy = Vec::new();
        for x in [-1.0, 0.0, 1.0] {
            for y in [-2.0, 0.0, 2.0] {
                for z in [-0.5, 0.5] {
                    boxy.push(Point3::new(x, y, z));
                }
            }
        }
        let mut dirs = random_dirs(20_000, 4);
        for a in [-1.0, 0.0, 1.0] {
            for b in [-1.0, 0.0, 1.0] {
                for c in [-1.0, 0.0, 1.0] {
                    dirs.push(Vector3::new(a, b, c));
                }
            }
        }
        for pts in [cloud, boxy] {
            let hull = Hull::new(&pts).unwrap();
            assert!(!hull.scan);
            assert_eq!(hull.points(), hull.poly.points());
            for d in &dirs {
                assert_eq!(hull.support_index(d), scan_support(hull.points(), d), "dir {d:?}");
                assert_eq!(hull.support_point(d), hull.poly.local_support_point(d));
            }
        }
    }
}
