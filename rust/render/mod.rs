//! The differentiable Gaussian renderer after forward kinematics, in one native call each way:
//! EWA projection, spherical-harmonic colour, tile rasterization (`render/splat.rs`), and the
//! backward of all three fused, from image gradients to the 3D Gaussians and the cameras.
//! Generic over [`Real`] (`f32` for float32 tensors, `f64` for gradient checks).
//!
//! # Views
//! `P` poses of the same `N` Gaussians (world means `μ` `[P, N, 3]`, covariances `Σ`
//! `[P, N, 3, 3]`) are seen from `C` cameras; the images are the `V` views `(pose, camera)`
//! listed in `views` (all `P × C`, pose-major, for a robot; `(c, c)` when each camera has its
//! own Gaussians). Opacities and colours are shared by every view or given per view.
//!
//! # Projection (identical to `render/rasterize.py: project`)
//! Camera `[R | t]` (world to camera, OpenCV) and `K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`:
//!
//! ```text
//! x = R μ + t,   u = fx x₀/x₂ + cx,   v = fy x₁/x₂ + cy,   depth z = x₂
//! J = [[fx/z, 0, -fx x̃/z], [0, fy/z, -fy ỹ/z]]   (x̃, ỹ: x₀/z, x₁/z clamped to the image
//!                                                  plus 15 % of its size each side)
//! M = J R (2 × 3),   Σ₂ = M Σ Mᵀ + 0.3 I = [[a, b], [b, c]],   conic = (c, -b, a) / (ac - b²)
//! ```
//!
//! Gaussians with `z ≤ 0.01` m are not drawn (and get no gradient).
//!
//! # Colour (identical to `render/gaussians.py: eval_sh`)
//! SH coefficients `f_k` (degree 0–2, 3DGS's basis and signs) live in each Gaussian's frame
//! `F` (`[P, N, 3, 3]`, frame to world): the viewing direction is `d = Fᵀ (μ - o_c)` with the
//! camera centre `o_c = -Rᵀ t`, normalised, and `colour = max(0, Σ_k Y_k(d̂) f_k + 1/2)`.
//! Plain per-Gaussian colours are the other mode.
//!
//! # Backward
//! Each step's Jacobian is written out beside its forward (`project_backward`,
//! `sh_backward`): conic → 2-D covariance → `M` → (`J`, `R`) → camera-frame point → `μ`,
//! `Σ`, `R`, `t`, `fx`, `fy`, `cx`, `cy`; colour → coefficients and direction → `F`, `μ`, `R`,
//! `t`. The clamps pass gradients where torch's do: the Jacobian's clamp sends them to the
//! bound (so to `K`), the colour's clamp and the depth clamp stop them.
//!
//! # Determinism
//! Per (view, Gaussian) gradients are computed independently; sums over views, poses and
//! Gaussians (the shared parameters, the cameras) run in a fixed order, cameras in fixed
//! chunks of Gaussians. Bit-identical for any thread count.
//!
//! The folder is the renderer, apart from the labeller: [`real`] (the float types), [`splat`]
//! (the rasterizer), this module (projection, colour, the fused backward) and [`images`] (the
//! images finished and compared).

pub mod images;
pub mod real;
pub mod splat;

use rayon::prelude::*;

use crate::error::{invalid_input, Result};
use crate::render::real::{first_non_finite, Real};
use crate::render::splat::{Cutoff, Splats, NEAR};

/// EWA low-pass filter added to the 2-D covariance (px²).
pub const LOWPASS: f64 = 0.3;
/// The projection Jacobian's `x/z`, `y/z` are clamped to the image plus this share of its size on each side.
pub const JACOBIAN_MARGIN: f64 = 0.15;
const SH_C0: f64 = 0.282_094_791_773_878_14;
const SH_C1: f64 = 0.488_602_511_902_919_9;
const SH_C2: [f64; 5] =
    [1.092_548_430_592_079_2, -1.092_548_430_592_079_2, 0.315_391_565_252_520_05, -1.092_548_430_592_079_2, 0.546_274_215_296_039_6];
/// Gaussians per chunk of the camera-gradient sums (fixed: the sums do not depend on threads).
const CHUNK: usize = 1024;

/// A pinhole camera: world-to-camera `[R | t]` and intrinsics (pixels, centres at integers).
#[derive(Clone, Copy, Debug)]
pub struct Camera<T> {
    pub r: [[T; 3]; 3],
    pub t: [T; 3],
    pub fx: T,
    pub fy: T,
    pub cx: T,
    pub cy: T,
}

/// Where the colours come from.
#[derive(Clone, Debug)]
pub enum Colors<T> {
    /// `coeffs` `[N, nsh, 3]` (`nsh` 1, 4 or 9) in each Gaussian's frame (the scene's
    /// `frames`, required when `nsh > 1`).
    Sh { nsh: usize, coeffs: Vec<T> },
    /// `[V, N, 3]` when `per_view`, else `[N, 3]`.
    Rgb { per_view: bool, rgb: Vec<T> },
}

/// Gaussians rigidly attached to the bodies of `P` poses:
///
/// ```text
/// μ = R_b m + x_b,   A = R_b Q,   Σ = A diag(s²) Aᵀ,   frame = R_b
/// ```
///
/// with each Gaussian's body `b`, local mean `m` (m), rotation `Q` and scales `s` (m).
#[derive(Clone, Debug)]
pub struct Rigid<T> {
    pub nbody: usize,
    /// `[P, nbody, 3, 3]` body rotations (row-major) and `[P, nbody, 3]` positions (m).
    pub body_rot: Vec<T>,
    pub body_pos: Vec<T>,
    /// `[N]` each Gaussian's body.
    pub body: Vec<u32>,
    /// `[N, 3]` local means (m), each Gaussian's rotation `Q` in its body, `[N, 3]` scales (m).
    pub means: Vec<T>,
    pub rots: LocalRots<T>,
    pub scales: Vec<T>,
}

/// The Gaussians' rotations in their bodies, as the caller keeps them.
#[derive(Clone, Debug)]
pub enum LocalRots<T> {
    /// `[N, 3, 3]` row-major matrices.
    Matrices(Vec<T>),
    /// `[N, 4]` quaternions `(w, x, y, z)` of any nonzero norm: `Q` is that of `q / |q|`
    /// (`kinematics.py: quat_to_matrix`), and the gradient comes back through the
    /// normalisation. Saves the caller a batched quaternion-to-matrix op and its backward.
    Quats(Vec<T>),
}

impl<T: Real> LocalRots<T> {
    /// The input's name and values per Gaussian (for the checks).
    fn named(&self) -> (&'static str, &Vec<T>, usize) {
        match self {
            LocalRots::Matrices(m) => ("local_rots", m, 9),
            LocalRots::Quats(q) => ("local_quats", q, 4),
        }
    }

    /// `[N, 9]` row-major matrices (computed from quaternions, or borrowed).
    fn matrices(&self) -> std::borrow::Cow<'_, [T]> {
        match self {
            LocalRots::Matrices(m) => std::borrow::Cow::Borrowed(m),
            LocalRots::Quats(q) => {
                let mut m = vec![T::zero(); q.len() / 4 * 9];
                m.par_chunks_mut(9).zip(q.par_chunks(4)).for_each(|(m, q)| m.copy_from_slice(&quat_matrix([q[0], q[1], q[2], q[3]])));
                std::borrow::Cow::Owned(m)
            }
        }
    }
}

