"""Held-out metrics of a field: classification, ranking, and how distance-like g is."""

from __future__ import annotations

import numpy as np
import torch
from scipy.stats import rankdata

from .model import PoseSDF


@torch.no_grad()
def field_values(sdf: PoseSDF, poses: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """g (N,) for poses (N, K), evaluated in chunks without gradients."""
    dev = sdf.joint_limits.device
    out = [sdf(torch.as_tensor(poses[i:i + chunk], dtype=torch.float32, device=dev)).cpu().numpy()
           for i in range(0, len(poses), chunk)]
    return np.concatenate(out) if out else np.zeros(0, dtype=np.float32)


def _values_and_gradient_norms(sdf: PoseSDF, poses: np.ndarray, chunk: int = 2048) -> tuple[np.ndarray, np.ndarray]:
    """g (N,) and ‖∂g/∂θ‖₂ (N,) for poses (N, K), one backward pass (see :func:`gradient_norms`)."""
    gs, out = [], []
    dev = sdf.joint_limits.device
    for i in range(0, len(poses), chunk):
        q = torch.as_tensor(poses[i:i + chunk], dtype=torch.float32, device=dev).requires_grad_(True)
        g = sdf(q)
        (grad,) = torch.autograd.grad(g.sum(), q)
        if getattr(sdf, "scene_joints", None):
            grad = grad[:, sdf.robot_index]
        gs.append(g.detach().cpu().numpy())
        out.append(grad.norm(dim=1).cpu().numpy())
    empty = np.zeros(0, dtype=np.float32)
    return (np.concatenate(gs), np.concatenate(out)) if out else (empty, empty)


def _classifier_norms(sdf: PoseSDF, g: np.ndarray, norms: np.ndarray) -> np.ndarray:
    """The classifier's ‖∂σ(s·g)/∂θ‖₂ = s·σ(s·g)·(1 − σ(s·g))·‖∂g/∂θ‖₂ (N,) from g and ‖∂g/∂θ‖₂: it
    vanishes wherever the classifier is confident, whatever the size of ∇g."""
    s = float(sdf.scale.detach())
    f = 1.0 / (1.0 + np.exp(-s * g.astype(np.float64)))
    return (s * f * (1 - f) * norms).astype(np.float32)


def gradient_norms(sdf: PoseSDF, poses: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """‖∂g/∂θ‖₂ (N,) for poses (N, K) (over the whole pose vector, as the paper's Eikonal term; for
    a family field over the robot joints θ, as its training's Eikonal term)."""
    return _values_and_gradient_norms(sdf, poses, chunk)[1]


def gradient_summary(sdf: PoseSDF, poses: np.ndarray) -> dict:
    """On poses (N, K), from one backward pass: the mean ‖∇g‖ (``grad_norm``), the Eikonal loss
    mean (‖∇g‖ − 1)² (``eikonal_loss``) and the classifier's mean ‖∇σ(s·g)‖
    (``classifier_grad_norm``)."""
    g, norms = _values_and_gradient_norms(sdf, poses)
    return dict(eikonal_loss=float(np.mean((norms - 1) ** 2)), grad_norm=float(np.mean(norms)),
                classifier_grad_norm=float(np.mean(_classifier_norms(sdf, g, norms))))


def auroc(score: np.ndarray, label: np.ndarray) -> float:
    """Area under the ROC curve (Mann–Whitney U with tied ranks averaged)."""
    label = np.asarray(label, dtype=bool)
    n1, n0 = int(label.sum()), int((~label).sum())
    if n1 == 0 or n0 == 0:
        return float("nan")
    r = rankdata(score)
    return float((r[label].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def evaluate(sdf: PoseSDF, poses: np.ndarray, collides: np.ndarray, *, gradient_poses: int = 10_000) -> dict:
    """Metrics on labelled poses (N, K), labels (N,) bool (True = colliding):

    accuracy, precision and recall of "colliding" (g > 0); ``false_free_rate``: the share of poses
    predicted free that actually collide (the error that breaks robots); AUROC of g; and on the
    first ``gradient_poses`` poses the Eikonal loss mean (‖∇g‖ − 1)², the mean ‖∇g‖, and the mean
    gradient norm of the classifier σ(s·g) (``classifier_grad_norm``).
    """
    collides = np.asarray(collides, dtype=bool)
    was_training = sdf.training
    sdf.eval()
    g = field_values(sdf, poses)
    pred = g > 0
    tp = int((pred & collides).sum())
    fp = int((pred & ~collides).sum())
    fn = int((~pred & collides).sum())
    tn = int((~pred & ~collides).sum())
    grads = gradient_summary(sdf, poses[:gradient_poses])
    sdf.train(was_training)
    return dict(
        n=len(g), accuracy=(tp + tn) / max(len(g), 1), precision=tp / max(tp + fp, 1), recall=tp / max(tp + fn, 1),
        false_free_rate=fn / max(fn + tn, 1), auroc=auroc(g, collides),
        **grads,
    )


def format_metrics(m: dict) -> str:
    """A small two-column table of metrics."""
    rows = [(k, f"{v:.4f}" if isinstance(v, float) else str(v)) for k, v in m.items()]
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)
