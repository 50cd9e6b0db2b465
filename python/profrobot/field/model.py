"""The pose collision field g(θ) (paper §3): g < 0 free, g > 0 colliding; ``prob = sigmoid(s·g)``."""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Literal, get_args

import numpy.typing as npt
import torch
from torch import nn

from .chunking import cpu_chunks
from .checkpoint import read_checkpoint, write_checkpoint
from .encoders import FlatEncoder, HierarchicalEncoder, KinematicEncoder
from .pairs import PairEncoder, PairHead, pair_union
from .identity import _Shared
from .layout import LayoutField
from ..errors import InputError, InputTypeError
from ..robot.gate import Layout
from ..robot.robot import Robot

#: poses per chunk when a CPU batch is larger (:meth:`PoseSDF.forward`)
EVAL_CHUNK = 4096

Encoder = Literal["kinematic", "hierarchical", "flat", "pairs"]
Objective = Literal["sdf", "ndf"]
ENCODERS: tuple[str, ...] = get_args(Encoder)
OBJECTIVES: tuple[str, ...] = get_args(Objective)


class LipschitzLinear(nn.Linear):
    """Linear layer with a learnable Lipschitz bound (Liu et al. 2022): each row of W is rescaled
    so its absolute sum is at most ``softplus(c)``; the product of the bounds is penalised."""

    def __init__(self, n_in: int, n_out: int):
        super().__init__(n_in, n_out)
        self.c = nn.Parameter(self.weight.detach().abs().sum(1).max().clone())

    def bound(self) -> torch.Tensor:
        return nn.functional.softplus(self.c)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scale = torch.clamp(self.bound() / self.weight.abs().sum(1), max=1.0)
        return nn.functional.linear(x, self.weight * scale[:, None], self.bias)