/// `|q|` and `q / |q|`.
#[inline(always)]
fn unit_quat<T: Real>(q: [T; 4]) -> (T, [T; 4]) {
    let len = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    (len, q.map(|c| c / len))
}

/// The rotation matrix (row-major) of `q / |q|`, `q = (w, x, y, z)`, by the formula of
/// `kinematics.py: quat_to_matrix`:
///
/// ```text
/// [[1 - 2(y² + z²), 2(xy - wz),     2(xz + wy)    ],
///  [2(xy + wz),     1 - 2(x² + z²), 2(yz - wx)    ],
///  [2(xz - wy),     2(yz + wx),     1 - 2(x² + y²)]]
/// ```
#[inline]
pub(crate) fn quat_matrix<T: Real>(q: [T; 4]) -> [T; 9] {
    let (_, [w, x, y, z]) = unit_quat(q);
    let (one, two) = (T::one(), T::c(2.0));
    [
        one - two * (y * y + z * z),
        two * (x * y - w * z),
        two * (x * z + w * y),
        two * (x * y + w * z),
        one - two * (x * x + z * z),
        two * (y * z - w * x),
        two * (x * z - w * y),
        two * (y * z + w * x),
        one - two * (x * x + y * y),
    ]
}

/// `∂L/∂q` from `g = ∂L/∂Q` (row-major) for [`quat_matrix`]: first w.r.t. the unit `q̂`, entry
/// by entry of the formula (e.g. `∂/∂x̂ = 2(ŷ g01 + ẑ g02 + ŷ g10 - 2x̂ g11 - ŵ g12 + ẑ g20 +
/// ŵ g21 - 2x̂ g22)`), then through `q̂ = q / |q|`: `(g_q̂ - q̂ (q̂ · g_q̂)) / |q|`.
#[inline]
pub(crate) fn quat_matrix_backward<T: Real>(q: [T; 4], g: &[T]) -> [T; 4] {
    let (len, [w, x, y, z]) = unit_quat(q);
    let two = T::c(2.0);
    let gh = [
        two * (-z * g[1] + y * g[2] + z * g[3] - x * g[5] - y * g[6] + x * g[7]),
        two * (y * g[1] + z * g[2] + y * g[3] - two * x * g[4] - w * g[5] + z * g[6] + w * g[7] - two * x * g[8]),
        two * (-two * y * g[0] + x * g[1] + w * g[2] + x * g[3] + z * g[5] - w * g[6] + z * g[7] - two * y * g[8]),
        two * (-two * z * g[0] - w * g[1] + x * g[2] + w * g[3] - two * z * g[4] + y * g[5] + x * g[6] + y * g[7]),
    ];
    let dot = w * gh[0] + x * gh[1] + y * gh[2] + z * gh[3];
    let qh = [w, x, y, z];
    std::array::from_fn(|k| (gh[k] - qh[k] * dot) / len)
}

/// Which gradients a backward computes. The scene's world (or body) gradients always are (every
/// other one chains through them); each group here can be left out, and then comes back empty
/// (length 0): a pose fit needs none of them (its model and cameras are constants), and skips
/// the colour coefficients' products, the camera sums of every (view, Gaussian) and the
/// Gaussians' local chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Needs {
    /// SH coefficients or colours.
    pub colors: bool,
    pub opacity: bool,
    /// `viewmats` and `ks`.
    pub cameras: bool,
    /// The rigid mode's local means, rotations (or quaternions) and scales.
    pub local: bool,
}

impl Needs {
    /// Every gradient.
    pub const ALL: Needs = Needs { colors: true, opacity: true, cameras: true, local: true };
}

/// Gradients w.r.t. [`Rigid`]'s arrays, same layouts (`means`, `rots`, `scales` empty when the
/// local gradients are not needed).
#[derive(Clone, Debug)]
pub struct RigidGrads<T> {
    pub body_rot: Vec<T>,
    pub body_pos: Vec<T>,
    pub means: Vec<T>,
    /// In the layout of [`Rigid::rots`]' variant (`[N, 3, 3]` or `[N, 4]`).
    pub rots: Vec<T>,
    pub scales: Vec<T>,
}

