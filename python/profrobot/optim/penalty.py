"""The collision penalty L_SDF = ReLU(g(θ) − l_thres) (paper §4.2), for any torch loss."""

from __future__ import annotations

import torch

from ..field.identity import Field, check_field
from ..field.layout import field_at_layout
from ..robot.gate import Layout, finite
from ..errors import InputError, InputTypeError


def collision_penalty(sdf: Field, theta: torch.Tensor, l_thres: float = -0.1, *,
                      layout: Layout | None = None) -> torch.Tensor:
    """ReLU(g(θ) − l_thres) per pose: θ (..., K) radians / metres → (...,), differentiable in θ
    (and in the field's parameters). Zero once the field puts a pose ``-l_thres`` inside the free
    region; add ``β · penalty.mean()`` to a loss to keep its poses out of collision.

    Raises TypeError for a non-tensor or non-float θ, ValueError for a last dimension that is not
    the field's joint count or for NaN/inf poses. A family field (:mod:`profrobot.robot.family`) needs
    ``scene``, the layout δ (θ then holds the robot joints only; δ is never moved).
    """
    check_field(sdf)
    sdf, _ = field_at_layout(sdf, None, layout)  # a family field at its layout: the penalty moves θ, never δ
    l_thres = finite("l_thres", l_thres)
    if not isinstance(theta, torch.Tensor):
        raise InputTypeError(f"theta must be a torch.Tensor; got {type(theta).__name__}")
    if not theta.is_floating_point():
        raise InputTypeError(f"theta must be a floating-point tensor; got {theta.dtype}")
    if theta.ndim == 0 or theta.shape[-1] != sdf.njoint:
        raise InputError(f"theta must have shape (..., {sdf.njoint}) for robot {getattr(sdf, 'robot_name', '?')!r}; "
                         f"got {tuple(theta.shape)}")
    if not torch.isfinite(theta).all():
        raise InputError("theta contains NaN or inf")
    lead = theta.shape[:-1]
    g = sdf(theta.reshape(-1, sdf.njoint))
    return torch.relu(g - l_thres).reshape(lead)
