"""Rendering a simulation to pictures (needs matplotlib, the `render` extra)."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import characters, rest_pose, render
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
