"""A pose from a text prompt (paper §5, Table 9): maximise a scorer's match between one camera's
render of the Gaussian robot and a prompt (CLIP: the raw dot product of image and text
features), with the collision penalty added when a field is given; every returned pose is
certified by the exact labeller, and one that still collides is resolved on the field
(:func:`profrobot.resolve`, certify-and-continue) before it is returned, or reported."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import torch

from ..errors import InputError, InputTypeError
from ..kinematics.limits import Limits
from ..field.identity import Field
from ..render.cameras import Cameras
from ..render.gaussians import GaussianRobot
from ..robot.gate import Layout, finite, positive
from ..exact.certification import certified_summary, certify_poses, failures_of
from ..robot.robot import Robot
from ..field.layout import field_at_layout
from ..exact.certification import CLEARANCE
from ._common import labeller_robot
from .scorers import Scorer

__all__ = ["TextResult", "pose_from_text"]


@dataclass
class TextResult:
    """``runs`` optimisations of one prompt.

    Attributes:
        poses: (R, K) returned poses; score: (R,) the scorer's value at them (CLIP: raw dot
        product); score_before_repair: (R,) at the end of the optimisation; certified: (R,) the
        returned pose is certified free (:mod:`profrobot.exact.certification`); certified_before_repair:
        (R,) the optimised pose was (the others were then resolved on the field); g: (R,) the field at the
        returned pose (NaN without one); history: (iterations, R) score per step;
        iterations: Adam steps per run; seconds.
    """

    poses: np.ndarray
    score: np.ndarray
    score_before_repair: np.ndarray
    certified: np.ndarray
    certified_before_repair: np.ndarray
    g: np.ndarray
    history: np.ndarray
    seconds: float
    iterations: int = 0

    @property
    def failures(self) -> np.ndarray:
        """Indices of runs whose returned pose is not certified free."""
        return failures_of(self.certified)

    def summary(self) -> str:
        return (f"{len(self.poses)} runs: score {self.score.mean():.3f} ± {self.score.std():.3f}, "
                f"{1 - self.certified_before_repair.mean():.0%} not certified before repair, "
                f"{certified_summary(self.certified)}; {self.seconds:.1f} s")


def pose_from_text(model: GaussianRobot, prompt: str, scorer: Scorer, *, camera: Cameras, sdf: Field | None = None,
                   init: npt.ArrayLike | None = None, runs: int = 1, iterations: int = 200, lr: float = 0.01,
                   beta: float = 10.0, l_thres: float = -0.1, background: npt.ArrayLike = (1.0, 1.0, 1.0),
                   noise: float = 0.0, seed: int = 0, robot: Robot | None = None, layout: Layout | None = None,
                   margin: float = CLEARANCE) -> TextResult:
    """Joint angles whose render from ``camera`` (a one-camera :class:`~profrobot.render.Cameras`)
    best matches ``prompt`` under ``scorer`` (:mod:`profrobot.inverse.scorers`).

    ``init`` (K,) start (default: the zero pose, clipped into the limits, as the paper's hand);
    ``runs`` starts optimised as one batch, perturbed by ``noise`` radians (seeded). Adam
    (``lr``, ``iterations`` steps) on −score + ``beta`` ReLU(g − l_thres) (the latter with ``sdf``).
    Then every pose is labelled by the exact labeller (``robot``: default the field's; without a
    field required to label); with a field, colliding poses are resolved and re-certified.
    ``scene``: for a field of a family of scenes (:mod:`profrobot.robot.family`), the layout δ to work
    at; answers are certified at exactly that layout. ``margin``: metres every certified answer keeps from the obstacles (:mod:`profrobot.robot.margin`).
    """
    t0 = time.perf_counter()
    if not hasattr(scorer, "encode_image") or not hasattr(scorer, "encode_text") or not hasattr(scorer, "score"):
        raise InputTypeError(f"scorer must have encode_text, encode_image and score; got {type(scorer).__name__}")
    sdf, robot = field_at_layout(sdf, robot, layout)
    robot = labeller_robot(sdf, model, robot, "pose_from_text", margin=margin)
    if len(camera) != 1:
        raise InputError(f"pose_from_text renders from one camera; got {len(camera)}")
    runs = positive("runs", runs, integer=True)
    iterations = positive("iterations", iterations, integer=True, allow_zero=True)
    lr, beta, l_thres, noise = positive("lr", lr), finite("beta", beta), finite("l_thres", l_thres), finite("noise", noise)
    dev = model.means.device
    limits = Limits.of(model, like=model.means)
    K = model.njoint
    q0 = np.zeros(K) if init is None else np.asarray(init, dtype=np.float64).reshape(-1)
    if q0.shape != (K,) or not np.isfinite(q0).all():
        raise InputError(f"init must be {K} finite joint values; got {np.asarray(init).shape}")
    q0 = np.clip(q0, limits.lim_np[:, 0], limits.lim_np[:, 1])
    gen = torch.Generator().manual_seed(seed)
    start = torch.as_tensor(q0, dtype=torch.float32).repeat(runs, 1) + noise * torch.randn(runs, K, generator=gen)
    theta = torch.nn.Parameter(limits.clamp_or_wrap(start.to(dev)))
    opt = torch.optim.Adam([theta], lr=lr)
    goal = scorer.encode_text(prompt).detach()
    vm = torch.as_tensor(camera.world_to_cam, dtype=torch.float32, device=dev)
    Ks = torch.as_tensor(camera.K, dtype=torch.float32, device=dev)
    bg = torch.as_tensor(np.asarray(background, dtype=np.float32), device=dev)
    W, H = camera.width, camera.height

    def score(th):
        out = model.render_unchecked(th, vm, Ks, W, H, background=bg)
        return scorer.score(scorer.encode_image(out.rgb), goal)

    hist = []
    for _ in range(iterations):
        s = score(theta)
        loss = -s.sum()
        if sdf is not None:
            loss = loss + beta * torch.relu(sdf(theta.to(sdf.joint_limits.device)) - l_thres).sum().to(dev)
        opt.zero_grad()
        loss.backward()
        opt.step()
        with torch.no_grad():
            limits.clamp_or_wrap_(theta)
        hist.append(s.detach().cpu().numpy())
    poses = limits.numpy(theta.detach().cpu().numpy().astype(np.float64))
    with torch.no_grad():
        before = score(theta).cpu().numpy().astype(np.float64)
    certified = certify_poses(robot, poses)
    collided = ~certified
    after = before.copy()
    if sdf is not None and collided.any():
        from ..optim import resolve

        bad = np.flatnonzero(collided)
        r = resolve(sdf, poses[bad], l_thres=l_thres, robot=robot)
        poses[bad] = r.poses
        certified[bad] = r.certified
        with torch.no_grad():
            after[bad] = score(torch.as_tensor(poses[bad], dtype=torch.float32, device=dev)).cpu().numpy()
    g = (np.full(runs, np.nan) if sdf is None else
         sdf(torch.as_tensor(poses, dtype=torch.float32, device=sdf.joint_limits.device)).detach().cpu().numpy())
    return TextResult(poses=poses, score=after, score_before_repair=before, certified=certified,
                      certified_before_repair=~collided, g=np.asarray(g, dtype=np.float64),
                      history=np.array(hist).reshape(iterations, runs), iterations=iterations, seconds=time.perf_counter() - t0)