/// `A B` for row-major 3 × 3 matrices.
#[inline(always)]
fn mat_mul<T: Real>(a: &[T], b: &[T]) -> [T; 9] {
    let mut c = [T::zero(); 9];
    for i in 0..3 {
        for j in 0..3 {
            c[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
        }
    }
    c
}

impl<T: Real> Rigid<T> {
    /// World means `[P, N, 3]`, covariances `[P, N, 9]` and frames `[P, N, 9]`.
    fn world(&self, poses: usize) -> (Vec<T>, Vec<T>, Vec<T>) {
        let n = self.body.len();
        let rots = self.rots.matrices();
        let mut means = vec![T::zero(); 3 * poses * n];
        let mut covs = vec![T::zero(); 9 * poses * n];
        let mut frames = vec![T::zero(); 9 * poses * n];
        means.par_chunks_mut(3).zip(covs.par_chunks_mut(9)).zip(frames.par_chunks_mut(9)).enumerate().for_each(
            |(k, ((mu, cov), frame))| {
                let (p, i) = (k / n, k % n);
                let b = p * self.nbody + self.body[i] as usize;
                let r = &self.body_rot[9 * b..9 * b + 9];
                let m = [self.means[3 * i], self.means[3 * i + 1], self.means[3 * i + 2]];
                let rm = mat_vec(r, m);
                let a = mat_mul(r, &rots[9 * i..9 * i + 9]);
                let s2 = [0, 1, 2].map(|k| self.scales[3 * i + k] * self.scales[3 * i + k]);
                for d in 0..3 {
                    mu[d] = rm[d] + self.body_pos[3 * b + d];
                }
                for x in 0..3 {
                    for y in 0..3 {
                        cov[3 * x + y] =
                            a[3 * x] * s2[0] * a[3 * y] + a[3 * x + 1] * s2[1] * a[3 * y + 1] + a[3 * x + 2] * s2[2] * a[3 * y + 2];
                    }
                }
                frame.copy_from_slice(r);
            },
        );
        (means, covs, frames)
    }

    /// Chains the world gradients (`g_means` `[P, N, 3]`, `g_covs` `[P, N, 9]`, `g_frames`
    /// `[P, N, 9]` or None) to the rigid inputs; sums in a fixed order (bodies: chunk by chunk).
    fn backward(&self, poses: usize, g_means: &[T], g_covs: &[T], g_frames: Option<&[T]>, local_needed: bool) -> RigidGrads<T> {
        let n = self.body.len();
        let nb = self.nbody;
        let zero = T::zero();
        let rots = self.rots.matrices();
        // per chunk: its Gaussians' local gradients and its partial body sums [P, nb, 12]
        let chunks: Vec<(Vec<[T; 15]>, Vec<T>)> = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|k| {
                let (i0, i1) = (k * CHUNK, ((k + 1) * CHUNK).min(n));
                let mut local = vec![[zero; 15]; if local_needed { i1 - i0 } else { 0 }];
                let mut bodies = vec![zero; poses * nb * 12];
                for p in 0..poses {
                    for i in i0..i1 {
                        let b = self.body[i] as usize;
                        let r = &self.body_rot[9 * (p * nb + b)..9 * (p * nb + b) + 9];
                        let q = &rots[9 * i..9 * i + 9];
                        let a = mat_mul(r, q);
                        let s = [self.scales[3 * i], self.scales[3 * i + 1], self.scales[3 * i + 2]];
                        let g_mu = &g_means[3 * (p * n + i)..3 * (p * n + i) + 3];
                        let g_cov = &g_covs[9 * (p * n + i)..9 * (p * n + i) + 9];
                        // Σ_xy = Σ_k A_xk s_k² A_yk: ∂/∂A_xk = Σ_y (G_xy + G_yx) s_k² A_yk, ∂/∂s_k = 2 s_k Σ_xy G_xy A_xk A_yk
                        let mut g_a = [zero; 9];
                        let mut g_s = [zero; 3];
                        for x in 0..3 {
                            for kk in 0..3 {
                                let mut acc = zero;
                                for y in 0..3 {
                                    acc = acc + (g_cov[3 * x + y] + g_cov[3 * y + x]) * a[3 * y + kk];
                                }
                                g_a[3 * x + kk] = acc * s[kk] * s[kk];
                            }
                        }
                        if local_needed {
                            for kk in 0..3 {
                                let mut acc = zero;
                                for x in 0..3 {
                                    for y in 0..3 {
                                        acc = acc + g_cov[3 * x + y] * a[3 * x + kk] * a[3 * y + kk];
                                    }
                                }
                                g_s[kk] = T::c(2.0) * s[kk] * acc;
                            }
                        }
                        // A = R Q: ∂/∂R = G_A Qᵀ, ∂/∂Q = Rᵀ G_A; μ = R m + x: ∂/∂R += g_μ mᵀ, ∂/∂m = Rᵀ g_μ
                        let m = [self.means[3 * i], self.means[3 * i + 1], self.means[3 * i + 2]];
                        let gb = &mut bodies[12 * (p * nb + b)..12 * (p * nb + b) + 12];
                        for x in 0..3 {
                            for y in 0..3 {
                                let mut acc = g_mu[x] * m[y];
                                for kk in 0..3 {
                                    acc = acc + g_a[3 * x + kk] * q[3 * y + kk];
                                }
                                if let Some(gf) = g_frames {
                                    acc = acc + gf[9 * (p * n + i) + 3 * x + y];
                                }
                                gb[3 * x + y] = gb[3 * x + y] + acc;
                            }
                            gb[9 + x] = gb[9 + x] + g_mu[x];
                        }
                        if !local_needed {
                            continue;
                        }
                        let l = &mut local[i - i0];
                        let g_m = mat_t_vec(r, [g_mu[0], g_mu[1], g_mu[2]]);
                        for x in 0..3 {
                            l[x] = l[x] + g_m[x];
                            l[12 + x] = l[12 + x] + g_s[x];
                            for y in 0..3 {
                                // (Rᵀ G_A)_xy = Σ_k R_kx G_A,ky
                                let v = r[x] * g_a[y] + r[3 + x] * g_a[3 + y] + r[6 + x] * g_a[6 + y];
                                l[3 + 3 * x + y] = l[3 + 3 * x + y] + v;
                            }
                        }
                    }
                }
                // a quaternion's gradient from its matrix's, here in parallel (slots 3..7)
                if let LocalRots::Quats(q) = &self.rots {
                    for (i, l) in (i0..i1).zip(local.iter_mut()) {
                        let g_q = quat_matrix_backward([q[4 * i], q[4 * i + 1], q[4 * i + 2], q[4 * i + 3]], &l[3..12]);
                        l[3..7].copy_from_slice(&g_q);
                    }
                }
                (local, bodies)
            })
            .collect();
        let mut g = RigidGrads {
            body_rot: vec![zero; poses * nb * 9],
            body_pos: vec![zero; poses * nb * 3],
            means: Vec::with_capacity(3 * n),
            rots: Vec::with_capacity(self.rots.named().2 * n),
            scales: Vec::with_capacity(3 * n),
        };
        for (local, bodies) in &chunks {
            for l in local {
                g.means.extend_from_slice(&l[0..3]);
                match &self.rots {
                    LocalRots::Matrices(_) => g.rots.extend_from_slice(&l[3..12]),
                    LocalRots::Quats(_) => g.rots.extend_from_slice(&l[3..7]),
                }
                g.scales.extend_from_slice(&l[12..15]);
            }
            for pb in 0..poses * nb {
                for x in 0..9 {
                    g.body_rot[9 * pb + x] = g.body_rot[9 * pb + x] + bodies[12 * pb + x];
                }
                for x in 0..3 {
                    g.body_pos[3 * pb + x] = g.body_pos[3 * pb + x] + bodies[12 * pb + 9 + x];
                }
            }
        }
        g
    }
}

/// Everything one render call draws.
#[derive(Clone, Debug)]
pub struct Scene<T> {
    pub poses: usize,
    pub n: usize,
    pub width: usize,
    pub height: usize,
    /// `[P, N, 3]` world means, metres (empty when `rigid` gives them).
    pub means: Vec<T>,
    /// `[P, N, 3, 3]` world covariances, m² (row-major; empty when `rigid` gives them).
    pub covs: Vec<T>,
    /// `[P, N, 3, 3]` each Gaussian's frame to world (row-major), for SH of degree ≥ 1 (the
    /// body rotation when `rigid` gives them).
    pub frames: Option<Vec<T>>,
    /// Gaussians rigidly attached to bodies: means, covariances and frames from the bodies'
    /// poses (see [`Rigid`]).
    pub rigid: Option<Rigid<T>>,
    /// `[V, N]` when `opacity_per_view`, else `[N]`.
    pub opacity: Vec<T>,
    pub opacity_per_view: bool,
    pub colors: Colors<T>,
    pub cameras: Vec<Camera<T>>,
    /// `(pose, camera)` of each image.
    pub views: Vec<[usize; 2]>,
    pub cutoff: Cutoff,
}

/// Forward outputs (images `[V, H, W, ...]`, as the rasterizer's) and the backward's state.
pub type Forward<T> = splat::Forward<T, State<T>>;

/// What the backward needs: the scene and the rasterizer's state.
#[derive(Clone, Debug)]
pub struct State<T> {
    pub scene: Scene<T>,
    splat: splat::State<T>,
}

/// Gradients w.r.t. the scene's inputs, in their layouts. `frames` only for SH of degree ≥ 1;
/// `colors` holds the SH coefficients' gradient or the plain colours'; `viewmats` `[C, 4, 4]`
/// and `ks` `[C, 3, 3]` have zeros where the inputs are constants.
#[derive(Clone, Debug)]
pub struct Grads<T> {
    pub means: Vec<T>,
    pub covs: Vec<T>,
    pub frames: Option<Vec<T>>,
    pub colors: Vec<T>,
    pub opacity: Vec<T>,
    pub viewmats: Vec<T>,
    pub ks: Vec<T>,
    /// The rigid inputs' gradients, when the scene had them (then `means`, `covs`, `frames`
    /// are the intermediate world gradients).
    pub rigid: Option<RigidGrads<T>>,
}

