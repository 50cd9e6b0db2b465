"""Inverse problems through the renderer (profrobot.inverse): the baseline reports collisions
without correcting them, the field phase stops at the threshold, certify-and-continue reports
what it cannot fix, and bad input raises errors naming the problem."""

import numpy as np
import pytest
import torch

import profrobot
from profrobot.exact import problems
from profrobot.errors import ProfrobotError, RobotMismatchError
from profrobot.field import PoseSDF
from profrobot.inverse import pose_from_images
from profrobot.render import GaussianRobot, ring_cameras


@pytest.fixture(scope="module")
def setup(panda):
    torch.manual_seed(0)
    model = GaussianRobot.from_robot(panda, 1500, seed=0)
    cams = ring_cameras(2, size=32, distance=1.6, lookat=(0.0, 0.0, 0.45))
    target = problems.colliding_poses(panda, 2, 7)                 # they hit the blocks
    with torch.no_grad():
        out = model.render_views(torch.as_tensor(target, dtype=torch.float32), cams)
    t = dict(rgb=out.rgb.reshape(2, 2, 32, 32, 3).numpy(), depth=out.depth.reshape(2, 2, 32, 32).numpy(),
             mask=(out.alpha > 0.5).reshape(2, 2, 32, 32).numpy())
    return model, cams, target, t


def _field(robot, shift):
    torch.manual_seed(0)
    sdf = PoseSDF(robot, hidden=(16,))
    with torch.no_grad():
        sdf.head[-1].bias += shift
    return sdf


def test_baseline_labels_but_does_not_correct(panda, setup):
    model, cams, target, t = setup
    r = pose_from_images(model, t, cams, init=target + 0.02, image_iterations=5, robot=panda)
    assert r.poses.shape == target.shape and r.image_iterations == 5 and (r.iterations == 0).all()
    assert np.isnan(r.g).all()
    # the images do not show the blocks: the answer stays near the colliding target
    assert (~r.certified).any() and set(r.failures) == set(np.flatnonzero(~r.certified))
    assert "certified" in r.summary()


def test_uncertified_baseline_is_never_reported_certified(setup):
    """Issue 19: with no field and no robot= there is no scene to check against; the poses hit
    the blocks, and the old answer called every one of them certified."""
    model, cams, target, t = setup
    r = pose_from_images(model, t, cams, init=target + 0.02, image_iterations=2)
    assert r.certified is None and r.certified_before_continue is None and r.failures is None
    assert "not checked" in r.summary() and "certified free" not in r.summary()
    assert r.poses.shape == target.shape and np.isfinite(r.image_loss).all()


def test_field_phase_stops_at_the_threshold_and_failures_are_reported(panda, setup):
    model, cams, target, t = setup
    # a field that calls every pose free (g ~ -100): the field phase takes no step, the labeller
    # still finds the collisions, certify-and-continue cannot help (g is already below every
    # lowered threshold); the last resort, resolve, answers them with the labeller's own
    # nearest-free search, and every returned pose is certified by the labeller
    r = pose_from_images(model, t, cams, init=target, image_iterations=2, sdf=_field(panda, -100.0), refine_rounds=2)
    assert (r.iterations == 0).all() and r.field_free_before_certify.all()
    stuck = ~r.certified_before_continue
    assert stuck.any() and r.rounds == 2
    assert np.allclose(r.threshold[stuck], -0.1 - 2 * 0.05)
    assert r.history[-1]["round"] == "resolve" and r.certified.all()
    assert profrobot.certify_poses(panda, r.poses).all()
    # a field that calls every pose colliding (g ~ +100): every pose runs its whole budget
    r = pose_from_images(model, t, cams, init=target, image_iterations=0, sdf=_field(panda, 100.0), field_iterations=3,
                         refine_rounds=0)
    assert (r.iterations == 3).all() and not r.field_free_before_certify.any()


def test_bad_input(panda, ur5e, setup):
    model, cams, target, t = setup
    with pytest.raises(RobotMismatchError):
        pose_from_images(model, t, cams, init=target, sdf=_field(ur5e, 0.0))
    with pytest.raises(ProfrobotError, match="init"):
        pose_from_images(model, t, cams, init=np.zeros((2, 4)))
    with pytest.raises(ProfrobotError, match="cameras"):
        pose_from_images(model, t, ring_cameras(3, size=32), init=target)
    bad = dict(t, rgb=np.full_like(t["rgb"], np.nan))
    with pytest.raises(ProfrobotError, match="NaN"):
        pose_from_images(model, bad, cams, init=target, image_iterations=1)
    with pytest.raises(ProfrobotError, match="targets"):
        pose_from_images(model, dict(rgb=t["rgb"]), cams, init=target)
    with pytest.raises(ProfrobotError, match="beta"):
        pose_from_images(model, t, cams, init=target, beta=float("nan"), sdf=_field(panda, 0.0))
    assert profrobot.pose_from_images is pose_from_images