class PoseSDF(nn.Module):
    """Collision field over joint space for one robot.

    ``forward(theta)``: θ (B, K), radians / metres in MuJoCo joint order → g (B,); g < 0 is free.
    ``prob(theta)``: collision probability sigmoid(s·g), (B,).

    Options (the paper's model is ``encoder="hierarchical"``; ours ``"kinematic"``, the class's
    default, and ``"pairs"``, the default of :func:`~profrobot.field.train_sdf`):

    - ``encoder``: "kinematic" (link poses and pair clearances from torch FK), "hierarchical"
      (paper), "flat" (ablation), "pairs" (one MLP per candidate body pair over its relative
      pose, g their union (the largest pair logit where all are free); ``hidden`` is then each pair's widths, e.g. (32, 32):
      :mod:`profrobot.field.pairs`);
    - ``pairs`` (``encoder="pairs"``): indices of the candidate pairs that get a network (the
      full list is ``PairClearance.all_npair`` long); None: all. ``train_sdf`` keeps the pairs
      its dataset shows in contact (``prune_pairs``): a pair never seen colliding can only learn
      "free", which leaving it out says exactly, at a third less cost;
    - ``feature_size`` (hierarchical/flat, default 8); ``hidden``: MLP widths (default 4 × 512);
    - ``learn_scale`` (default True; False fixes s = 1: the ablation), ``init_scale`` 10;
    - ``lipschitz``: Lipschitz-constrained MLP layers;
    - ``objective``: "sdf" (classifier field) or "ndf" (the baseline: g regresses the distance
      to the nearest free pose, minus a threshold fitted on training data).

    A field pickles with its robot (``pickle``, ``torch.save`` / ``torch.load(...,
    weights_only=False)``, DataLoader workers): the copy gives the same g and ∂g/∂θ. ``deepcopy``
    copies the weights and shares the (immutable) robot. Checkpoints to keep are
    :meth:`save`'s (safetensors, nothing unpickled).
    """

    # buffers (register_buffer); robot_index and scene_index are None for an ordinary field
    joint_limits: torch.Tensor
    robot_index: torch.Tensor | None
    scene_index: torch.Tensor | None
    ndf_threshold: torch.Tensor
    encoder: HierarchicalEncoder | FlatEncoder | KinematicEncoder | PairEncoder
    head: nn.Sequential | PairHead
    # attached by train_sdf
    history: list[dict]
    snapshots: list[dict]

    def __init__(self, robot: Robot, *, encoder: Encoder = "kinematic", feature_size: int = 8,
                 hidden: tuple[int, ...] = (512, 512, 512, 512), learn_scale: bool = True,
                 init_scale: float = 10.0, lipschitz: bool = False, objective: Objective = "sdf",
                 spheres_per_body: int = 4, pairs: Iterable[int] | None = None):
        super().__init__()
        if encoder not in ENCODERS:
            raise InputError(f"encoder must be one of {ENCODERS}; got {encoder!r}")
        if objective not in OBJECTIVES:
            raise InputError(f"objective must be one of {OBJECTIVES}; got {objective!r}")
        if not hidden or any(int(h) <= 0 for h in hidden):
            raise InputError(f"hidden must be a non-empty list of positive widths; got {hidden!r}")
        if pairs is not None and encoder != "pairs":
            raise InputError(f"pairs= selects the pair networks of encoder='pairs'; got encoder={encoder!r}")
        self.config: dict[str, Any] = dict(encoder=encoder, feature_size=int(feature_size), hidden=[int(h) for h in hidden],
                           learn_scale=bool(learn_scale), init_scale=float(init_scale), lipschitz=bool(lipschitz),
                           objective=objective, spheres_per_body=int(spheres_per_body))
        self._robot = _Shared(robot)
        self.robot_name = robot.name
        self.fingerprint = robot.fingerprint
        self.joint_names = list(robot.joint_names)
        self.njoint = robot.njoint
        self.register_buffer("joint_limits", torch.as_tensor(robot.joint_limits, dtype=torch.float32))
        # a family of scenes (profrobot.robot.family): g(θ, δ), the scene joints δ inputs like any joint
        self.scene_joints = list(getattr(robot, "scene_joints", ()))
        # (D,) and (K − D,) column indices; None for an ordinary field (an empty buffer breaks
        # torch.export's packaging: "numel: integer multiplication overflow")
        if self.scene_joints:
            self.register_buffer("robot_index", torch.as_tensor(robot.robot_index), persistent=False)
            self.register_buffer("scene_index", torch.as_tensor(robot.scene_index), persistent=False)
        else:
            self.robot_index = self.scene_index = None
        if encoder == "hierarchical":
            self.encoder = HierarchicalEncoder(robot.joint_parents, feature_size)
        elif encoder == "flat":
            self.encoder = FlatEncoder(robot.njoint, feature_size)
        elif encoder == "pairs":
            self.encoder = PairEncoder(robot, spheres_per_body=spheres_per_body, pairs=pairs)
            if pairs is not None:
                self.config["pairs"] = self.encoder.clearance.kept
        else:
            self.encoder = KinematicEncoder(robot, spheres_per_body=spheres_per_body)
        if isinstance(self.encoder, PairEncoder):   # one MLP per body pair, g their union (field/pairs.py)
            if lipschitz:
                raise InputError("lipschitz=True is for the single-MLP encoders, not encoder='pairs'")
            self.head = PairHead(self.encoder.npair, tuple(self.config["hidden"]))
        else:
            Lin = LipschitzLinear if lipschitz else nn.Linear
            layers: list[nn.Module] = [nn.LeakyReLU()] if encoder != "kinematic" else []
            width = self.encoder.out_features
            for h in self.config["hidden"]:
                layers += [Lin(width, h), nn.LeakyReLU()]
                width = h
            layers.append(Lin(width, 1))
            self.head = nn.Sequential(*layers)
        self.s_raw = nn.Parameter(torch.tensor(math.log(init_scale)), requires_grad=learn_scale)
        # NDF: g = distance − threshold (set by training)
        self.register_buffer("ndf_threshold", torch.tensor(0.0))
        self.metrics: dict = {}

    @property
    def scale(self) -> torch.Tensor:
        """s = exp(s_raw), clamped to [1e-3, 1e3]."""
        return self.s_raw.exp().clamp(1e-3, 1e3)

    def check_poses(self, theta: torch.Tensor) -> None:
        if not isinstance(theta, torch.Tensor):
            hint = " (torch.as_tensor(poses, dtype=torch.float32))" if hasattr(theta, "__array__") else ""
            raise InputTypeError(f"theta must be a torch.Tensor{hint}; got {type(theta).__name__}")
        if theta.ndim != 2 or theta.shape[1] != self.njoint:
            raise InputError(f"theta must have shape (B, {self.njoint}) for robot {self.robot_name!r}; "
                             f"got {tuple(theta.shape)}")
        if not theta.is_floating_point():
            raise InputTypeError(f"theta must be a floating-point tensor; got {theta.dtype}")
        bad = ~torch.isfinite(theta.detach())
        if bad.any():   # NaN in, NaN out would pass silently through every optimiser
            i, j = (int(v) for v in bad.nonzero()[0])
            raise InputError(f"theta[{i}, {j}] ({self.joint_names[j] if j < len(self.joint_names) else j}) is "
                             f"{float(theta[i, j])}; poses must be finite")

    def head_g(self, features: torch.Tensor) -> torch.Tensor:
        """g (B,) from encoder features (B, F) (``encoder="pairs"``: the pairs' union, :func:`~.pairs.pair_union`)."""
        g = pair_union(self.head(features)) if self.config["encoder"] == "pairs" else self.head(features)[:, 0]
        return g - self.ndf_threshold if self.config["objective"] == "ndf" else g

    def forward(self, theta: torch.Tensor, layout: Layout | None = None) -> torch.Tensor:
        """g (B,) at poses θ (B, K); for a family field, θ (B, K − D) with ``scene`` δ, (D,) or one
        per pose (B, D), or θ (B, K) the full vectors (θ, δ) in MuJoCo joint order."""
        if layout is not None:
            theta = self.compose(theta, layout)
        self.check_poses(theta)
        theta = theta.to(self.joint_limits.dtype)
        # chunks of poses (field/chunking.py): the intermediates stay in cache; the backward runs
        # chunk by chunk too (each chunk's graph is its own branch)
        parts = [self.head_g(self.encoder(t)) for t in cpu_chunks(theta, EVAL_CHUNK)]
        return parts[0] if len(parts) == 1 else torch.cat(parts)

    def prob(self, theta: torch.Tensor, layout: Layout | None = None) -> torch.Tensor:
        """Collision probability sigmoid(s·g(θ)), (B,)."""
        return torch.sigmoid(self.scale * self(theta, layout))

    def compose(self, theta: torch.Tensor, layout: Layout) -> torch.Tensor:
        """Full pose vectors (B, K) from robot poses θ (B, K − D) and a layout δ, (D,) or (B, D),
        checked against the family's ranges (:meth:`profrobot.Robot.check_layout`); differentiable
        in θ."""
        if not self.scene_joints:
            raise InputError(f"the field for {self.robot_name!r} is not a family field (no scene joints); it takes no scene")
        assert self.robot_index is not None   # a family field has its column indices
        if not isinstance(theta, torch.Tensor) or theta.ndim != 2 or theta.shape[1] != len(self.robot_index):
            raise InputError(f"theta must be a (B, {len(self.robot_index)}) tensor of the robot joints when layout= "
                             f"is given; got {tuple(theta.shape) if isinstance(theta, torch.Tensor) else type(theta).__name__}")
        return self.scatter(theta, self.robot.check_layouts(layout, len(theta)))

    def scatter(self, theta: torch.Tensor, deltas: npt.ArrayLike) -> torch.Tensor:
        """Full vectors (B, K): robot joints θ (B, K − D) and checked layouts ``deltas`` (1 or B, D)
        put in their columns; differentiable in θ."""
        full = theta.new_empty(len(theta), self.njoint)
        full[:, self.robot_index] = theta
        full[:, self.scene_index] = torch.as_tensor(deltas, dtype=theta.dtype, device=theta.device)
        return full

    def at(self, layout: Layout) -> LayoutField:
        """This family field at one layout δ (``layout``: (D,) or ``{scene joint: value}``): a field
        over the robot joints θ alone, whose ``robot`` is ``self.robot.at(scene)`` (the static
        scene the exact labeller certifies against). What ``resolve``, ``plan_trajectory`` and the
        inverse problems use with ``layout=``."""
        return LayoutField(self, layout)

    def lipschitz_bound(self) -> torch.Tensor:
        """Product of the layers' Lipschitz bounds (1 if the MLP is unconstrained)."""
        out = torch.ones((), device=self.s_raw.device)
        for m in (self.head if isinstance(self.head, nn.Sequential) else ()):   # a PairHead has no Lipschitz layers
            if isinstance(m, LipschitzLinear):
                out = out * m.bound()
        return out

    @property
    def robot(self) -> Robot:
        """The :class:`profrobot.Robot` this field was built for (certification labels with it)."""
        return self._robot.value

    # ---- persistence ---------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Save to the directory ``path`` (``model.safetensors`` + ``config.json``: architecture,
        robot fingerprint, metrics, format version; ``robot.pkl``: the robot), created or replaced
        atomically."""
        return write_checkpoint(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike, robot: Robot | None = None) -> "PoseSDF":
        """A field saved by :meth:`save`. ``robot``: the :class:`~profrobot.Robot` it was trained
        for (its fingerprint is checked), or None for the robot the directory stores
        (``robot.pkl``: the robot in its cell, obstacles, URDF meshes and all; read by a restricted
        unpickler, :mod:`profrobot.robot.file`). Raises :class:`~profrobot.errors.RobotMismatchError`
        for another robot and :class:`~profrobot.errors.CorruptFileError` for missing, corrupt or
        newer files."""
        return read_checkpoint(cls, path, robot)

    def __repr__(self) -> str:
        n = sum(p.numel() for p in self.parameters())
        family = f", scene joints={len(self.scene_joints)}" if self.scene_joints else ""
        return (f"PoseSDF(robot={self.robot_name!r}, encoder={self.config['encoder']!r}, "
                f"hidden={self.config['hidden']}, params={n:,}{family})")