/// One (view, Gaussian)'s projection and what its backward reuses.
#[derive(Clone, Copy, Debug, Default)]
struct Proj<T> {
    x: [T; 3],
    iz: T,
    xz: T,
    yz: T,
    /// The clamped `x/z`, `y/z` of the Jacobian, and which side clamped (-1 low, 0, +1 high).
    txz: T,
    tyz: T,
    side: [i8; 2],
    m0: [T; 3],
    m1: [T; 3],
    abc: [T; 3],
    det: T,
    det_clamped: bool,
    uv: [T; 2],
    conic: [T; 3],
}

#[inline(always)]
fn dot3<T: Real>(a: [T; 3], b: [T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `Σ m` for a row-major 3 × 3 `Σ`.
#[inline(always)]
fn mat_vec<T: Real>(s: &[T], m: [T; 3]) -> [T; 3] {
    [s[0] * m[0] + s[1] * m[1] + s[2] * m[2], s[3] * m[0] + s[4] * m[1] + s[5] * m[2], s[6] * m[0] + s[7] * m[1] + s[8] * m[2]]
}

/// `Σᵀ m`.
#[inline(always)]
fn mat_t_vec<T: Real>(s: &[T], m: [T; 3]) -> [T; 3] {
    [s[0] * m[0] + s[3] * m[1] + s[6] * m[2], s[1] * m[0] + s[4] * m[1] + s[7] * m[2], s[2] * m[0] + s[5] * m[1] + s[8] * m[2]]
}

/// The Jacobian clamp's bounds on `x/z` (or `y/z`): the image's extent (pixel edges -1/2 and
/// `size - 1/2`) plus [`JACOBIAN_MARGIN`] of its size each side, back through `f`, `c`.
#[inline(always)]
fn clamp_bounds<T: Real>(f: T, c: T, size: usize) -> (T, T) {
    let s = T::c(size as f64);
    let (half, m) = (T::c(0.5), T::c(JACOBIAN_MARGIN));
    ((-half - c - m * s) / f, (s - half - c + m * s) / f)
}

#[inline(always)]
fn clamp_side<T: Real>(x: T, lo: T, hi: T) -> (T, i8) {
    // torch.maximum(torch.minimum(x, hi), lo)
    let m = if x > hi { (hi, 1) } else { (x, 0) };
    if m.0 < lo {
        (lo, -1)
    } else {
        m
    }
}

/// EWA projection of mean `mu`, covariance `cov` (row-major 3 × 3) into `cam`.
#[inline(always)]
fn project<T: Real>(mu: [T; 3], cov: &[T], cam: &Camera<T>, width: usize, height: usize) -> Proj<T> {
    let r = &cam.r;
    let x = [dot3(r[0], mu) + cam.t[0], dot3(r[1], mu) + cam.t[1], dot3(r[2], mu) + cam.t[2]];
    let iz = T::one() / x[2].max(T::c(NEAR));
    let (xz, yz) = (x[0] * iz, x[1] * iz);
    let uv = [cam.fx * xz + cam.cx, cam.fy * yz + cam.cy];
    let (lx, hx) = clamp_bounds(cam.fx, cam.cx, width);
    let (ly, hy) = clamp_bounds(cam.fy, cam.cy, height);
    let (txz, sx) = clamp_side(xz, lx, hx);
    let (tyz, sy) = clamp_side(yz, ly, hy);
    // M = J R: row 0 = fx/z (R₀ - x̃ R₂), row 1 = fy/z (R₁ - ỹ R₂)
    let (fxz, fyz) = (cam.fx * iz, cam.fy * iz);
    let m0 = [0, 1, 2].map(|j| fxz * (r[0][j] - txz * r[2][j]));
    let m1 = [0, 1, 2].map(|j| fyz * (r[1][j] - tyz * r[2][j]));
    let (sm0, sm1) = (mat_vec(cov, m0), mat_vec(cov, m1));
    let lp = T::c(LOWPASS);
    let abc = [dot3(m0, sm0) + lp, dot3(m0, sm1), dot3(m1, sm1) + lp];
    let raw_det = abc[0] * abc[2] - abc[1] * abc[1];
    let det_clamped = raw_det < T::c(1e-12);
    let det = if det_clamped { T::c(1e-12) } else { raw_det };
    let conic = [abc[2] / det, -abc[1] / det, abc[0] / det];
    Proj { x, iz, xz, yz, txz, tyz, side: [sx, sy], m0, m1, abc, det, det_clamped, uv, conic }
}

/// Gradients of [`project`]: from `(g_uv, g_conic, g_z)` to the mean, the covariance (full
/// 3 × 3) and the camera (`[R (9), t (3), fx, fy, cx, cy]`, added into `g_cam`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn project_backward<T: Real>(
    p: &Proj<T>,
    mu: [T; 3],
    cov: &[T],
    cam: &Camera<T>,
    g_uv: [T; 2],
    g_conic: [T; 3],
    g_z: T,
    g_cam: Option<&mut [T; 16]>,
) -> ([T; 3], [T; 9]) {
    let zero = T::zero();
    let two = T::c(2.0);
    let [a, b, c] = p.abc;
    let det = p.det;
    // conic = (c, -b, a) / det, det = ac - b²
    let [ga_, gb_, gc_] = g_conic;
    let g_det = if p.det_clamped { zero } else { -(ga_ * p.conic[0] + gb_ * p.conic[1] + gc_ * p.conic[2]) / det };
    let ga = gc_ / det + g_det * c;
    let gb = -gb_ / det - two * g_det * b;
    let gc = ga_ / det + g_det * a;
    // a = m₀ᵀΣm₀, b = m₀ᵀΣm₁, c = m₁ᵀΣm₁: ∂/∂Σ_ij = ga m₀ᵢm₀ⱼ + gb m₀ᵢm₁ⱼ + gc m₁ᵢm₁ⱼ
    let (m0, m1) = (p.m0, p.m1);
    let mut g_cov = [zero; 9];
    for i in 0..3 {
        for j in 0..3 {
            g_cov[3 * i + j] = ga * m0[i] * m0[j] + gb * m0[i] * m1[j] + gc * m1[i] * m1[j];
        }
    }
    let (sm0, sm1, stm0, stm1) = (mat_vec(cov, m0), mat_vec(cov, m1), mat_t_vec(cov, m0), mat_t_vec(cov, m1));
    let g_m0 = [0, 1, 2].map(|k| ga * (sm0[k] + stm0[k]) + gb * sm1[k]);
    let g_m1 = [0, 1, 2].map(|k| gc * (sm1[k] + stm1[k]) + gb * stm0[k]);
    // m₀ⱼ = fx iz (R₀ⱼ - x̃ R₂ⱼ), m₁ⱼ = fy iz (R₁ⱼ - ỹ R₂ⱼ)
    let r = &cam.r;
    let (fxz, fyz) = (cam.fx * p.iz, cam.fy * p.iz);
    let (mut g_fxz, mut g_fyz, mut g_txz, mut g_tyz) = (zero, zero, zero, zero);
    for j in 0..3 {
        g_fxz = g_fxz + g_m0[j] * (r[0][j] - p.txz * r[2][j]);
        g_fyz = g_fyz + g_m1[j] * (r[1][j] - p.tyz * r[2][j]);
        g_txz = g_txz - g_m0[j] * fxz * r[2][j];
        g_tyz = g_tyz - g_m1[j] * fyz * r[2][j];
    }
    let (mut g_fx, mut g_fy, mut g_cx, mut g_cy) = (g_fxz * p.iz, g_fyz * p.iz, zero, zero);
    let mut g_iz = g_fxz * cam.fx + g_fyz * cam.fy;
    // x̃ = clamp(x/z, lo, hi); lo = (-1/2 - cx - m W)/fx, hi = (W - 1/2 - cx + m W)/fx
    let (mut g_xz, mut g_yz) = (zero, zero);
    match p.side[0] {
        0 => g_xz = g_xz + g_txz,
        _ => {
            g_cx = g_cx - g_txz / cam.fx;
            g_fx = g_fx - g_txz * p.txz / cam.fx;
        }
    }
    match p.side[1] {
        0 => g_yz = g_yz + g_tyz,
        _ => {
            g_cy = g_cy - g_tyz / cam.fy;
            g_fy = g_fy - g_tyz * p.tyz / cam.fy;
        }
    }
    // u = fx x/z + cx, v = fy y/z + cy
    let [gu, gv] = g_uv;
    g_fx = g_fx + gu * p.xz;
    g_fy = g_fy + gv * p.yz;
    g_cx = g_cx + gu;
    g_cy = g_cy + gv;
    g_xz = g_xz + gu * cam.fx;
    g_yz = g_yz + gv * cam.fy;
    // x/z = x₀ iz, y/z = x₁ iz, iz = 1 / max(x₂, NEAR)
    g_iz = g_iz + g_xz * p.x[0] + g_yz * p.x[1];
    let mut g_x = [g_xz * p.iz, g_yz * p.iz, g_z];
    if p.x[2] > T::c(NEAR) {
        g_x[2] = g_x[2] - g_iz * p.iz * p.iz;
    }
    // x = R μ + t
    let g_mu = mat_t_vec(&[r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2]], g_x);
    if let Some(g_cam) = g_cam {
        // M's rows (R₀ - x̃ R₂, R₁ - ỹ R₂ scaled) and x = R μ + t, w.r.t. R, t and the intrinsics
        for j in 0..3 {
            g_cam[j] = g_cam[j] + g_m0[j] * fxz;
            g_cam[3 + j] = g_cam[3 + j] + g_m1[j] * fyz;
            g_cam[6 + j] = g_cam[6 + j] - g_m0[j] * fxz * p.txz - g_m1[j] * fyz * p.tyz;
        }
        for i in 0..3 {
            for j in 0..3 {
                g_cam[3 * i + j] = g_cam[3 * i + j] + g_x[i] * mu[j];
            }
            g_cam[9 + i] = g_cam[9 + i] + g_x[i];
        }
        g_cam[12] = g_cam[12] + g_fx;
        g_cam[13] = g_cam[13] + g_fy;
        g_cam[14] = g_cam[14] + g_cx;
        g_cam[15] = g_cam[15] + g_cy;
    }
    (g_mu, g_cov)
}

