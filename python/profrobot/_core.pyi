"""The native core (Rust, pyo3). Everything here releases the GIL while it works.

Shapes: B poses, K joints (MuJoCo joint order; radians for hinges, metres for slides), nbody
bodies (the world included), P candidate geom pairs. Arrays are read in any memory layout
(C or Fortran order, negative strides, sliced views): rows are read through the strides, never
reinterpreted. Invalid input raises :class:`InputError` (a ValueError), a bad robot model :class:`ModelError`, a
wrong dtype or object :class:`InputTypeError` (a TypeError) naming the dtype wanted; all three are
:class:`ProfrobotError`s; never a panic. A pose whose geom pair the narrow phase (parry) cannot
decide is never labelled (neither free nor colliding): the labelling, oracle and planning calls
raise :class:`ModelError` naming the pose and the pair (MuJoCo geom ids).

Angles: continuous hinges wrap into [-pi, pi) and shortest arcs are ``wrap(b - a)`` by one
function (``rust/joints/angles.rs``; ``profrobot.robot.angles.wrap`` is its Python twin): values already in
[-pi, pi) are unchanged, pi goes to -pi, so a half turn moves the negative way in
:func:`interpolate` and in :meth:`RobotModel.plan_path` alike.
"""

from collections.abc import Callable, Sequence
from typing import Any, Literal, TypedDict, final

import numpy as np
import numpy.typing as npt

__all__ = ["RobotModel", "ProfrobotError", "InputError", "InputTypeError", "ModelError", "interpolate", "first_bad_entries", "CrewAwake", "crew_awake", "voxel_downsample", "RenderState", "render_forward", "render_backward", "finish_images", "finish_images_backward", "image_loss", "image_loss_backward",
           "__version__"]

__version__: str
"""The package's version (one source: ``Cargo.toml``)."""

class _PlannedPath(TypedDict):
    """What :meth:`RobotModel.plan_path` returns (a plain dict at run time)."""

    path: npt.NDArray[np.float64]
    status: Literal["direct", "connected", "time_out", "iteration_limit"]
    checks: int
    iterations: int
    tree_sizes: tuple[int, int]
    raw_waypoints: int
    seconds: float
    shortcut_seconds: float

class ProfrobotError(Exception):
    """Root of every error profrobot raises on purpose (profrobot.errors lists the family)."""

class InputError(ProfrobotError, ValueError):
    """Bad input: a shape, a NaN, an option out of range (a ValueError)."""

class InputTypeError(ProfrobotError, TypeError):
    """An argument of the wrong type or dtype (a TypeError)."""

class ModelError(InputError):
    """A robot model the core cannot label exactly (inconsistent arrays, unsupported geoms or joints)."""