def test_trajectory_from_images_frames_and_certificate(panda, setup):
    """Baseline: every iterate is a frame, from the start towards the pose in the images; the
    certificate covers every frame and dense segment. With a field that calls everything free
    nothing is smoothed away, and a colliding result is reported, or replaced by a certified
    planner path between free ends, never returned as free while colliding."""
    from profrobot.inverse import trajectory_from_images

    model, cams, _, _ = setup
    a, b = problems.free_poses(panda, 2, 11)
    with torch.no_grad():
        out = model.render_views(torch.as_tensor(b[None], dtype=torch.float32), cams)
    t = dict(rgb=out.rgb.numpy(), depth=out.depth.numpy(), mask=(out.alpha > 0.5).numpy())
    r = trajectory_from_images(model, t, cams, start=a, goal=b, steps=12, robot=panda)
    assert r.path.shape == (12, panda.njoint) and np.allclose(r.path[0], a) and r.method == "images"
    assert np.linalg.norm(r.path[-1] - b) < np.linalg.norm(a - b)            # moved towards the goal
    assert r.certified == (not r.waypoint_uncertified.any() and not r.segment_uncertified.any())
    f = trajectory_from_images(model, t, cams, start=a, goal=b, steps=12, sdf=_field(panda, -100.0), smooth_iterations=5)
    assert f.certified or f.method != "images+planner"
    assert f.certified == (not f.waypoint_uncertified.any() and not f.segment_uncertified.any())
    with pytest.raises(ProfrobotError, match="robot="):
        trajectory_from_images(model, t, cams, start=a, steps=5)
    with pytest.raises(ProfrobotError, match="steps"):
        trajectory_from_images(model, t, cams, start=a, steps=2, robot=panda)


def test_actions_from_video_tracks_a_free_trajectory(panda, setup):
    """Frames rendered along a short free path are tracked frame to frame; the result is
    certified per frame and segment; a field that calls everything free only refines."""
    from profrobot.inverse import actions_from_video

    model, cams, _, _ = setup
    a = problems.free_poses(panda, 1, 21)[0]
    path = np.stack([a + np.r_[0.02 * t * np.ones(7), 0, 0] for t in range(4)])
    with torch.no_grad():
        out = model.render_views(torch.as_tensor(path, dtype=torch.float32), cams)
    f = dict(rgb=out.rgb.reshape(4, 2, 32, 32, 3).numpy(), depth=out.depth.reshape(4, 2, 32, 32).numpy(),
             mask=(out.alpha > 0.5).reshape(4, 2, 32, 32).numpy())
    r = actions_from_video(model, f, cams, init=path[0] + 0.01, iterations_per_frame=4, joint_iterations=3, robot=panda)
    assert r.path.shape == (4, panda.njoint) and r.method == "video"
    assert np.median(np.abs(r.path - path)[:, :7]) < 0.03
    assert r.certified == (not r.waypoint_uncertified.any() and not r.segment_uncertified.any())
    rf = actions_from_video(model, f, cams, init=path[0] + 0.01, iterations_per_frame=4, joint_iterations=3,
                            sdf=_field(panda, -100.0))
    # the field's stage adds joint_iterations more steps (its penalty is 0 here): only image refinement
    assert rf.method == "video+field" and np.abs(rf.path - r.path).max() < 0.02
    assert rf.certified == (not rf.waypoint_uncertified.any() and not rf.segment_uncertified.any())
    with pytest.raises(ProfrobotError, match="2 frames"):
        actions_from_video(model, {k: v[:1] for k, v in f.items()}, cams, init=path[0], robot=panda)
    with pytest.raises(ProfrobotError, match="init"):
        actions_from_video(model, f, cams, init=path[0][:3], robot=panda)


def test_family_fields_work_at_a_layout_and_certify_there(setup):
    """A family field (obstacles on scene joints) needs the layout; given layout=δ every inverse
    problem certifies at exactly that layout (the front block moved 15 cm, rotated 0.5 rad)."""
    from profrobot.inverse import actions_from_video, trajectory_from_images

    model, cams, target, t = setup
    family = profrobot.scenes.load("panda_blocks_moving")
    sdf = _field(family, -100.0)                     # calls every pose free: the labeller decides
    delta = np.zeros(9)
    delta[[0, 2]] = 0.15, 0.5
    layout = family.at(delta)
    with pytest.raises(ProfrobotError, match="pass layout="):
        pose_from_images(model, t, cams, init=target, sdf=sdf, image_iterations=1)
    r = pose_from_images(model, t, cams, init=target + 0.02, sdf=sdf, layout=delta, image_iterations=2,
                         field_iterations=2, refine_rounds=0)
    # certified means certified at the layout: the exact labeller with the certification margin
    # (a pose closer than CLEARANCE to contact is free to label_poses but not certified)
    np.testing.assert_array_equal(r.certified, profrobot.certify_poses(layout, r.poses))
    same = pose_from_images(model, t, cams, init=target + 0.02, sdf=sdf, robot=layout, image_iterations=2,
                            field_iterations=2, refine_rounds=0)
    np.testing.assert_array_equal(same.poses, r.poses)
    one = {k: v[0] for k, v in t.items()}
    a = problems.free_poses(layout, 1, 5)[0]
    tr = trajectory_from_images(model, one, cams, start=a, steps=6, sdf=sdf, layout=delta, smooth_iterations=2)
    np.testing.assert_array_equal(tr.waypoint_uncertified, ~profrobot.certify_poses(layout, tr.path))
    frames = {k: np.stack([v[0], v[0]]) for k, v in t.items()}
    v = actions_from_video(model, frames, cams, init=a, sdf=sdf, layout=delta, iterations_per_frame=1,
                           first_frame_iterations=1, joint_iterations=1)
    np.testing.assert_array_equal(v.waypoint_uncertified, ~profrobot.certify_poses(layout, v.path))