/// The SH basis `Y_k(d)` (`nsh` values) of a unit direction, 3DGS's signs.
#[inline(always)]
fn sh_basis<T: Real>(nsh: usize, d: [T; 3]) -> [T; 9] {
    let mut y = [T::zero(); 9];
    y[0] = T::c(SH_C0);
    if nsh > 1 {
        let [x, yy, z] = d;
        let c1 = T::c(SH_C1);
        y[1] = -c1 * yy;
        y[2] = c1 * z;
        y[3] = -c1 * x;
        if nsh > 4 {
            y[4] = T::c(SH_C2[0]) * x * yy;
            y[5] = T::c(SH_C2[1]) * yy * z;
            y[6] = T::c(SH_C2[2]) * (T::c(2.0) * z * z - x * x - yy * yy);
            y[7] = T::c(SH_C2[3]) * x * z;
            y[8] = T::c(SH_C2[4]) * (x * x - yy * yy);
        }
    }
    y
}

/// `Σ_k Y_k f_k + 1/2` per channel (before the clamp at 0), for one Gaussian's coefficients
/// `c` (`[nsh, 3]`) and basis `y`.
#[inline(always)]
fn sh_color<T: Real>(nsh: usize, c: &[T], y: &[T; 9]) -> [T; 3] {
    let mut col = [T::c(0.5); 3];
    for k in 0..nsh {
        for ch in 0..3 {
            col[ch] = col[ch] + y[k] * c[3 * k + ch];
        }
    }
    col
}

/// `∂Y_k/∂d` (rows k, columns x, y, z) for `k < nsh`.
#[inline(always)]
fn sh_basis_grad<T: Real>(nsh: usize, d: [T; 3]) -> [[T; 3]; 9] {
    let zero = T::zero();
    let mut g = [[zero; 3]; 9];
    if nsh > 1 {
        let [x, y, z] = d;
        let c1 = T::c(SH_C1);
        g[1] = [zero, -c1, zero];
        g[2] = [zero, zero, c1];
        g[3] = [-c1, zero, zero];
        if nsh > 4 {
            let two = T::c(2.0);
            let c2 = SH_C2.map(T::c);
            g[4] = [c2[0] * y, c2[0] * x, zero];
            g[5] = [zero, c2[1] * z, c2[1] * y];
            g[6] = [-two * c2[2] * x, -two * c2[2] * y, T::c(4.0) * c2[2] * z];
            g[7] = [c2[3] * z, zero, c2[3] * x];
            g[8] = [two * c2[4] * x, -two * c2[4] * y, zero];
        }
    }
    g
}

/// The camera centre `o = -Rᵀ t`.
#[inline(always)]
fn centre<T: Real>(cam: &Camera<T>) -> [T; 3] {
    let (r, t) = (&cam.r, &cam.t);
    [0, 1, 2].map(|k| -(r[0][k] * t[0] + r[1][k] * t[1] + r[2][k] * t[2]))
}

/// The viewing direction in the Gaussian's frame `F` (row-major 3 × 3, frame to world):
/// `Fᵀ (μ - o)`, its length (clamped at 1e-9) and the unit vector.
#[inline(always)]
fn view_dir<T: Real>(mu: [T; 3], o: [T; 3], f: &[T]) -> ([T; 3], [T; 3], T, bool) {
    let d = [mu[0] - o[0], mu[1] - o[1], mu[2] - o[2]];
    let loc = mat_t_vec(f, d);
    let len = dot3(loc, loc).sqrt();
    let clamped = len < T::c(1e-9);
    let len = if clamped { T::c(1e-9) } else { len };
    (d, [loc[0] / len, loc[1] / len, loc[2] / len], len, clamped)
}

impl<T: Real> Scene<T> {
    fn nviews(&self) -> usize {
        self.views.len()
    }