@final
class RobotModel:
    """A robot scene's collision model, built once from flat MuJoCo arrays
    (``profrobot.Robot`` builds it; see ``Robot.core_arrays()`` for the keys).

    Immutable and picklable: the pickle holds the model's description, every float exact to
    the bit, so an unpickled model (in another process, e.g. a DataLoader worker) labels
    exactly as the original. Safe to use in a child forked after the parent labelled poses:
    the child starts its own threads. A batch of at most 256 poses (``body_frames``,
    ``forward_kinematics``, ``label``, ``collides``, ``certified``) is one work item and runs on
    the calling thread, the GIL released: no thread hand-off; results never depend on it."""

    def __new__(cls, arrays: dict[str, npt.NDArray | bool]) -> RobotModel: ...
    def __reduce__(self) -> tuple[Callable[[bytes], RobotModel], tuple[bytes]]:
        """Pickling: ``(RobotModel._from_state, (state,))``."""
    @classmethod
    def _from_state(cls, state: bytes) -> RobotModel:
        """A model from a pickle state; ProfrobotError for bytes that are not one (truncated,
        altered, another version), ModelError for a description the core rejects."""
    @property
    def njoint(self) -> int: ...
    @property
    def nbody(self) -> int: ...
    @property
    def ngeom(self) -> int:
        """Number of collidable geoms."""
    @property
    def npair(self) -> int:
        """Number of candidate geom pairs after MuJoCo's filters."""
    def pairs(self) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.bool_], npt.NDArray[np.float64]]:
        """(P, 2) MuJoCo geom ids, (P,) is-self-collision flag, (P,) contact margin (m)."""
    def sampling_ranges(self) -> npt.NDArray[np.float64]:
        """(K, 2) joint ranges; continuous hinges report [-pi, pi]."""
    def continuous(self) -> npt.NDArray[np.bool_]:
        """(K,) whether each joint is an unlimited hinge."""
    def body_frames(self, poses: npt.NDArray[np.float64], body: int, threads: int | None = None
                    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Body ``body``'s world frame for (B, K) poses: positions (B, 3) metres and quaternions
        (B, 4) (w, x, y, z), :meth:`forward_kinematics`' for that body bit for bit; only its chain
        is placed. InputError for a body out of range."""
    def forward_kinematics(self, poses: npt.NDArray[np.float64], threads: int | None = None
                           ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """Body poses for (B, K) poses: xpos (B, nbody, 3) metres and xquat (B, nbody, 4) (w, x, y, z),
        as MuJoCo's ``mj_kinematics`` computes them."""
    def label(self, poses: npt.NDArray[np.float64], *, pairs: bool = False, distance: bool = False,
              threads: int | None = None) -> dict[str, npt.NDArray]:
        """Labels (B, K) float64 poses. Keys: collides, self_collides, scene_collides
        (B,) bool; n_pairs (B,) int32; with ``distance``, min_distance (B,) float64 metres
        (negative: penetration); with ``pairs``, colliding_pairs (M, 2) int64 (pose, pair index)."""
    def collides(self, poses: npt.NDArray[np.float64], *, threads: int | None = None) -> npt.NDArray[np.bool_]:
        """(B,) bool for (B, K) float64 poses: ``label(poses)["collides"]``, bit for bit, by the
        booleans-only fast path (stops at the first pair in contact, likeliest pairs first)."""
    def certified(self, poses: npt.NDArray[np.float64], clearance: float,
                  threads: int | None = None) -> npt.NDArray[np.bool_]:
        """(B,) bool for (B, K) float64 poses: no candidate pair in contact and every candidate pair
        more than ``clearance`` metres apart (``0 < clearance <= 1e-6``), i.e.
        ``~label(poses, distance=True)["collides"] & (min_distance > clearance)``, by the fast
        path (pair by pair, stopping at the first pair that is not clear)."""
    def certify_motions(self, starts: npt.NDArray[np.float64], goals: npt.NDArray[np.float64], clearance: float, *,
                        via: npt.NDArray[np.float64] | None = None, as_given: bool = False,
                        threads: int | None = None) -> dict[str, npt.NDArray]:
        """The continuous certificate of each straight motion ``starts[i] -> goals[i]`` ((B, K)
        float64 each; continuous hinges along the short arc, other joints straight), or with
        ``via`` ((B, K)) of each quadratic Bézier ``starts[i] -> via[i] -> goals[i]`` (a
        parabolic blend at the corner ``via[i]``, ``planning/motion.rs`` ``Bezier``): every pose
        of the motion proven to keep every candidate pair above ``max(margin, clearance)``
        (``0 < clearance <= 1e-6``) by conservative advancement. Keys: verdict (B,) uint8 (0
        certified, 1 blocked: a placed pose not shown clear, 2 unproven within 1e-7 rad /
        65 536 poses), blocked_at (B,) float64 (t in [0, 1] of that pose, NaN otherwise), states
        (B,) int64 (poses placed). With ``as_given``, each motion is taken as given in unwrapped
        coordinates (``goals - starts`` on every joint, continuous hinges too, however far: the
        motion a timed path crosses). Same answer for any thread count."""
    def time_path(self, path: npt.NDArray[np.float64], velocity: npt.NDArray[np.float64],
                  acceleration: npt.NDArray[np.float64], clearance: float, *, blend: bool = True, cut: float = 0.5,
                  threads: int | None = None) -> dict[str, Any]:
        """``path`` ((M, K) float64, M >= 2, unwrapped: each step the short arc on continuous
        hinges, none of length zero) timed within ``velocity`` and ``acceleration`` ((K,) float64,
        positive; per second and per second squared): straight segments at constant velocity,
        each corner a parabolic blend kept only where ``certify_motions(via=)`` proves it (else
        a stop), and with ``blend`` and ``cut`` in (0, 0.5], each corner first cut by the widest
        proven chord of ``cut``, ``cut/2``, ``cut/4`` of its segments
        (``planning/timing.rs``). Keys: waypoints (M', K) (the path timed, cut corners replaced by
        their chords' ends), starts (P,) s, q0, v0, acc (P, K) (each piece of constant
        acceleration at its start), duration (float, s), times (M',) s, stops (M',) bool,
        unproven_segment (int: the first segment of ``path`` whose part the timed motion crosses
        is not certified, -1 when every part crossed, chord and blend is) and unproven_verdict
        (int: its verdict, as ``certify_motions``'; 0 with none). Same answer for any thread
        count."""
    def ik(self, targets_pos: npt.NDArray[np.float64], targets_quat: npt.NDArray[np.float64] | None,
           starts: npt.NDArray[np.float64], body: int, local_pos: Sequence[float], local_quat: Sequence[float], *,
           seeds: int = 128, iterations: int = 60, tol_pos: float = 1e-6, tol_rot: float = 1e-6,
           accept_pos: float = 1e-6, accept_rot: float = 1e-6, clearance: float = 1e-6, seed: int = 0,
           escape: bool = True, held: Sequence[bool] | None = None, moving: Sequence[bool] | None = None,
           posture: Sequence[float] | None = None, free_axis: Sequence[float] | None = None,
           threads: int | None = None) -> dict[str, npt.NDArray]:
        """Inverse kinematics of the frame at ``local_pos``, ``local_quat`` (w, x, y, z) in body
        ``body``: for each of N targets (``targets_pos`` (N, 3) metres, ``targets_quat`` (N, 4) or
        None for position only), Levenberg–Marquardt on the SE(3) error from ``seeds`` seeds (the
        start of ``starts`` (N, K), three perturbations, then uniform), limits, couplings and
        continuous joints kept; each seed iterates to ``tol_pos`` / ``tol_rot``, and a pose within
        ``accept_pos`` / ``accept_rot`` reaches the target and is certified at ``clearance``
        (``escape``: a seed that reaches it in contact first tries the linearised distance rows).
        ``held`` (K,): joints kept at their start values (with a family's scene joints).
        ``moving`` (K,): joints solved for although they do not move the frame (a gripper's jaw).
        ``posture`` (K,): a pose the answers move towards in the target's null space, and the
        certified answer nearest it chosen (``rust/ik/mod.rs`` ``toward_posture``).
        ``free_axis`` (3,): an axis of the frame (its own coordinates) whose rotation is free. Keys: poses (N, K), outcome (N,) uint8 (0 certified, 1 unreachable, 2
        reached only in collision), reached (N,) bool, position_error, rotation_error (N,)
        float64, iterations, seeds (N,) int64. Same seed, same answer, for any thread count."""
    def nearest_free(self, poses: npt.NDArray[np.float64], *, directions: int = 256, step: float = 0.02,
                     tolerance: float = 1e-4, refine: int = 1024, max_distance: float | None = None, seed: int = 0,
                     threads: int | None = None) -> dict[str, npt.NDArray]:
        """The nearest free pose found for each of (B, K) poses within their joint limits: rays
        ``q + t u`` from each colliding pose along ``directions`` seeded unit directions, marched
        by ``step`` and bisected to ``tolerance`` (radians / metres, L2), then ``refine``
        perturbations of the best direction; every state labelled exactly. Keys: distance (B,)
        float64 (0 for a free pose, inf when none was found within ``max_distance``, default the
        diagonal of the joint ranges), poses (B, K) float64 (free; NaN rows when none found),
        checks (B,) int64 (states labelled). Same seed, same answer, for any thread count."""
    def plan_path(self, start: npt.NDArray[np.float64], goal: npt.NDArray[np.float64], *, resolution: float = 0.01,
                  max_time: float = 10.0, seed: int = 0, range: float = 0.0, max_iterations: int = 200_000,
                  shortcut_rounds: int = 200, verify: int = 10, continuous: bool = True, clearance: float = 1e-6,
                  held: Sequence[bool] | None = None, threads: int | None = None) -> _PlannedPath:
        """A free path from ``start`` to ``goal`` (K,) (both free and within limits): the straight
        SO(2) path if free, else RRT-Connect then shortcutting. ``continuous``: every edge proven
        free at every pose, every pair above ``max(margin, clearance)`` (``certify_motions``;
        start and goal must be that clear); else every edge checked so that no joint moves more
        than ``resolution`` between labelled poses, the answer then verified ``verify`` times
        finer (failing segments re-planned at that resolution; 1: off). ``held`` (K,): joints no
        state of the search moves (start and goal must agree on them). ``checks``: poses placed
        (continuous) or labelled. Keys: path (M, K) float64 (0 rows
        when none was found), status ('direct' | 'connected' | 'time_out' | 'iteration_limit'),
        checks, iterations, tree_sizes (2,), raw_waypoints, seconds, shortcut_seconds (of seconds).
        Continuous hinges of the path
        are wrapped into [-pi, pi) (start and goal too); each segment is the motion
        :func:`interpolate` replays between its ends. Same seed, same path, for any thread count."""
    def sample(self, n: int, seed: int, threads: int | None = None) -> npt.NDArray[np.float64]:
        """(n, K) uniform poses within the sampling ranges; identical for any thread count."""
    def with_cloud(self, points: npt.NDArray[np.float64] | None, radius: npt.NDArray[np.float64] | None,
                   margin: float = 0.0, contype: int = 1, conaffinity: int = 1) -> RobotModel:
        """This model with the point cloud ``points`` (N, 3) world metres of radii ``radius`` (N,)
        metres instead of its own (both None: no cloud; ``rust/geometry/cloud.rs``): one more geom, MuJoCo
        id -1 in :meth:`pairs`, its balls with geom ``margin`` and MuJoCo's contact filter. The
        MuJoCo geoms' shapes are shared, not built again. InputError for NaN points or negative
        radii, naming the entry."""
    def rebuilt(self, arrays: dict[str, npt.NDArray | bool]) -> RobotModel:
        """The model of ``arrays`` (as ``RobotModel(arrays)``), a scene edited from this one: a geom
        described bit for bit as one of this model's shares its shape (hull, inner balls), and a
        pair of two such geoms its proofs of clearance over joint boxes, so replacing obstacles
        costs the new geoms, the candidate pairs, the broad phase and, on first use, the new pairs'
        proofs (``Robot.with_obstacles``, ``robot/world.py``). This model's proofs are made first
        (once). Labels, certificates and proofs as ``RobotModel(arrays)``'s, bit for bit."""
    def points_near(self, pose: npt.NDArray[np.float64], points: npt.NDArray[np.float64], margin: float,
                    static_margin: float | None = None) -> npt.NDArray[np.uint8]:
        """(N,) per point of ``points`` (N, 3, world metres) at ``pose`` (1, K): 1 within
        ``margin`` metres of a robot geom, else 2 within ``static_margin`` of another geom (the
        point cloud excepted; None: not tested), else 0 (``rust/collision/filter.rs``: exact)."""

def interpolate(start: npt.NDArray[np.float64], goal: npt.NDArray[np.float64], steps: int,
                continuous: npt.NDArray[np.bool_]) -> npt.NDArray[np.float64]:
    """(B, steps, K) poses from (B, K) start to goal, both ends included: shortest arc where
    ``continuous`` (K,) (``start + t * wrap(goal - start)``, not wrapped itself; a half turn
    moves the negative way), straight otherwise."""

def first_bad_entries(poses: npt.NDArray[np.float64], lo: npt.NDArray[np.float64],
                      hi: npt.NDArray[np.float64]) -> tuple[int | None, int | None]:
    """Row-major flat indices into the (B, K) ``poses`` (any layout) of the first entry that is not
    finite and of the first outside ``[lo[j], hi[j]]`` of its column (``lo``, ``hi``: (K,); -inf /
    inf where unlimited), or None each; one pass, the GIL released (``as_poses``' checks)."""

@final
class CrewAwake:
    """While alive, the crew's helper threads stay awake for a call (:func:`crew_awake`); a
    guard of one call, dropped when its last reference goes (not pickled)."""

def crew_awake(threads: int | None = None) -> CrewAwake:
    """Wakes the crew's helper threads for a call on ``threads`` threads (None: the default
    count), ahead of it: they wake (tens of µs on a VM) while the Python checks before the call
    run, and stay awake while the guard lives (each at most 1 ms after its last section). A
    call on one thread, or more than 8, wakes none. ``rust/threads/crew.rs``."""

def voxel_downsample(points: npt.NDArray[np.float64], radius: npt.NDArray[np.float64],
                     voxel: float) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Conservative voxel downsampling of the balls ``points`` (N, 3) / ``radius`` (N,) metres by
    ``voxel``-metre cubes: ``(centres (M, 3), radii (M,))``, each kept ball about its group's mean
    reaching every ball of the group; groups in order of their first ball."""


_Float = npt.NDArray[np.float32] | npt.NDArray[np.float64]


@final
class RenderState:
    """What :func:`render_backward` needs from one :func:`render_forward` call: the scene, the
    tile lists and every composited pair (list entry, pixel, alpha, transmittance in front).
    Opaque."""

def render_forward(opacities: _Float, viewmats: _Float, Ks: _Float, views: npt.NDArray[np.int64], width: int,
                   height: int, *, means: _Float | None = None, covs: _Float | None = None, frames: _Float | None = None,
                   body_rot: _Float | None = None, body_pos: _Float | None = None,
                   body: npt.NDArray[np.int64] | None = None, local_means: _Float | None = None,
                   local_rots: _Float | None = None, local_quats: _Float | None = None, scales: _Float | None = None,
                   colors: _Float | None = None,
                   sh: _Float | None = None, cutoff: Literal["soft", "hard"] = "soft", threads: int | None = None
                   ) -> tuple[_Float, _Float, _Float, _Float, int, RenderState]:
    """The Gaussian renderer after forward kinematics (``rust/bindings/render.rs``, ``rust/render/splat.rs``):
    EWA projection, colour, tile rasterization; float32 when the inputs are float32, float64
    when they are float64 (every float input the same dtype).

    The Gaussians of P poses, either in the world (``means`` (P, N, 3) m, ``covs`` (P, N, 3, 3)
    m^2, optional ``frames`` (P, N, 3, 3), each Gaussian's frame to world) or rigidly on
    bodies (``body_rot`` (P, nb, 3, 3), ``body_pos`` (P, nb, 3) m, ``body`` (N,) int64,
    ``local_means`` (N, 3) m, ``local_rots`` (N, 3, 3) or ``local_quats`` (N, 4) (w, x, y, z,
    any nonzero norm, normalised here), ``scales`` (N, 3) m: ``mu = R_b m + x_b``,
    ``Sigma = R_b Q diag(s^2) Q^T R_b^T``, frame ``R_b``); ``opacities`` (N,) or (V, N);
    colours either ``sh`` (N, 1 | 4 | 9, 3) (3DGS's basis, in each Gaussian's frame, viewed from
    the camera centre; degree >= 1 needs frames) or ``colors`` (N, 3) or (V, N, 3); cameras
    ``viewmats`` (C, 4, 4) world-to-camera (OpenCV) and ``Ks`` (C, 3, 3) (fx, fy > 0, pixel
    centres at integers); ``views`` (V, 2) the (pose, camera) of each image.

    Returns rgb (V, H, W, 3) ``sum w c`` (no background), alpha (V, H, W) ``sum w``, dsum
    (V, H, W) ``sum w z``, contrib (V, N) each Gaussian's largest weight, the number of
    composited pairs, and the backward state. Bit-identical for any ``threads``. NaN/inf,
    wrong shapes, N = 0, a zero-size image, views or bodies out of range, a covariance that
    projects to a 2D covariance that is not positive definite raise :class:`InputError` naming
    the entry; a wrong dtype :class:`InputTypeError`."""

def render_backward(state: RenderState, grad_rgb: _Float, grad_alpha: _Float, grad_dsum: _Float, *,
                    needs: list[str] | None = None, threads: int | None = None) -> dict[str, _Float]:
    """Exact gradients of ``sum(grad_rgb * rgb) + sum(grad_alpha * alpha) + sum(grad_dsum * dsum)``
    w.r.t. :func:`render_forward`'s inputs, by keyword (the rigid arrays' or ``means``,
    ``covs``, ``frames``; ``sh`` or ``colors``; ``opacities``, ``viewmats``, ``Ks``), same
    shapes, in the state's dtype. Deterministic: every sum runs in a fixed order.

    ``needs``: the keywords whose gradients are wanted (None: all). The world (or body) ones are
    always returned; colours, opacities, cameras (``viewmats``/``Ks``) and the rigid mode's local
    arrays only when named, and then skipped in the kernel (a pose fit's model and cameras are
    constants). An unknown name raises :class:`InputError`. The gradients returned are the same
    bits either way. The upstream gradients are read in place, with the GIL released: do not
    write to them from another thread during the call."""

def finish_images(rgb: _Float, alpha: _Float, dsum: _Float, *, background: _Float | None = None,
                  threads: int | None = None) -> None:
    """Finishes :func:`render_forward`'s images in place (``rust/bindings/images.rs``): ``rgb`` (V, H, W,
    3) gets ``(1 - alpha) background`` added (``background`` (3,) or (V, 3); None: black),
    ``dsum`` (V, H, W) becomes the expected depth ``dsum / alpha`` (0 where ``alpha <= 1e-6``).
    ``rgb`` and ``dsum`` must be writeable and C-contiguous, every array one float dtype."""

def finish_images_backward(grad_rgb: _Float, grad_alpha: _Float, grad_depth: _Float, alpha: _Float, depth: _Float,
                           *, background: _Float | None = None, threads: int | None = None
                           ) -> tuple[_Float, _Float]:
    """The gradient of :func:`finish_images`: ``(grad_alpha, grad_dsum)`` w.r.t. the raw alpha
    and dsum, from the gradients w.r.t. the finished images (``grad_rgb`` passes through
    unchanged); ``alpha`` and ``depth`` are the finished images."""

def image_loss(rgb: _Float, alpha: _Float, depth: _Float, rgb_t: _Float, depth_t: _Float,
               mask_t: npt.NDArray[np.bool_], *, valid: npt.NDArray[np.bool_] | None = None, w_depth: float = 1.0,
               w_mask: float = 0.5, threads: int | None = None) -> _Float:
    """Per-image loss (V,) of finished renders (rgb (V, H, W, 3), alpha and depth (V, H, W))
    against targets ``rgb_t`` (V, H, W, 3), ``depth_t`` (V, H, W) metres, ``mask_t`` (V, H, W):
    ``mean_mask sum_c (rgb - rgb_t)^2 + w_mask mean_valid |alpha - mask| + w_depth
    mean_{mask & alpha > 1/2} |depth - depth_t|`` (``profrobot.render.targets.pose_loss``,
    term for term; the depth term only when ``w_depth`` is not 0; every array C-contiguous is
    read in place, others copied). Float arrays share alpha's dtype; wrong shapes or dtypes
    raise naming the array; a non-finite weight raises :class:`InputError`."""

def image_loss_backward(seed: _Float, rgb: _Float, alpha: _Float, depth: _Float, rgb_t: _Float, depth_t: _Float,
                        mask_t: npt.NDArray[np.bool_], *, valid: npt.NDArray[np.bool_] | None = None,
                        w_depth: float = 1.0, w_mask: float = 0.5, threads: int | None = None
                        ) -> tuple[_Float, _Float, _Float]:
    """The gradient of ``sum(seed * image_loss(...))`` (``seed`` (V,)) w.r.t. ``(rgb, alpha,
    depth)``; ``alpha > 1/2`` selects pixels and carries no gradient, ``|x|``'s gradient at 0
    is 0."""
