"""Scorers for :func:`profrobot.inverse.pose_from_text`: how well a render matches a goal.

A scorer has ``encode_text(prompt) -> Tensor (D,)``, a differentiable
``encode_image(images (B, H, W, 3) in [0, 1]) -> Tensor (B, D)``, and
``score(image_features (B, D), goal (D,)) -> Tensor (B,)`` (higher is better).

- :class:`CLIPScorer`: a frozen CLIP (``transformers``; ``pip install "profrobot[clip]"``). CLIP's
  own preprocessing (clamp to [0, 1], resize to 224 x 224, CLIP's mean and std; no crop or
  augmentation), and the paper's objective: the raw dot product of image and text features (no
  normalisation, no logit scale); ``mode="cosine"`` gives 100 x cosine instead.
- :class:`ImageGoalScorer`: the "prompt" is a goal image (e.g. a MuJoCo render of one of the
  Shadow Hand's named keyframe gestures); the score is minus the mean squared difference of
  the images at a low resolution. It runs where no CLIP weights can be had; tables say which
  scorer produced them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt
import torch
import torch.nn.functional as F

from ..errors import InputError

__all__ = ["Scorer", "CLIPScorer", "ImageGoalScorer"]

# OpenAI CLIP's normalisation (used when a checkpoint carries no image processor config)
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)


@runtime_checkable
class Scorer(Protocol):
    def encode_text(self, prompt: str) -> torch.Tensor: ...

    def encode_image(self, images: torch.Tensor) -> torch.Tensor: ...

    def score(self, image_features: torch.Tensor, goal: torch.Tensor) -> torch.Tensor: ...


class ClipModel(Protocol):
    """What :class:`CLIPScorer` uses of a ``transformers.CLIPModel`` (an optional dependency, not
    imported here): its parameters and its image and text feature heads."""

    def eval(self) -> Any: ...

    def parameters(self) -> Iterator[torch.nn.Parameter]: ...

    @property
    def get_image_features(self) -> Callable[..., Any]: ...

    @property
    def get_text_features(self) -> Callable[..., Any]: ...


def _features(out) -> torch.Tensor:
    """transformers < 5 returns the projected features; 5.x a ModelOutput holding them as
    ``pooler_output``."""
    return out if isinstance(out, torch.Tensor) else out.pooler_output


def _check_images(images) -> torch.Tensor:
    if not isinstance(images, torch.Tensor) or images.ndim != 4 or images.shape[-1] != 3:
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise InputError(f"images must be a (B, H, W, 3) tensor in [0, 1]; got {shape}")
    return images


class CLIPScorer:
    """A frozen CLIP model as a differentiable scorer (module docs). Build with
    :meth:`from_pretrained`, or from a ``transformers.CLIPModel`` and its tokenizer."""

    def __init__(self, model: ClipModel, tokenizer: Callable[..., Mapping[str, Any]], *,
                 mode: Literal["dot", "cosine"] = "dot", size: int = 224, mean: Sequence[float] = CLIP_MEAN,
                 std: Sequence[float] = CLIP_STD):
        if mode not in ("dot", "cosine"):
            raise InputError(f"mode must be 'dot' (the paper) or 'cosine'; got {mode!r}")
        self.model = model.eval()
        for p in self.model.parameters():
            p.requires_grad_(False)
        self.tokenizer, self.mode, self.size = tokenizer, mode, int(size)
        dev = next(self.model.parameters()).device
        self.mean = torch.tensor(mean, dtype=torch.float32, device=dev).reshape(1, 3, 1, 1)
        self.std = torch.tensor(std, dtype=torch.float32, device=dev).reshape(1, 3, 1, 1)

    @classmethod
    def from_pretrained(cls, path_or_name: str, *, mode: Literal["dot", "cosine"] = "dot",
                        device: str | torch.device = "cpu") -> "CLIPScorer":
        """CLIP weights and tokenizer from a local directory or a hub name (e.g.
        ``openai/clip-vit-base-patch32``); the normalisation and input size from the
        checkpoint's image processor config when it has one."""
        try:
            from transformers import AutoTokenizer, CLIPModel
        except ImportError as e:
            raise ImportError('CLIPScorer needs transformers: pip install "profrobot[clip]"') from e
        try:
            model = CLIPModel.from_pretrained(path_or_name).to(device)
            tokenizer = AutoTokenizer.from_pretrained(path_or_name)
        except OSError as e:
            raise InputError(f"could not load a CLIP model from {path_or_name!r}: {e}") from e
        mean, std, size = CLIP_MEAN, CLIP_STD, model.config.vision_config.image_size
        try:
            from transformers import CLIPImageProcessor

            proc = CLIPImageProcessor.from_pretrained(path_or_name)
            mean, std = tuple(proc.image_mean), tuple(proc.image_std)
        except (OSError, ValueError, ImportError):
            pass
        return cls(model, tokenizer, mode=mode, size=size, mean=mean, std=std)

    def preprocess(self, images: torch.Tensor) -> torch.Tensor:
        """(B, H, W, 3) in [0, 1] → CLIP's (B, 3, size, size) pixel values, differentiably."""
        x = _check_images(images).clamp(0.0, 1.0).permute(0, 3, 1, 2)
        x = F.interpolate(x, size=(self.size, self.size), mode="bilinear", align_corners=False, antialias=True)
        return (x - self.mean) / self.std

    def encode_image(self, images: torch.Tensor) -> torch.Tensor:
        return _features(self.model.get_image_features(pixel_values=self.preprocess(images)))

    @torch.no_grad()
    def encode_text(self, prompt: str) -> torch.Tensor:
        if not isinstance(prompt, str) or not prompt:
            raise InputError("prompt must be a non-empty string")
        dev = next(self.model.parameters()).device
        enc = self.tokenizer([prompt], return_tensors="pt", padding=True)
        return _features(self.model.get_text_features(**{k: v.to(dev) for k, v in enc.items()}))[0]

    def score(self, image_features: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        if self.mode == "cosine":
            return 100.0 * F.cosine_similarity(image_features, goal[None], dim=-1)
        return image_features @ goal                      # the paper: raw dot product


class ImageGoalScorer:
    """Score = −mean ((image − goal)²) at ``size`` x ``size`` (module docs). ``goal``: (H, W, 3)
    uint8 or [0, 1] image; ``encode_text`` ignores its prompt and returns the goal's features."""

    def __init__(self, goal: npt.ArrayLike, *, size: int = 64):
        g = np.asarray(goal)
        if g.ndim != 3 or g.shape[-1] != 3:
            raise InputError(f"goal must be an (H, W, 3) image; got shape {g.shape}")
        g = g.astype(np.float32) / 255.0 if g.dtype == np.uint8 else g.astype(np.float32)
        if not np.isfinite(g).all():
            raise InputError("goal image contains NaN or inf")
        self.size = int(size)
        self.goal = self.encode_image(torch.as_tensor(g)[None])[0]

    def encode_image(self, images: torch.Tensor) -> torch.Tensor:
        x = _check_images(images).permute(0, 3, 1, 2)
        x = F.interpolate(x, size=(self.size, self.size), mode="bilinear", align_corners=False, antialias=True)
        return x.reshape(len(x), -1)

    def encode_text(self, prompt: str) -> torch.Tensor:
        return self.goal

    def score(self, image_features: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        return -((image_features - goal[None]) ** 2).mean(-1)
