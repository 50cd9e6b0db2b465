"""Training the pose collision field: BCE(sigmoid(s·g), label) + α (‖∂g/∂θ‖ − 1)² (paper §3);
a pair field adds each pair's BCE on its own label, and takes the Eikonal term on each pair's
logit near contact instead of on g (:func:`pair_eikonal_from_features`).

Three presets:

- ``"pairs"`` (default): the pair-structured field (:mod:`profrobot.field.pairs`: one 32 × 32
  MLP per candidate body pair over its relative pose, each pair supervised by its own exact
  label; pairs no training pose has in contact get none, ``prune_pairs``), 1 M poses, batch
  2048, 8000 iterations, Adam (lr 2e-3, cosine), colliding poses weighted 1.5 in the BCE (fewer
  of them called free). Its cost grows with the pairs that collide: on two CPU cores about 9.5
  minutes for a 7-DoF arm and gripper in a scene (82 pairs); with ``device="cuda"`` about one
  minute on an H200 (benches/field_gpu_results.md).
- ``"cpu"``: the kinematics-aware field (one 4 × 256 MLP over link poses and pair clearances),
  2 M balanced poses, batch 8192, 3000 iterations, Adam (lr 2e-3). Cheaper per pose; less sharp
  (98.2 % against 99 % balanced accuracy held out on xarm7_table).
- ``"paper"``: the paper's model and recipe: hierarchical encoder, 10 M poses, batch 100 000,
  10 000 iterations, Adam lr 1e-3 halved at iterations 100, 500, 1400, 3000, 5500, 9100.

``"pairs"`` and ``"cpu"`` (parameter-free encoders): BCE on batches with the features computed
once per pose (float16 past ``feature_memory``), the Eikonal term on 256 poses a step (a pair
field: on their pairs within 0.3 of contact), drawn from a pool whose feature Jacobians ∂f/∂θ
were computed once (so a step differentiates the MLP, not the FK).

Any option can be overridden by keyword. ``time_budget`` (seconds) ends training early and
stretches the schedule over the budget instead of the iteration count.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import torch

from ..executors.progress import progress_bar
from ..files import check_robot
from ..exact.dataset import Dataset, make_dataset
from ..robot.robot import Robot
from .metrics import evaluate
from .model import PoseSDF
from .pairs import PairEncoder, pair_union
from ..errors import BackendUnavailableError, InputError, InputTypeError

Schedule = Literal["cosine", "paper", "constant"]
Preset = Literal["cpu", "pairs", "paper"]
PAPER_MILESTONES = (100, 500, 1400, 3000, 5500, 9100)
MODEL_OPTIONS = ("encoder", "feature_size", "hidden", "learn_scale", "init_scale", "lipschitz", "objective",
                 "spheres_per_body", "pairs")


@dataclass
class TrainConfig:
    """Training options (see module docstring for the presets)."""

    n_poses: int = 2_000_000          # balanced poses generated when given a Robot (train + test)
    test_fraction: float = 0.1
    batch_size: int = 8192
    iterations: int = 3000
    lr: float = 1e-3
    schedule: Schedule = "cosine"          # "cosine", "paper" (halvings at PAPER_MILESTONES), "constant"
    eikonal_weight: float = 0.1       # α
    pair_weight: float = 1.0          # encoder="pairs": weight of the per-pair BCE (summed over pairs)
    prune_pairs: bool = True          # encoder="pairs": networks only for the pairs some training pose has in contact
    collision_weight: float = 1.0     # BCE weight of colliding poses (> 1: fewer colliding poses called free)
    eikonal_batch: int = 0            # poses per iteration for the Eikonal term (0: whole batch)
    eikonal_pool: int = 8192          # parameter-free encoders: poses whose ∂f/∂θ is kept for the Eikonal term (0: off)
    feature_memory: float = 4 * 2**30  # bytes for stored features: float16 past it in float32, fewer poses past that
    steik_weight: float = 0.0         # StEik directional-divergence term |dᵀ H d|, d = ∇g/‖∇g‖
    lipschitz_weight: float = 1e-6    # weight of the product of Lipschitz bounds (lipschitz MLPs)
    time_budget: float | None = None  # seconds of optimisation; None: run all iterations
    seed: int = 0
    threads: int | None = None        # torch and labeller threads (None: as configured)
    eval_every: int = 0               # evaluate on the test split every N iterations (0: at the end)
    eval_at_seconds: tuple = ()       # full test metrics when training time passes each of these
    boundary_fraction: float = 0.0    # extra training poses near the collision boundary, × the uniform ones
    boundary_spread: float = 0.02     # their distance from the boundary: Gaussian, × each joint's range
    device: str = "cpu"               # torch device to train on ("cuda", "cuda:1"); the field stays there


PRESETS: dict[str, dict] = {
    "cpu": dict(encoder="kinematic", hidden=(256, 256, 256, 256), lr=2e-3, eikonal_batch=256),
    # one MLP per body pair with its own labels (field/pairs.py): sharper, features P·13 per pose
    "pairs": dict(encoder="pairs", hidden=(32, 32), n_poses=1_000_000, batch_size=2048, iterations=8000, lr=2e-3,
                  eikonal_batch=256, collision_weight=1.5),
    "paper": dict(encoder="hierarchical", hidden=(512, 512, 512, 512), n_poses=10_000_000, batch_size=100_000, iterations=10_000,
                  schedule="paper", eikonal_batch=0),
}
"""The named recipes of :func:`train_sdf` (``preset=``): model and training options, each overridable by keyword."""


#: the fewest held-out poses train_sdf reports metrics from
MIN_HELD_OUT = 20

def _split_options(preset: Preset, options: dict) -> tuple[dict, TrainConfig]:
    if preset not in PRESETS:
        raise InputError(f"unknown preset {preset!r}; choose from {sorted(PRESETS)}")
    merged = {**PRESETS[preset], **options}
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = set(merged) - fields - set(MODEL_OPTIONS)
    if unknown:
        raise InputTypeError(f"unknown train_sdf option(s): {', '.join(sorted(unknown))}")
    model_opts = {k: v for k, v in merged.items() if k in MODEL_OPTIONS}
    cfg = TrainConfig(**{k: v for k, v in merged.items() if k in fields})
    if cfg.schedule not in get_args(Schedule):
        raise InputError(f"schedule must be 'cosine', 'paper' or 'constant'; got {cfg.schedule!r}")
    if not (cfg.collision_weight > 0 and math.isfinite(cfg.collision_weight)):
        raise InputError(f"collision_weight must be a positive number; got {cfg.collision_weight!r}")
    if not (0 <= cfg.boundary_fraction <= 10 and cfg.boundary_spread > 0):
        raise InputError(f"boundary_fraction must be in [0, 10] and boundary_spread > 0; got "
                         f"{cfg.boundary_fraction!r}, {cfg.boundary_spread!r}")
    if cfg.batch_size < 2 or cfg.iterations < 1 or cfg.lr <= 0:
        raise InputError("batch_size >= 2, iterations >= 1 and lr > 0 are required")
    cfg.device = str(_check_device(cfg.device))
    return model_opts, cfg


def _check_device(device) -> torch.device:
    """``device`` as a torch.device that can run here: a clear error for a name torch does not
    know, and :class:`BackendUnavailableError` for a CUDA device this machine has not."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as e:
        raise InputError(f"device must name a torch device ('cpu', 'cuda', 'cuda:1'); got {device!r}") from e
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise BackendUnavailableError(f"train_sdf(device={device!r}): this torch ({torch.__version__}) sees no CUDA "
                                          "device; train on device='cpu'")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise BackendUnavailableError(f"train_sdf(device={device!r}): only {torch.cuda.device_count()} CUDA "
                                          "device(s) here")
    elif dev.type != "cpu":
        raise BackendUnavailableError(f"train_sdf(device={device!r}): only 'cpu' and CUDA devices are supported")
    return dev