    /// Shapes, finiteness, views and cameras; errors name the entry.
    fn check(&self) -> Result<()> {
        let (p, n, v, c) = (self.poses, self.n, self.nviews(), self.cameras.len());
        if n == 0 {
            return invalid_input("render: the Gaussian set is empty (N = 0)");
        }
        if v == 0 || c == 0 || p == 0 {
            return invalid_input(format!("render: nothing to draw ({p} poses, {c} cameras, {v} views)"));
        }
        if self.width == 0 || self.height == 0 {
            return invalid_input(format!("render: image size must be positive; got {}x{}", self.width, self.height));
        }
        let (ov, cv) = (
            if self.opacity_per_view { v } else { 1 },
            match &self.colors {
                Colors::Rgb { per_view: true, .. } => v,
                _ => 1,
            },
        );
        let mut arrays: Vec<(&str, &Vec<T>, usize, usize)> = vec![("opacities", &self.opacity, ov, n)];
        match &self.rigid {
            None => {
                arrays.push(("means", &self.means, p, n * 3));
                arrays.push(("covs", &self.covs, p, n * 9));
                if let Some(f) = &self.frames {
                    arrays.push(("frames", f, p, n * 9));
                }
            }
            Some(r) => {
                let nb = r.nbody;
                if r.body.len() != n {
                    return invalid_input(format!("render: body holds {} entries; expected {n}", r.body.len()));
                }
                if let Some(i) = r.body.iter().position(|&b| b as usize >= nb) {
                    return invalid_input(format!("render: body[{i}] = {} is out of range ({nb} bodies)", r.body[i]));
                }
                arrays.push(("body_rot", &r.body_rot, p, nb * 9));
                arrays.push(("body_pos", &r.body_pos, p, nb * 3));
                arrays.push(("local_means", &r.means, 1, n * 3));
                let (name, rots, per) = r.rots.named();
                arrays.push((name, rots, 1, n * per));
                arrays.push(("scales", &r.scales, 1, n * 3));
            }
        }
        match &self.colors {
            Colors::Sh { nsh, coeffs } => {
                if ![1, 4, 9].contains(nsh) {
                    return invalid_input(format!("render: SH coefficients per Gaussian must be 1, 4 or 9; got {nsh}"));
                }
                arrays.push(("sh", coeffs, 1, n * nsh * 3));
                if *nsh > 1 && self.frames.is_none() && self.rigid.is_none() {
                    return invalid_input("render: SH of degree >= 1 need the Gaussians' frames");
                }
            }
            Colors::Rgb { rgb, .. } => arrays.push(("colors", rgb, cv, n * 3)),
        }
        for (name, a, rows, per) in arrays {
            if a.len() != rows * per {
                return invalid_input(format!("render: {name} holds {} values; expected {rows} x {per}", a.len()));
            }
            // (scanned in parallel blocks; the first non-finite entry is then found in order)
            if let Some(k) = first_non_finite(a) {
                let (r, i) = (k / per, (k % per) / (per / n).max(1));
                return invalid_input(format!("render: {name}[{r}, {i}] is {:?}", a[k].f64()));
            }
        }
        if let Some(Rigid { rots: LocalRots::Quats(q), .. }) = &self.rigid {
            let unusable = |q: &[T]| {
                let norm2 = q.iter().fold(T::zero(), |acc, &c| acc + c * c);
                !(norm2 > T::zero() && norm2.is_finite())
            };
            if let Some(i) = q.chunks_exact(4).position(unusable) {
                let q = &q[4 * i..4 * i + 4];
                return invalid_input(format!(
                    "render: local_quats[{i}] = {:?} has no usable norm (zero, or too small or too large to square): a rotation needs a nonzero quaternion",
                    q.iter().map(|c| c.f64()).collect::<Vec<_>>()
                ));
            }
        }
        for (k, cam) in self.cameras.iter().enumerate() {
            let vals = cam.r.iter().flatten().chain(&cam.t).chain([&cam.fx, &cam.fy, &cam.cx, &cam.cy]);
            if vals.clone().any(|x| !x.is_finite()) {
                return invalid_input(format!("render: camera {k} (viewmats or Ks) contains NaN or inf"));
            }
            if !(cam.fx > T::zero() && cam.fy > T::zero()) {
                return invalid_input(format!(
                    "render: Ks[{k}] focal lengths must be positive; got fx {:?}, fy {:?}",
                    cam.fx.f64(),
                    cam.fy.f64()
                ));
            }
        }
        for (k, &[pp, cc]) in self.views.iter().enumerate() {
            if pp >= p || cc >= c {
                return invalid_input(format!("render: views[{k}] = ({pp}, {cc}) is out of range ({p} poses, {c} cameras)"));
            }
        }
        if (v * n) as u64 > u32::MAX as u64 {
            return invalid_input("render: too many views x Gaussians for 32-bit indices");
        }
        // the images and the tile lists are indexed with 32 bits; beyond, a clear error, not
        // an allocation that aborts the process
        let pixels = (v as u128) * (self.width as u128) * (self.height as u128);
        let tiles = (v as u128) * (self.width.div_ceil(splat::TILE) as u128) * (self.height.div_ceil(splat::TILE) as u128);
        if pixels > (1u128 << 31) || tiles > u32::MAX as u128 {
            return invalid_input(format!(
                "render: {v} views of {}x{} pixels are too many for one call (at most 2^31 pixels): render fewer views per call",
                self.width, self.height
            ));
        }
        // the images (colour, depth, alpha) in T
        crate::budget::check("render: views x height x width", &[pixels as usize, 5], std::mem::size_of::<T>())?;
        Ok(())
    }

    #[inline(always)]
    fn mean(&self, pose: usize, i: usize) -> [T; 3] {
        let k = 3 * (pose * self.n + i);
        [self.means[k], self.means[k + 1], self.means[k + 2]]
    }

    #[inline(always)]
    fn cov(&self, pose: usize, i: usize) -> &[T] {
        let k = 9 * (pose * self.n + i);
        &self.covs[k..k + 9]
    }

    #[inline(always)]
    fn opacity(&self, v: usize, i: usize) -> T {
        self.opacity[if self.opacity_per_view { v * self.n + i } else { i }]
    }

    /// Gaussian `i`'s frame in pose `pose` (row-major 3 × 3), when the SH need one.
    #[inline(always)]
    fn frame(&self, pose: usize, i: usize, nsh: usize) -> Option<&[T]> {
        let k = 9 * (pose * self.n + i);
        self.frames.as_ref().filter(|_| nsh > 1).map(|f| &f[k..k + 9])
    }

    /// The colour of Gaussian `i` in view `v` before the clamp at 0 (SH), or the given colour.
    #[inline(always)]
    fn color(&self, v: usize, i: usize, mu: [T; 3], o: [T; 3]) -> [T; 3] {
        match &self.colors {
            Colors::Rgb { per_view, rgb } => {
                let k = 3 * (if *per_view { v * self.n + i } else { i });
                [rgb[k], rgb[k + 1], rgb[k + 2]]
            }
            Colors::Sh { nsh, coeffs } => {
                let d = self.frame(self.views[v][0], i, *nsh).map_or([T::zero(); 3], |f| view_dir(mu, o, f).1);
                sh_color(*nsh, &coeffs[3 * nsh * i..3 * nsh * (i + 1)], &sh_basis(*nsh, d))
            }
        }
    }
}

