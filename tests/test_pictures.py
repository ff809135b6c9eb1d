"""The peak-pose pictures' facing arrow and marker (`agents.discovery.pictures.draw_facing`):
flat-shaded bodies look the same from the front and the back, so they are what shows a face-up
crossing from a face-down one. Checked on poses whose facing direction is known by
construction."""

import math

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="the render extra is part of the test extra")

from agents.discovery import pictures  # noqa: E402
from jaxsim import render  # noqa: E402

ROOT = np.array([0.3, 1.2, -0.4])


def _pose(turn_about_z: float) -> np.ndarray:
    """A root pose at ROOT turned about the world Z axis: +90° turns its X axis (the facing
    direction) to +Y, face up; −90° to −Y, face down."""
    half = math.radians(turn_about_z) / 2
    return np.concatenate([ROOT, [math.cos(half), 0.0, 0.0, math.sin(half)]])


@pytest.mark.parametrize("turn, facing", [(0.0, (1.0, 0.0, 0.0)), (90.0, (0.0, 1.0, 0.0)),
                                          (-90.0, (0.0, -1.0, 0.0))])
def test_the_facing_direction_is_the_root_x_axis(turn, facing):
    np.testing.assert_allclose(pictures.facing_direction(_pose(turn)), facing, atol=1e-6)


@pytest.mark.parametrize("turn, from_above, from_below", [(90.0, "solid", "dashed"),
                                                          (-90.0, "dashed", "solid")])
def test_the_arrow_is_solid_only_towards_the_camera(turn, from_above, from_below):
    plt = render.pyplot()
    fig, ax = plt.subplots()
    styles = {}
    markers = {}
    for view, elevation in (("above", 90.0), ("below", -90.0)):
        arrow, marker = pictures.draw_facing(ax, _pose(turn), 0.0, elevation)
        styles[view] = "solid" if arrow.arrow_patch.get_linestyle() == "-" else "dashed"
        markers[view] = marker.get_marker()
    plt.close(fig)
    assert styles == {"above": from_above, "below": from_below}
    dot_or_cross = {"solid": "o", "dashed": "x"}
    assert markers == {"above": dot_or_cross[from_above], "below": dot_or_cross[from_below]}


def test_seen_level_the_arrow_runs_from_the_root_along_the_facing_direction():
    plt = render.pyplot()
    fig, ax = plt.subplots()
    arrow, marker = pictures.draw_facing(ax, _pose(90.0), 0.0, 0.0, length=0.5)     # face up
    plt.close(fig)
    view = render.camera(0.0, 0.0)
    np.testing.assert_allclose(arrow.xyann, view[:2] @ ROOT)
    np.testing.assert_allclose(np.ravel(marker.get_xydata()), view[:2] @ ROOT)
    np.testing.assert_allclose(np.subtract(arrow.xy, arrow.xyann), [0.0, 0.5], atol=1e-9)