def _lr_factor(cfg: TrainConfig, progress: float, it: int) -> float:
    if cfg.schedule == "paper":
        return 0.5 ** sum(it >= m for m in PAPER_MILESTONES)
    if cfg.schedule == "cosine":
        return 0.5 * (1 + math.cos(math.pi * min(progress, 1.0)))
    return 1.0


def eikonal_terms(sdf: PoseSDF, theta: torch.Tensor, steik: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Eikonal loss mean (‖∂g/∂θ‖ − 1)² on poses θ (B, K), and the StEik term mean |dᵀ H d|
    (d = ∇g/‖∇g‖; zero unless ``steik``), both differentiable in the network's parameters. For a
    family field the gradient is taken over the robot joints only (δ is never optimised). A pair
    field trained through this path (no stored Jacobian pool: ``eikonal_pool=0``, or StEik) takes
    the term on g itself, not per pair (:func:`pair_eikonal_from_features`)."""
    theta = theta.detach().requires_grad_(True)
    (grad,) = torch.autograd.grad(sdf(theta).sum(), theta, create_graph=True)
    if getattr(sdf, "scene_joints", None):  # a family field: Eikonal on θ, the joints optimised; δ is given
        grad = grad[:, sdf.robot_index]
    norm = grad.norm(dim=1)
    eik = ((norm - 1) ** 2).mean()
    if not steik:
        return eik, torch.zeros((), dtype=eik.dtype, device=eik.device)
    d = (grad / norm.clamp(min=1e-8)[:, None]).detach()
    (hd,) = torch.autograd.grad((grad * d).sum(), theta, create_graph=True)  # H d
    if getattr(sdf, "scene_joints", None):
        hd = hd[:, sdf.robot_index]
    return eik, (hd * d).sum(1).abs().mean()


def feature_jacobians(encoder, theta: torch.Tensor, columns, chunk: int = 256) -> torch.Tensor:
    """∂f/∂θ of a parameter-free encoder at poses θ (B, K), for the joint ``columns`` (C,):
    (B, F, C), exact: forward-mode dual numbers through the FK, the C tangents of ``chunk`` poses
    in one pass of C·chunk rows."""
    import torch.autograd.forward_ad as fwad

    columns = torch.as_tensor(list(columns), dtype=torch.long, device=theta.device)
    C = len(columns)
    out = []
    with torch.no_grad():
        for i in range(0, len(theta), chunk):
            q = theta[i:i + chunk]
            b = len(q)
            tangent = torch.zeros(C, b, q.shape[1], dtype=q.dtype, device=q.device)
            tangent[torch.arange(C), :, columns] = 1.0                        # row block c moves joint columns[c]
            with fwad.dual_level():
                y = encoder(fwad.make_dual(q.repeat(C, 1), tangent.reshape(C * b, -1)))
                jac = fwad.unpack_dual(y).tangent                             # (C·b, F)
            out.append(jac.reshape(C, b, -1).permute(1, 2, 0))                # (b, F, C)
    return torch.cat(out)


def eikonal_from_features(sdf: PoseSDF, features: torch.Tensor, jacobians: torch.Tensor) -> torch.Tensor:
    """The Eikonal loss mean (‖∂g/∂θ‖ − 1)² from features f (B, F) and their Jacobians ∂f/∂θ
    (B, F, C): ∂g/∂θ = (∂f/∂θ)ᵀ ∂g/∂f by the chain rule, so only the MLP is differentiated (twice),
    never the FK. Equal to :func:`eikonal_terms`'s for a parameter-free encoder."""
    f = features.detach().requires_grad_(True)
    (gf,) = torch.autograd.grad(sdf.head_g(f).sum(), f, create_graph=True)     # (B, F)
    grad = torch.einsum("bfc,bf->bc", jacobians, gf)                             # (B, C)
    return ((grad.norm(dim=1) - 1) ** 2).mean()


#: a pair field's Eikonal term covers the (pose, pair) entries with z_p above −PAIR_EIKONAL_BAND
PAIR_EIKONAL_BAND = 0.3


def pair_eikonal_from_features(sdf: PoseSDF, features: torch.Tensor, jacobians: torch.Tensor,
                               band: float = PAIR_EIKONAL_BAND) -> torch.Tensor:
    """A pair field's Eikonal loss, on every pair's own logit: mean (‖∂z_p/∂θ‖ − 1)² over the
    (pose, pair) entries with z_p > −``band`` (in contact, or within ``band`` of it), from
    features f (B, P·13) and Jacobians ∂f/∂θ (B, P·13, C). z_p reads only its pair's 13
    features, so ∂(Σ_p z_p)/∂f holds every ∂z_p/∂f_p at once, and ∂z_p/∂θ = (∂f_p/∂θ)ᵀ ∂z_p/∂f_p.

    Why not g's: g = :func:`~.pairs.pair_union` is the sum of the colliding pairs' logits, so
    inside a contact of several pairs ‖∇g‖ is not 1 by design, and asking it to be flattens every
    pair (measured: 0.5 points of held-out accuracy lost on Panda-blocks). Where every pair is
    free, g is the largest logit: within the band this term holds g's slope, farther out g's
    slope is left to the data term (the pose is then at least the band's worth from contact)."""
    f = features.detach().requires_grad_(True)
    z = sdf.head(f)                                                               # (B, P)
    (gf,) = torch.autograd.grad(z.sum(), f, create_graph=True)                    # (B, P·13)
    B, P = z.shape
    grad = torch.einsum("bpkc,bpk->bpc", jacobians.reshape(B, P, -1, jacobians.shape[-1]), gf.reshape(B, P, -1))
    near = z.detach() > -band                                                     # (B, P)
    if not bool(near.any()):
        return z.new_zeros(())
    return ((grad.norm(dim=2)[near] - 1) ** 2).mean()


#: |logit| beyond which a correctly classified pose's BCE gradient is dropped (σ(−30) ≈ 1e-13)
SETTLED_LOGIT = 30.0


def _settled(logit: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """The logit, held at ±SETTLED_LOGIT on the side its label agrees with (y = 0: not below
    −30; y = 1: not above +30), so that a pose or pair classified right with that margin gives a
    gradient of exactly 0 instead of σ(−|logit|). That gradient is under 1e-13 (no step can use
    it), and past |logit| ≈ 87 it is a denormal float: most pairs of a pair field are far apart,
    their logits drift there during training, and denormals make the CPU's backward products
    several times slower. A wrong logit keeps its whole gradient."""
    return torch.where(y > 0.5, logit.clamp(max=SETTLED_LOGIT), logit.clamp(min=-SETTLED_LOGIT))


def _stored_features(sdf: PoseSDF, theta: torch.Tensor, budget: float, progress: bool) -> tuple[torch.Tensor, int]:
    """The features of a parameter-free encoder at every training pose θ (N, K), computed once,
    and how many poses they cover: (n, F) in float32 when that fits ``budget`` bytes, else
    float16 (standardised features to 3 significant digits: a 0.1 m-wide clearance feature to
    0.05 mm), else float16 for the first n poses that fit, with a warning. Filled in place, in
    chunks that keep the FK's intermediates in cache (no second copy of the whole)."""
    n, F = len(theta), sdf.encoder.out_features
    dtype = torch.float32 if n * F * 4 <= budget else torch.float16
    keep = n if dtype == torch.float32 else min(n, max(1, int(budget // (F * 2))))
    if keep < n:
        warnings.warn(f"train_sdf: the features of {n} poses ({F} each) need {n * F * 2 / 2**30:.1f} GiB in float16, over "
                      f"feature_memory={budget / 2**30:.1f} GiB; training on the first {keep} (raise feature_memory, or "
                      "lower n_poses)", stacklevel=3)
    out = torch.empty(keep, F, dtype=dtype, device=theta.device)
    with torch.no_grad():
        for i in progress_bar(iterable=range(0, keep, 2048), desc="features", progress=progress, leave=False):
            out[i:i + 2048] = sdf.encoder(theta[i:min(i + 2048, keep)])
    return out, keep


def _fit_ndf_targets(train: Dataset) -> np.ndarray:
    """NDF targets: L2 distance (in θ) from each pose to the nearest free training pose."""
    from scipy.spatial import cKDTree

    free = train.poses[~train.collides]
    dist, _ = cKDTree(free).query(train.poses, k=1, workers=-1)
    return dist.astype(np.float32)


def train_sdf(data: Robot | Dataset, *, robot: Robot | None = None, preset: Preset = "pairs",
              progress: bool = True, **options) -> PoseSDF:
    """Train a :class:`PoseSDF` and return it with ``.metrics`` (held-out balanced split) and
    ``.history`` attached.

    ``data``: a :class:`~profrobot.Robot` (a balanced dataset of ``n_poses`` is made with the exact
    labeller) or a :class:`~profrobot.Dataset` (then pass ``robot=``, or the dataset's robot must
    be a bundled scene). Options: the fields of :class:`TrainConfig` and PoseSDF's ``encoder``,
    ``feature_size``, ``hidden``, ``learn_scale``, ``init_scale``, ``lipschitz``, ``objective``.
    ``device="cuda"`` trains on a GPU (features, batches and the Eikonal FK all on it); the field
    is returned on that device (``.cpu()`` moves it back; checkpoints load on the CPU). Labelling
    stays on the CPU's exact labeller either way.
    Ctrl-C stops training early; the model trained so far is evaluated and returned.
    """
    model_opts, cfg = _split_options(preset, options)
    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    if isinstance(data, Robot):
        robot, dataset = data, make_dataset(data, cfg.n_poses, seed=cfg.seed, progress=progress,
                                            threads=cfg.threads)
    elif isinstance(data, Dataset):
        dataset = data
        if robot is None:
            from ..scenes import family_names, load, names

            name = data.metadata.get("robot")
            if name not in names() + family_names():
                raise InputError("pass robot= with a Dataset whose robot is not a bundled scene")
            robot = load(name)
        check_robot(data.metadata, robot, "the dataset", missing_ok=True)
    else:
        raise InputTypeError(f"train_sdf needs a profrobot.Robot or Dataset; got {type(data).__name__}")
    train, test = dataset.split(cfg.test_fraction, seed=cfg.seed)
    # metrics from a handful of held-out poses would be noise reported as accuracy
    if len(test) < MIN_HELD_OUT or test.collides.all() or not test.collides.any():
        raise InputError(f"train_sdf: {len(dataset)} poses (n_poses) leave {len(test)} held out "
                         f"(test_fraction {cfg.test_fraction}, {int(test.collides.sum())} colliding): at least "
                         f"{MIN_HELD_OUT}, colliding and free both, are needed to report metrics; raise n_poses (or test_fraction)")

    if cfg.boundary_fraction > 0:
        # poses where the sign of g is hardest to get right; the held-out split stays uniform
        from ..exact.dataset import boundary_dataset

        near = boundary_dataset(robot, max(1, int(cfg.boundary_fraction * len(train))), seed=cfg.seed,
                                spread=cfg.boundary_spread, threads=cfg.threads)
        train = train.concat(near)

    # encoder="pairs": every pair's own exact label (body pairs in contact), P labels per pose;
    # a pair no training pose has in contact gets no network (prune_pairs): it could only learn "free"
    pair_lab = None
    if model_opts.get("encoder") == "pairs" and model_opts.get("objective", "sdf") == "sdf":
        from ..kinematics.fk import Kinematics
        from ..exact.labels import label_poses
        from .proxies import PairClearance

        if cfg.pair_weight > 0 or (cfg.prune_pairs and model_opts.get("pairs") is None):
            pair_lab = label_poses(robot, train.poses, pairs=True, threads=cfg.threads).colliding_pairs
        if cfg.prune_pairs and model_opts.get("pairs") is None:
            assert pair_lab is not None   # labelled just above, with pairs=True
            hit = PairClearance(robot, Kinematics.from_robot(robot)).pair_hits(pair_lab)
            if len(hit):
                model_opts = {**model_opts, "pairs": hit.tolist()}

    torch.manual_seed(cfg.seed)
    dev = torch.device(cfg.device)
    sdf = PoseSDF(robot, **model_opts).to(dev)   # built (and its encoder standardised) on the CPU, then moved
    ndf = sdf.config["objective"] == "ndf"
    rng = np.random.default_rng(cfg.seed)
    theta_all = torch.as_tensor(train.poses, dtype=torch.float32, device=dev)
    target = torch.as_tensor(_fit_ndf_targets(train) if ndf else train.collides.astype(np.float32), device=dev)

    # Parameter-free encoders: features once per pose, so BCE costs only the MLP. Small chunks
    # keep the FK's intermediates in cache (2x faster than 16k-pose chunks on a laptop CPU).
    features = None
    if not sdf.encoder.learnable:
        features, kept = _stored_features(sdf, theta_all, cfg.feature_memory, progress)
        if kept < len(theta_all):
            theta_all, target, train = theta_all[:kept], target[:kept], train.take(np.arange(kept))
            if pair_lab is not None:
                pair_lab = pair_lab[pair_lab[:, 0] < kept]

    # The Eikonal term of a parameter-free encoder through stored Jacobians: ∂f/∂θ of a pool of
    # training poses, computed once (forward mode), so each step differentiates the MLP only
    # (10x cheaper than the FK's double backward; the same loss, see eikonal_from_features).
    # Capped at 256 MB; the Hessian term (StEik) still needs the FK itself.
    pool = jac = None
    eik_cols = sdf.robot_index if sdf.robot_index is not None else torch.arange(sdf.njoint)   # a family: θ only
    if (features is not None and cfg.eikonal_pool > 0 and cfg.eikonal_weight > 0 and cfg.steik_weight == 0
            and cfg.eikonal_batch > 0):
        per_pose = 4 * features.shape[1] * len(eik_cols)
        size = int(min(len(theta_all), cfg.eikonal_pool, max(cfg.eikonal_batch, 256 * 2**20 // per_pose)))
        pool = torch.as_tensor(np.sort(rng.permutation(len(theta_all))[:size]), device=dev)
        jac = feature_jacobians(sdf.encoder, theta_all[pool], eik_cols.tolist())

    pos_weight = None if cfg.collision_weight == 1.0 else torch.tensor(float(cfg.collision_weight), device=dev)
    pair_y = None
    if pair_lab is not None and cfg.pair_weight > 0 and features is not None:
        assert isinstance(sdf.encoder, PairEncoder)   # pair labels are made for encoder="pairs" only
        pair_y = torch.as_tensor(sdf.encoder.pair_labels(pair_lab, len(train)), device=dev)
    params = [p for p in sdf.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=cfg.lr)
    history: list[dict] = []
    snapshots: list[dict] = []
    pending = sorted(float(x) for x in cfg.eval_at_seconds)
    n = len(theta_all)
    bs = min(cfg.batch_size, n)
    order, cursor = rng.permutation(n), 0
    start = time.perf_counter()
    # a time budget with "unlimited" iterations: no iteration total (its ETA would read in years)
    total = None if cfg.time_budget and cfg.iterations >= 10**7 else cfg.iterations
    bar = progress_bar(total, desc=f"train {robot.name}" + (f" ({cfg.time_budget / 60:g} min)" if cfg.time_budget else ""),
                       unit="it", progress=progress)
    it = 0
    try:
        for it in range(cfg.iterations):
            elapsed = time.perf_counter() - start
            progress_frac = max(it / cfg.iterations, elapsed / cfg.time_budget if cfg.time_budget else 0.0)
            if cfg.time_budget and elapsed >= cfg.time_budget:
                break
            if pending and elapsed >= pending[0]:
                sdf.eval()
                snapshots.append(dict(evaluate(sdf, test.poses, test.collides), at_seconds=pending.pop(0),
                                      iterations=it))
                sdf.train()
                start += time.perf_counter() - start - elapsed  # evaluation time is not training time
            for group in opt.param_groups:
                group["lr"] = cfg.lr * _lr_factor(cfg, progress_frac, it)
            if cursor + bs > n:
                order, cursor = rng.permutation(n), 0
            idx = torch.as_tensor(order[cursor:cursor + bs], device=dev)
            cursor += bs
            if pair_y is not None:
                assert features is not None   # pair labels are used with stored features only
                z = sdf.head(features[idx].float())                          # (B, P) pair logits
                g = pair_union(z)
            else:
                g = sdf.head_g(features[idx].float()) if features is not None else sdf(theta_all[idx])
            y = target[idx]
            if ndf:
                data_loss = torch.nn.functional.l1_loss(g + sdf.ndf_threshold, y)
            else:
                data_loss = torch.nn.functional.binary_cross_entropy_with_logits(
                    _settled(sdf.scale * g, y), y, pos_weight=pos_weight)
            if pair_y is not None:
                yp = pair_y[idx].to(z.dtype)
                data_loss = data_loss + cfg.pair_weight * torch.nn.functional.binary_cross_entropy_with_logits(
                    _settled(sdf.scale * z, yp), yp, pos_weight=pos_weight, reduction="none").sum(1).mean()
            loss = data_loss
            eik = steik = torch.zeros((), device=dev)
            if jac is not None:
                assert features is not None and pool is not None   # the Jacobians' pool is of stored features
                pick = torch.as_tensor(rng.integers(0, len(pool), cfg.eikonal_batch), device=dev)
                # a pair field: each pair's own slope (pair_eikonal_from_features); else g's
                term = pair_eikonal_from_features if sdf.config["encoder"] == "pairs" and not ndf else eikonal_from_features
                eik = term(sdf, features[pool[pick]].float(), jac[pick])
                loss = loss + cfg.eikonal_weight * eik
            elif cfg.eikonal_weight > 0 or cfg.steik_weight > 0:
                sub = idx[: cfg.eikonal_batch] if cfg.eikonal_batch else idx
                eik, steik = eikonal_terms(sdf, theta_all[sub], steik=cfg.steik_weight > 0)
                loss = loss + cfg.eikonal_weight * eik + cfg.steik_weight * steik
            if sdf.config["lipschitz"]:
                loss = loss + cfg.lipschitz_weight * sdf.lipschitz_bound()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            with torch.no_grad():
                sdf.s_raw.clamp_(math.log(1e-3), math.log(1e3))
            rec = dict(iteration=it, loss=float(loss.detach()), data=float(data_loss.detach()), eikonal=float(eik.detach()),
                       scale=float(sdf.scale.detach()), seconds=time.perf_counter() - start)
            if cfg.eval_every and (it + 1) % cfg.eval_every == 0:
                rec.update(_test_accuracy(sdf, test))
            history.append(rec)
            bar.set_postfix(loss=f"{rec['loss']:.4f}", eik=f"{rec['eikonal']:.3f}", s=f"{rec['scale']:.1f}",
                            refresh=False)
            bar.update(1)
    except KeyboardInterrupt:
        warnings.warn(f"training interrupted at iteration {it}; evaluating the model trained so far", stacklevel=2)
    finally:
        bar.close()
    train_seconds = time.perf_counter() - start
    if ndf:
        _set_ndf_threshold(sdf, train, features)
    sdf.eval()
    sdf.metrics = dict(evaluate(sdf, test.poses, test.collides), iterations=len(history),
                       train_seconds=train_seconds, train_poses=n, threads=torch.get_num_threads(),
                       device=str(dev))
    sdf.history = history
    sdf.snapshots = snapshots
    return sdf


def _test_accuracy(sdf: PoseSDF, test: Dataset, n: int = 20_000, n_grad: int = 2000) -> dict:
    """The periodic training record: accuracy on ``n`` held-out poses, and on ``n_grad`` of them the
    mean ‖∇g‖ and the classifier's mean ‖∇σ(s·g)‖ (how either evolves: the paper's Table 2)."""
    from .metrics import field_values, gradient_summary

    g = field_values(sdf, test.poses[:n])
    grads = gradient_summary(sdf, test.poses[:n_grad])
    return dict(test_accuracy=float(np.mean((g > 0) == test.collides[:n])), grad_norm=grads["grad_norm"],
                classifier_grad_norm=grads["classifier_grad_norm"])


@torch.no_grad()
def _set_ndf_threshold(sdf: PoseSDF, train: Dataset, features, n: int = 200_000) -> None:
    """The NDF baseline classifies "colliding" when its distance exceeds a threshold; pick the one
    that maximises training accuracy (fair to the baseline)."""
    sdf.ndf_threshold.zero_()
    q = torch.as_tensor(train.poses[:n], dtype=torch.float32, device=sdf.joint_limits.device)
    d = (sdf.head_g(features[:n].float()) if features is not None else sdf(q)).cpu().numpy()
    y = train.collides[:n]
    cands = np.quantile(d, np.linspace(0.01, 0.99, 99))
    acc = [np.mean((d > c) == y) for c in cands]
    sdf.ndf_threshold.fill_(float(cands[int(np.argmax(acc))]))