/// Renders `scene` (see the module docs). Errors name the offending input.
pub fn forward<T: Real>(mut scene: Scene<T>) -> Result<Forward<T>> {
    scene.check()?;
    if let Some(r) = &scene.rigid {
        let (means, covs, frames) = r.world(scene.poses);
        scene.means = means;
        scene.covs = covs;
        scene.frames = Some(frames);
    }
    let (n, v) = (scene.n, scene.nviews());
    let centres: Vec<[T; 3]> = scene.cameras.iter().map(centre).collect();
    // Projection and colour of every (view, Gaussian), straight into the rasterizer's arrays,
    // in parallel; a conic that is not positive definite is marked by a NaN centre and named
    // below.
    let mut splats = Splats {
        cameras: v,
        n,
        width: scene.width,
        height: scene.height,
        uv: vec![T::zero(); 2 * v * n],
        conic: vec![T::zero(); 3 * v * n],
        opacity: vec![T::zero(); v * n],
        color: vec![T::zero(); 3 * v * n],
        depth: vec![T::zero(); v * n],
        cutoff: scene.cutoff,
    };
    let Splats { uv, conic, opacity, color, depth, .. } = &mut splats;
    splat::for_each_gaussian(uv, conic, opacity, color, depth, |k, uv, conic, opacity, color, depth| {
        let (view, i) = (k / n, k % n);
        let [pose, c] = scene.views[view];
        let cam = &scene.cameras[c];
        let mu = scene.mean(pose, i);
        let p = project(mu, scene.cov(pose, i), cam, scene.width, scene.height);
        *opacity = scene.opacity(view, i);
        *depth = p.x[2];
        if p.x[2].f64() <= NEAR {
            // not drawn: any positive-definite conic keeps the rasterizer's checks simple
            conic.copy_from_slice(&[T::one(), T::zero(), T::one()]);
            return;
        }
        color.copy_from_slice(&scene.color(view, i, mu, centres[c]).map(|x| x.max(T::zero())));
        let [a, b, cc] = p.conic;
        let finite = p.uv.iter().chain(&p.conic).all(|x| x.is_finite());
        let u = if finite && a > T::zero() && cc > T::zero() && a * cc - b * b > T::zero() { p.uv[0] } else { T::nan() };
        uv.copy_from_slice(&[u, p.uv[1]]);
        conic.copy_from_slice(&p.conic);
    });
    if let Some(k) = splats.uv.iter().step_by(2).position(|u| u.is_nan()) {
        let (view, i) = (k / n, k % n);
        let [pose, c] = scene.views[view];
        let [a, b, cc] = [0, 1, 2].map(|j| splats.conic[3 * k + j].f64());
        return invalid_input(format!(
            "render: covs[{pose}, {i}] projects to a 2D covariance that is not positive definite in camera {c} \
             (conics[{view}, {i}] = ({a:?}, {b:?}, {cc:?})): a covariance must be positive semi-definite"
        ));
    }
    Ok(splat::forward_checked(splats)?.with_state(|splat| State { scene, splat }))
}

/// One (view, Gaussian)'s gradient w.r.t. its inputs (the camera's is added to a running sum).
#[derive(Clone, Copy, Debug, Default)]
struct Local<T> {
    mu: [T; 3],
    cov: [T; 9],
    frame: [T; 9],
    /// The SH coefficients' (`3 nsh`) or the colour's (3) gradient.
    color: [T; 27],
    opacity: T,
}

/// The gradient of Gaussian `i` in view `view` from the rasterizer's gradients `g2`; the
/// camera's part is added to `g_cam`.
// The Jacobians below are written entry by entry, indices as in the formulas beside them.
// (On the function: a `#![allow]` in `render/mod.rs` would reach its submodules too.)
#[allow(clippy::needless_range_loop)]
#[inline(always)]
fn local_backward<T: Real>(
    s: &Scene<T>,
    g2: &splat::Grads<T>,
    centres: &[[T; 3]],
    view: usize,
    i: usize,
    needs: Needs,
    g_cam: &mut [T; 16],
) -> Local<T> {
    let zero = T::zero();
    let n = s.n;
    let mut out = Local::default();
    let [pose, ci] = s.views[view];
    let cam = &s.cameras[ci];
    let g = view * n + i;
    // A Gaussian that composited no pixel of this view has zero gradients from the
    // rasterizer, so every gradient below is exactly zero: skip it (most hidden Gaussians).
    let untouched = g2.uv[2 * g] == zero
        && g2.uv[2 * g + 1] == zero
        && g2.conic[3 * g..3 * g + 3].iter().all(|&x| x == zero)
        && g2.opacity[g] == zero
        && g2.color[3 * g..3 * g + 3].iter().all(|&x| x == zero)
        && g2.depth[g] == zero;
    if untouched {
        return out;
    }
    let mu = s.mean(pose, i);
    let cov = s.cov(pose, i);
    let pj = project(mu, cov, cam, s.width, s.height);
    if pj.x[2].f64() <= NEAR {
        return out; // not drawn
    }
    // colour → its inputs
    let g_col = [0, 1, 2].map(|ch| g2.color[3 * g + ch]);
    match &s.colors {
        Colors::Rgb { .. } => out.color[..3].copy_from_slice(&g_col),
        Colors::Sh { nsh, coeffs } => {
            let nsh = *nsh;
            let frame = s.frame(pose, i, nsh);
            let (dv, dn, len, len_clamped) = match frame {
                Some(f) => view_dir(mu, centres[ci], f),
                None => ([zero; 3], [zero; 3], T::one(), true),
            };
            let y = sh_basis(nsh, dn);
            let coef = &coeffs[3 * nsh * i..3 * nsh * (i + 1)];
            let raw = sh_color(nsh, coef, &y); // as `Scene::color`, from the same basis
            let gc = [0, 1, 2].map(|ch| if raw[ch] >= zero { g_col[ch] } else { zero });
            if needs.colors {
                for k in 0..nsh {
                    for ch in 0..3 {
                        out.color[3 * k + ch] = y[k] * gc[ch];
                    }
                }
            }
            if let Some(f) = frame {
                let dy = sh_basis_grad(nsh, dn);
                let mut g_n = [zero; 3];
                for k in 1..nsh {
                    let gk = gc[0] * coef[3 * k] + gc[1] * coef[3 * k + 1] + gc[2] * coef[3 * k + 2];
                    for a in 0..3 {
                        g_n[a] = g_n[a] + gk * dy[k][a];
                    }
                }
                // n = loc / |loc|
                let nd = dot3(dn, g_n);
                let g_loc = if len_clamped { g_n.map(|x| x / len) } else { [0, 1, 2].map(|a| (g_n[a] - dn[a] * nd) / len) };
                // loc = Fᵀ d: ∂/∂F_ka = d_k g_loc_a; ∂/∂d = F g_loc
                for k in 0..3 {
                    for a in 0..3 {
                        out.frame[3 * k + a] = dv[k] * g_loc[a];
                    }
                }
                let g_d = mat_vec(f, g_loc);
                out.mu = g_d;
                // d = μ - o, o = -Rᵀ t: ∂/∂R_jk = g_d_k t_j, ∂/∂t_j = Σ_k R_jk g_d_k
                if needs.cameras {
                    for j in 0..3 {
                        for k in 0..3 {
                            g_cam[3 * j + k] = g_cam[3 * j + k] + g_d[k] * cam.t[j];
                        }
                        g_cam[9 + j] = g_cam[9 + j] + dot3(cam.r[j], g_d);
                    }
                }
            }
        }
    }
    out.opacity = g2.opacity[g];
    let g_uv = [g2.uv[2 * g], g2.uv[2 * g + 1]];
    let g_conic = [g2.conic[3 * g], g2.conic[3 * g + 1], g2.conic[3 * g + 2]];
    let (g_mu, g_cov) = project_backward(&pj, mu, cov, cam, g_uv, g_conic, g2.depth[g], needs.cameras.then_some(g_cam));
    for a in 0..3 {
        out.mu[a] = out.mu[a] + g_mu[a];
    }
    out.cov = g_cov;
    out
}

