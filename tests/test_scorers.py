"""Scorers for pose_from_text: the real CLIP loading path on a tiny randomly initialised
CLIPModel built from a config (no weights can be downloaded here), CLIP's preprocessing,
gradients from the score to the joint angles; the image-goal scorer; bad input."""

import json

import mujoco
import numpy as np
import pytest
import torch

import profrobot
from profrobot.errors import ProfrobotError
from profrobot.inverse import pose_from_text
from profrobot.render import GaussianRobot, ring_cameras
from profrobot.inverse.scorers import CLIPScorer, ImageGoalScorer

transformers = pytest.importorskip("transformers")

ARM = """<mujoco><compiler angle="radian"/>
  <asset><mesh name="bar" vertex="-.04 -.04 0  .04 -.04 0  .04 .04 0  -.04 .04 0  -.04 -.04 .3  .04 -.04 .3  .04 .04 .3  -.04 .04 .3"/></asset>
  <worldbody>
    <body name="l1"><joint name="j1" type="hinge" axis="0 0 1" range="-3 3"/><geom type="mesh" mesh="bar" rgba="0.1 0.1 0.1 1"/>
      <body name="l2" pos="0 0 0.3"><joint name="j2" type="hinge" axis="0 1 0" range="-2 2"/>
        <geom type="mesh" mesh="bar" rgba="0.2 0.6 0.9 1"/></body>
    </body>
  </worldbody></mujoco>"""


@pytest.fixture(scope="module")
def tiny_clip(tmp_path_factory):
    """A saved tiny CLIP (random weights from a config) with a character-level tokenizer."""
    from transformers import CLIPConfig, CLIPModel, CLIPTokenizer

    d = tmp_path_factory.mktemp("tinyclip")
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for c in "abcdefghijklmnopqrstuvwxyz":
        vocab[c] = len(vocab)
        vocab[c + "</w>"] = len(vocab)
    (d / "vocab.json").write_text(json.dumps(vocab))
    (d / "merges.txt").write_text("#version: 0.2\n")
    CLIPTokenizer(str(d / "vocab.json"), str(d / "merges.txt")).save_pretrained(d)
    torch.manual_seed(0)
    cfg = CLIPConfig(text_config=dict(vocab_size=len(vocab), hidden_size=32, intermediate_size=64, num_hidden_layers=2,
                                      num_attention_heads=2, max_position_embeddings=77, bos_token_id=0,
                                      eos_token_id=1, pad_token_id=1),
                     vision_config=dict(hidden_size=32, intermediate_size=64, num_hidden_layers=2,
                                        num_attention_heads=2, image_size=224, patch_size=32),
                     projection_dim=16)
    CLIPModel(cfg).save_pretrained(d)
    return str(d)


@pytest.fixture(scope="module")
def arm():
    return profrobot.Robot.from_spec(mujoco.MjSpec.from_string(ARM), name="arm")


def test_clip_scorer_loads_and_its_gradient_reaches_the_joints(tiny_clip, arm):
    scorer = CLIPScorer.from_pretrained(tiny_clip)
    text = scorer.encode_text("a black robotic hand do ok gestures with white background")
    assert text.shape == (16,)
    model = GaussianRobot.from_robot(arm, 300, seed=0)
    cam = ring_cameras(1, size=32, distance=1.4, elevation=-60.0, lookat=(0, 0, 0.3))
    theta = torch.tensor([[0.3, 0.5]], requires_grad=True)
    out = model.render_views(theta, cam, background=torch.ones(3))
    feats = scorer.encode_image(out.rgb)
    assert feats.shape == (1, 16)
    s = scorer.score(feats, text)
    assert torch.allclose(s, feats @ text)                         # the paper: raw dot product
    s.sum().backward()
    assert theta.grad is not None and theta.grad.abs().sum() > 0
    cos = CLIPScorer.from_pretrained(tiny_clip, mode="cosine").score(feats.detach(), text)
    assert torch.allclose(cos, 100 * torch.nn.functional.cosine_similarity(feats.detach(), text[None]))
    # CLIP's preprocessing: 224 x 224, normalised with CLIP's mean and std
    px = scorer.preprocess(torch.ones(2, 40, 30, 3))
    assert px.shape == (2, 3, 224, 224)
    assert torch.allclose(px[0, :, 0, 0], (1 - scorer.mean[0, :, 0, 0]) / scorer.std[0, :, 0, 0])

    r = pose_from_text(model, "ok", scorer, camera=cam, runs=2, iterations=3, noise=0.1, robot=arm)
    assert r.poses.shape == (2, 2) and r.history.shape == (3, 2) and r.certified.all()
    assert not np.allclose(r.poses, 0.0)                            # the score moved the joints


def test_image_goal_scorer_prefers_the_goal_pose(arm):
    model = GaussianRobot.from_robot(arm, 300, seed=0)
    cam = ring_cameras(1, size=32, distance=1.4, elevation=-20.0, lookat=(0, 0, 0.3))
    goal_theta = torch.tensor([[0.0, 1.0]])
    with torch.no_grad():
        goal = model.render_views(goal_theta, cam, background=torch.ones(3)).rgb[0].numpy()
    sc = ImageGoalScorer(goal, size=16)
    r = pose_from_text(model, "bent", sc, camera=cam, init=[0.0, 0.6], iterations=60, lr=0.02, robot=arm)
    assert abs(r.poses[0, 1] - 1.0) < abs(0.6 - 1.0)
    assert r.score[0] > r.history[0, 0]


def test_bad_input(tiny_clip, arm):
    with pytest.raises(ProfrobotError, match="could not load"):
        CLIPScorer.from_pretrained(tiny_clip + "_missing")
    scorer = CLIPScorer.from_pretrained(tiny_clip)
    with pytest.raises(ProfrobotError, match="mode"):
        CLIPScorer(scorer.model, scorer.tokenizer, mode="logits")
    with pytest.raises(ProfrobotError, match="images"):
        scorer.encode_image(torch.zeros(1, 3, 32, 32))
    with pytest.raises(ProfrobotError, match="prompt"):
        scorer.encode_text("")
    with pytest.raises(ProfrobotError, match="goal"):
        ImageGoalScorer(np.zeros((8, 8)))
    model = GaussianRobot.from_robot(arm, 100, seed=0)
    with pytest.raises(ProfrobotError, match="one camera"):
        pose_from_text(model, "x", scorer, camera=ring_cameras(2, size=16), robot=arm)
    with pytest.raises(ProfrobotError, match="robot="):
        pose_from_text(model, "x", scorer, camera=ring_cameras(1, size=16))
    with pytest.raises(TypeError, match="scorer"):
        pose_from_text(model, "x", object(), camera=ring_cameras(1, size=16), robot=arm)
