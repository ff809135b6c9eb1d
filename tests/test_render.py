"""Rendering a simulation to pictures (needs matplotlib, the `render` extra)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.tasks.reach import LINK_LENGTH, ReachEnv, arm
from jaxsim import characters, kinematics, rest_pose, render
from jaxsim.world import Box, make_world

pytest.importorskip("matplotlib", reason="the render extra is part of the test extra")


@pytest.fixture(scope="module")
def poses():
    model = characters.humanoid()
    q = rest_pose(model, 0.9)
    bend = q.at[7:11].set(jnp.array(np.array([0.9, 0.0, 0.0, 0.43]) / np.hypot(0.9, 0.43),
                                    q.dtype))
    return model, jnp.stack([q, bend, q])


def _is_png(path):
    return path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_filmstrip_gif_and_frames_are_written(tmp_path, poses):
    model, qs = poses
    world = make_world(boxes=[Box("bar", (0.5, 1.0, 0.0), (0.02, 0.02, 1.0))])
    render.filmstrip(model, qs, tmp_path / "strip.png", world=world, times=[0, 0.1, 0.2])
    render.animation(model, qs, tmp_path / "clip.gif", world=world, style="sticks")
    paths = render.frames(model, qs, tmp_path / "frames", azimuth=90, elevation=20)
    assert _is_png(tmp_path / "strip.png")
    assert (tmp_path / "clip.gif").read_bytes()[:6] == b"GIF89a"
    assert len(paths) == 3 and all(_is_png(tmp_path / "frames" / p.split("/")[-1])
                                   for p in paths)
    leftovers = [p for p in tmp_path.rglob("*") if p.is_file() and p.name.startswith("tmp")]
    assert not leftovers


def test_the_picture_shows_the_body(tmp_path, poses):
    from matplotlib.image import imread
    model, qs = poses
    render.filmstrip(model, qs[:1], tmp_path / "one.png", n_panels=1)
    image = imread(tmp_path / "one.png")[..., :3]
    body_blue = np.all(np.abs(image - np.array([0x4c, 0x72, 0xb0]) / 255) < 0.02, axis=-1)
    assert body_blue.mean() > 0.005


def test_camera_is_a_rotation():
    view = render.camera(30, 15)
    np.testing.assert_allclose(view @ view.T, np.eye(3), atol=1e-12)


def test_unknown_style_is_refused(tmp_path, poses):
    model, qs = poses
    with pytest.raises(ValueError, match="style must be one of"):
        render.filmstrip(model, qs, tmp_path / "x.png", style="wireframe")


def test_views_show_one_pose_from_each_camera(tmp_path, poses):
    """A pose from the side and from the front: two panels, each with the body in it."""
    from matplotlib.image import imread
    model, qs = poses
    render.views(model, qs[1], tmp_path / "views.png", azimuths=(0.0, 90.0),
                 labels=("side", "front"))
    image = imread(tmp_path / "views.png")[..., :3]
    body_blue = np.all(np.abs(image - np.array([0x4c, 0x72, 0xb0]) / 255) < 0.02, axis=-1)
    left, right = np.array_split(body_blue, 2, axis=1)
    assert left.mean() > 0.003 and right.mean() > 0.003


GROUND_FILL, GROUND_LINE, MARKER = "#e8e4da", "#8a8272", "#c44e52"


def _has_colour(image, colour, tolerance=0.02):
    rgb = np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)]) / 255
    return np.all(np.abs(image[..., :3] - rgb) < tolerance, axis=-1)


def _arm_points(model, q):
    """Base, elbow and tip of the two-link arm in pose q, in world coordinates."""
    _, pos = kinematics.forward_kinematics(model, q)
    tip = kinematics.point_positions(model, q, np.array([2]),
                                     jnp.array([[LINK_LENGTH, 0.0, 0.0]], q.dtype))[0]
    return np.vstack([np.asarray(pos), np.asarray(tip)[None]])


def test_a_world_without_ground_draws_no_ground_and_frames_the_whole_arm(tmp_path,
                                                                          monkeypatch):
    """The reach arm hangs below the origin in a world with no ground: no ground is drawn and
    every panel's limits hold the whole arm, hanging, bent or raised."""
    from matplotlib.image import imread
    model, world = arm(), make_world(ground=False)
    qs = jnp.array([[-np.pi / 2, 0.0], [-np.pi / 2, 1.2], [0.4, -2.5]], model.mass.dtype)
    limits, save = [], render.save_figure

    def keep_limits(fig, *args, **kwargs):
        limits.extend((ax.get_xlim(), ax.get_ylim()) for ax in fig.axes)
        save(fig, *args, **kwargs)

    monkeypatch.setattr(render, "save_figure", keep_limits)
    render.filmstrip(model, qs, tmp_path / "arm.png", world=world, n_panels=3)
    assert len(limits) == 3
    radius = 0.05                                       # the base sphere; links are thinner
    for q, (xlim, ylim) in zip(qs, limits):
        points = _arm_points(model, q)
        assert xlim[0] < points[:, 0].min() - radius and points[:, 0].max() + radius < xlim[1]
        assert ylim[0] < points[:, 1].min() - radius and points[:, 1].max() + radius < ylim[1]
    image = imread(tmp_path / "arm.png")
    assert not _has_colour(image, GROUND_FILL).any() and not _has_colour(image, GROUND_LINE).any()
    body_blue = _has_colour(image, "#4c72b0")
    assert all(panel.mean() > 0.003 for panel in np.array_split(body_blue, 3, axis=1))