/// One chunk of Gaussians' gradients, summed over views (layouts as [`Grads`], restricted to
/// the chunk), and each view's camera gradient from the chunk.
struct ChunkGrads<T> {
    means: Vec<T>,
    covs: Vec<T>,
    frames: Vec<T>,
    colors: Vec<T>,
    opacity: Vec<T>,
    cams: Vec<[T; 16]>,
}

/// Gradients of `L = Σ g_rgb·rgb + g_alpha·alpha + g_dsum·dsum` w.r.t. the scene's inputs; the
/// groups `needs` leaves out come back empty (length 0).
pub fn backward<T: Real>(st: &State<T>, g_rgb: &[T], g_alpha: &[T], g_dsum: &[T], needs: Needs) -> Result<Grads<T>> {
    let s = &st.scene;
    let g2 = splat::backward(&st.splat, g_rgb, g_alpha, g_dsum)?;
    let (n, v, p, c) = (s.n, s.nviews(), s.poses, s.cameras.len());
    let zero = T::zero();
    let centres: Vec<[T; 3]> = s.cameras.iter().map(centre).collect();
    let (nc, has_frames, colors_per_view) = match &s.colors {
        Colors::Sh { nsh, .. } => (3 * nsh, s.frames.is_some() && *nsh > 1, false),
        Colors::Rgb { per_view, .. } => (3, false, *per_view),
    };
    let op_per_view = s.opacity_per_view;
    // Per chunk of Gaussians (fixed size), every view in order: per-pose and shared sums run
    // over views in view order, cameras over the chunk's Gaussians in index order.
    let chunks: Vec<ChunkGrads<T>> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|k| {
            let (i0, i1) = (k * CHUNK, ((k + 1) * CHUNK).min(n));
            let m = i1 - i0;
            let mut out = ChunkGrads {
                means: vec![zero; p * m * 3],
                covs: vec![zero; p * m * 9],
                frames: if has_frames { vec![zero; p * m * 9] } else { Vec::new() },
                colors: vec![zero; if needs.colors { (if colors_per_view { v } else { 1 }) * m * nc } else { 0 }],
                opacity: vec![zero; if needs.opacity { (if op_per_view { v } else { 1 }) * m } else { 0 }],
                cams: vec![[zero; 16]; v],
            };
            for view in 0..v {
                let pose = s.views[view][0];
                let mut g_cam = [zero; 16];
                for i in i0..i1 {
                    let l = local_backward(s, &g2, &centres, view, i, needs, &mut g_cam);
                    let li = i - i0;
                    let add = |dst: &mut [T], src: &[T]| {
                        for (d, x) in dst.iter_mut().zip(src) {
                            *d = *d + *x;
                        }
                    };
                    add(&mut out.means[3 * (pose * m + li)..3 * (pose * m + li) + 3], &l.mu);
                    add(&mut out.covs[9 * (pose * m + li)..9 * (pose * m + li) + 9], &l.cov);
                    if has_frames {
                        add(&mut out.frames[9 * (pose * m + li)..9 * (pose * m + li) + 9], &l.frame);
                    }
                    if needs.colors {
                        let cr = if colors_per_view { view * m + li } else { li };
                        add(&mut out.colors[nc * cr..nc * cr + nc], &l.color[..nc]);
                    }
                    if needs.opacity {
                        let orow = if op_per_view { view * m + li } else { li };
                        out.opacity[orow] = out.opacity[orow] + l.opacity;
                    }
                }
                out.cams[view] = g_cam;
            }
            out
        })
        .collect();
    // Chunks back into the full layouts; cameras summed chunk by chunk, view by view.
    let mut g = Grads {
        means: vec![zero; p * n * 3],
        covs: vec![zero; p * n * 9],
        frames: if has_frames { Some(vec![zero; p * n * 9]) } else { None },
        colors: vec![zero; if needs.colors { (if colors_per_view { v } else { 1 }) * n * nc } else { 0 }],
        opacity: vec![zero; if needs.opacity { (if op_per_view { v } else { 1 }) * n } else { 0 }],
        viewmats: vec![zero; if needs.cameras { 16 * c } else { 0 }],
        ks: vec![zero; if needs.cameras { 9 * c } else { 0 }],
        rigid: None,
    };
    let place = |dst: &mut [T], src: &[T], rows: usize, i0: usize, m: usize, per: usize| {
        for r in 0..rows {
            dst[per * (r * n + i0)..per * (r * n + i0 + m)].copy_from_slice(&src[per * r * m..per * (r + 1) * m]);
        }
    };
    for (k, ch) in chunks.iter().enumerate() {
        let (i0, m) = (k * CHUNK, ((k + 1) * CHUNK).min(n) - k * CHUNK);
        place(&mut g.means, &ch.means, p, i0, m, 3);
        place(&mut g.covs, &ch.covs, p, i0, m, 9);
        if let Some(f) = g.frames.as_mut() {
            place(f, &ch.frames, p, i0, m, 9);
        }
        if needs.colors {
            place(&mut g.colors, &ch.colors, if colors_per_view { v } else { 1 }, i0, m, nc);
        }
        if needs.opacity {
            place(&mut g.opacity, &ch.opacity, if op_per_view { v } else { 1 }, i0, m, 1);
        }
        if !needs.cameras {
            continue;
        }
        for (view, gc) in ch.cams.iter().enumerate() {
            let ci = s.views[view][1];
            for a in 0..3 {
                for b in 0..3 {
                    g.viewmats[16 * ci + 4 * a + b] = g.viewmats[16 * ci + 4 * a + b] + gc[3 * a + b];
                }
                g.viewmats[16 * ci + 4 * a + 3] = g.viewmats[16 * ci + 4 * a + 3] + gc[9 + a];
            }
            g.ks[9 * ci] = g.ks[9 * ci] + gc[12];
            g.ks[9 * ci + 4] = g.ks[9 * ci + 4] + gc[13];
            g.ks[9 * ci + 2] = g.ks[9 * ci + 2] + gc[14];
            g.ks[9 * ci + 5] = g.ks[9 * ci + 5] + gc[15];
        }
    }
    if let Some(r) = &s.rigid {
        g.rigid = Some(r.backward(p, &g.means, &g.covs, g.frames.as_deref(), needs.local));
    }
    Ok(g)
}