def test_markers_are_drawn_fixed_or_per_frame(tmp_path):
    """A task's points (the reach goal) are drawn in every panel and frame, whether one set for
    the whole clip or one per frame; without markers nothing of their colour is drawn."""
    from matplotlib.image import imread
    model, world = arm(), make_world(ground=False)
    qs = jnp.array([[-np.pi / 2, 0.0], [0.0, 0.5]], model.mass.dtype)
    goal = np.array([[0.3, -0.6, 0.0]])
    render.filmstrip(model, qs, tmp_path / "plain.png", world=world)
    render.filmstrip(model, qs, tmp_path / "fixed.png", world=world, markers=goal)
    render.filmstrip(model, qs, tmp_path / "moving.png", world=world,
                     markers=np.stack([goal, goal + 0.2]))
    paths = render.frames(model, qs, tmp_path / "frames", world=world, markers=goal)
    assert not _has_colour(imread(tmp_path / "plain.png"), MARKER).any()
    for name in ("fixed.png", "moving.png"):
        marked = _has_colour(imread(tmp_path / name), MARKER)
        assert all(panel.any() for panel in np.array_split(marked, 2, axis=1))
    assert all(_has_colour(imread(path), MARKER).any() for path in paths)


def test_reach_offers_its_goal_as_a_marker():
    env = ReachEnv()
    state = env.reset(env.default_params(), jax.random.PRNGKey(3))
    np.testing.assert_array_equal(np.asarray(env.markers(state.task)),
                                  np.asarray(state.task)[None])


def test_the_gif_holds_one_frame_per_pose_even_when_poses_repeat(tmp_path):
    """A still arm for 12 control steps at 30 Hz: 12 frames (Pillow would merge identical
    consecutive frames) lasting 0.4 s in all (GIF delays are whole centiseconds)."""
    from PIL import Image
    model = arm()
    qs = jnp.zeros((12, 2), model.mass.dtype)
    render.animation(model, qs, tmp_path / "still.gif", world=make_world(ground=False),
                     fps=30.0, markers=np.array([[0.5, 0.5, 0.0]]))
    with Image.open(tmp_path / "still.gif") as gif:
        assert gif.n_frames == 12
        durations = []
        for k in range(gif.n_frames):
            gif.seek(k)
            durations.append(gif.info["duration"])
    assert sum(durations) == 400 and max(durations) - min(durations) <= 10
