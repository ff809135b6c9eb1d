"""Pictures of a simulation: PNG frames, a filmstrip image and an animated GIF.

An orthographic camera (azimuth about the vertical axis, elevation above the horizon) projects the
bodies, drawn as their collision shapes (spheres as discs, capsules as rounded bars, boxes as the
hull of their corners) or as sticks between joints, back to front, over the ground line and the
world's static boxes. Needs matplotlib (`pip install 'takeoff[render]'`); nothing else in takeoff
imports this module.
"""

import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import kinematics
from jaxsim.atomic import atomic_path
from jaxsim.contact import BOX_CORNERS
from jaxsim.model import Model
from jaxsim.world import World

STYLES = ("shapes", "sticks")


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (an ImportError says what to install)."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ImportError("jaxsim.render needs matplotlib: pip install 'takeoff[render]'") from None
    return plt


def camera(azimuth: float = 0.0, elevation: float = 0.0) -> np.ndarray:
    """Rows: screen right, screen up, and the viewing depth (towards the camera), in world
    coordinates. Azimuth 0 looks along −Z (the humanoid's side); 90° looks along −X."""
    az, el = np.radians(azimuth), np.radians(elevation)
    right = np.array([np.cos(az), 0.0, -np.sin(az)])
    toward = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    up = np.cross(toward, right)
    return np.stack([right, up, toward])


def _poses(model: Model, qs):
    qs = jnp.asarray(qs, model.mass.dtype)
    rot, pos = jax.jit(jax.vmap(lambda q: kinematics.forward_kinematics(model, q)))(qs)
    return np.asarray(rot, float), np.asarray(pos, float)


def _shape_polygons(model: Model, rot_w, pos_w, view):
    """(depth, polygon (k, 2)) of every shape in one pose, in screen coordinates."""
    items = []
    circle = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    unit = np.stack([np.cos(circle), np.sin(circle)], -1)
    rots, centres = (np.asarray(a, float) for a in kinematics.shape_poses(model, rot_w, pos_w))
    for i, kind in enumerate(model.topology.shape_types):
        if kind == "none":
            continue
        rot, centre = rots[i], centres[i]
        size = np.asarray(model.shape_size[i], float)
        depth = view[2] @ centre
        if kind == "sphere":
            polygon = (view[:2] @ centre) + size[0] * unit
        elif kind == "capsule":
            ends = np.stack([centre - rot[:, 1] * size[1], centre + rot[:, 1] * size[1]])
            discs = (ends @ view[:2].T)[:, None, :] + size[0] * unit[None]
            polygon = _hull(discs.reshape(-1, 2))
        else:
            polygon = _hull((centre + (BOX_CORNERS * size) @ rot.T) @ view[:2].T)
        items.append((depth, polygon))
    return items


def _hull(points):
    """Convex hull (monotone chain) of 2-D points, counter-clockwise."""
    pts = sorted(map(tuple, points))

    def turn(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and turn(out[-2], out[-1], p) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]

    return np.array(half(pts) + half(pts[::-1]))


def _draw_world(ax, world: World | None, view):
    """The ground (as a horizontal line at its height above the origin; an incline is drawn
    flat) and the static boxes."""
    ground_y = 0.0
    if world is not None and world.ground:
        ground_y = float(world.ground_offset) / max(float(world.ground_normal[1]), 1e-6)
    ax.axhspan(-10, ground_y, color="#e8e4da", zorder=0)
    ax.axhline(ground_y, color="#8a8272", lw=1, zorder=1)
    if world is None:
        return
    for k in range(len(world.box_names)):
        centre = np.asarray(world.box_center[k], float)
        rot = np.asarray(world.box_rotation[k], float)
        half = np.asarray(world.box_half_size[k], float)
        polygon = _hull((centre + (BOX_CORNERS * half) @ rot.T) @ view[:2].T)
        ax.fill(polygon[:, 0], polygon[:, 1], color="#c9a66b", ec="#7a5c2e", lw=1, zorder=2)


def _draw_pose(ax, model: Model, rot_w, pos_w, view, style, color):
    if style == "shapes":
        for depth, polygon in sorted(_shape_polygons(model, rot_w, pos_w, view),
                                     key=lambda item: item[0]):
            ax.fill(polygon[:, 0], polygon[:, 1], color=color, ec="black", lw=0.6, zorder=3)
    else:
        screen = pos_w @ view[:2].T
        for i, parent in enumerate(model.topology.parents):
            if parent >= 0:
                ax.plot(*screen[[parent, i]].T, color=color, lw=2.5, zorder=3)
        ax.plot(*screen.T, "o", color="black", ms=3, zorder=4)


def _check_style(style):
    if style not in STYLES:
        raise ValueError(f"style must be one of {', '.join(STYLES)}, got {style!r}")


def _frame_panel(ax, world, view, centre, height):
    """The world and a square-ish view whose horizontal centre is `centre` (screen units)."""
    half_width = 0.5 * height
    _draw_world(ax, world, view)
    ax.set_xlim(centre - half_width, centre + half_width)
    ax.set_ylim(-0.1, height)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def _draw_panel(ax, model: Model, rot_w, pos_w, world, view, centre, height, style):
    """One pose of `model` in its panel."""
    _frame_panel(ax, world, view, centre, height)
    _draw_pose(ax, model, rot_w, pos_w, view, style, "#4c72b0")


def _prepare(model, qs, style, azimuth, elevation):
    _check_style(style)
    rot, pos = _poses(model, qs)
    view = camera(azimuth, elevation)
    height = max(2.0, float(pos[..., 1].max()) + 0.5)
    return rot, pos, view, height


def filmstrip(model: Model, qs, path, world: World | None = None, n_panels: int = 8,
              style: str = "shapes", azimuth: float = 0.0, elevation: float = 0.0,
              times=None, title: str | None = None, panel_size: float = 2.2):
    """A row of `n_panels` evenly spaced poses from `qs` (T, nq), each panel centred on the
    root, saved as a PNG. `times` (T,) labels the panels."""
    qs = np.asarray(qs)
    picks = np.linspace(0, len(qs) - 1, min(n_panels, len(qs))).round().astype(int)
    rot, pos, view, height = _prepare(model, qs[picks], style, azimuth, elevation)
    plt = pyplot()
    fig, axes = plt.subplots(1, len(picks), figsize=(panel_size * len(picks), panel_size * 1.3),
                             squeeze=False)
    for k, ax in enumerate(axes[0]):
        _draw_panel(ax, model, rot[k], pos[k], world, view, pos[k, 0] @ view[0], height, style)
        if times is not None:
            ax.set_title(f"t = {float(np.asarray(times)[picks[k]]):.2f} s", fontsize=9)
    save_figure(fig, path, title)


def views(model: Model, q, path, world: World | None = None, azimuths=(0.0, 90.0),
          labels=None, style: str = "shapes", elevation: float = 0.0,
          title: str | None = None, panel_size: float = 3.0):
    """One pose q (nq,) seen from several cameras (`azimuths`, degrees; see `camera`), a panel
    each, centred on the root and labelled by `labels`, saved as a PNG."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(azimuths), figsize=(panel_size * len(azimuths),
                                                        panel_size * 1.2), squeeze=False)
    for k, (ax, azimuth) in enumerate(zip(axes[0], azimuths)):
        rot, pos, view, height = _prepare(model, np.asarray(q)[None], style, azimuth, elevation)
        _draw_panel(ax, model, rot[0], pos[0], world, view, pos[0, 0] @ view[0], height, style)
        if labels is not None:
            ax.set_title(labels[k], fontsize=9)
    save_figure(fig, path, title)


def save_figure(fig, path, title: str | None = None, dpi: int = 100):
    """Lay out a matplotlib figure, write it as a PNG atomically, and close it."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    pyplot().close(fig)


def pose_grid(model: Model, qs, path, columns: int = 6, style: str = "shapes",
              azimuth: float = 0.0, elevation: float = 0.0, title: str | None = None,
              panel_size: float = 2.0):
    """Every pose of `qs` (k, nq) in a grid of `columns` columns, each panel centred on its
    root, saved as a PNG."""
    qs = np.asarray(qs)
    rot, pos, view, height = _prepare(model, qs, style, azimuth, elevation)
    plt = pyplot()
    rows = -(-len(qs) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(panel_size * columns,
                                                     panel_size * 1.2 * rows), squeeze=False)
    for k, ax in enumerate(axes.ravel()):
        if k < len(qs):
            _draw_panel(ax, model, rot[k], pos[k], world=None, view=view,
                        centre=pos[k, 0] @ view[0], height=height, style=style)
        else:
            ax.axis("off")
    save_figure(fig, path, title)


def comparison_filmstrip(model: Model, qs, bones, path, n_panels: int = 8,
                         azimuth: float = 0.0, elevation: float = 0.0, times=None,
                         labels=("source", "model"), title: str | None = None,
                         panel_size: float = 2.2):
    """Two rows at the same evenly spaced frames: on top a source skeleton drawn as sticks,
    `bones` (T, n_bones, 2, 3) holding each bone's start and end in our world coordinates with
    bone 0 the root; below, `model` in the poses `qs` (T, nq). Saved as a PNG."""
    qs, bones = np.asarray(qs), np.asarray(bones, float)
    if len(qs) != len(bones):
        raise ValueError(f"qs has {len(qs)} frames but bones has {len(bones)}")
    picks = np.linspace(0, len(qs) - 1, min(n_panels, len(qs))).round().astype(int)
    rot, pos, view, height = _prepare(model, qs[picks], "shapes", azimuth, elevation)
    height = max(height, float(bones[picks][..., 1].max()) + 0.5)
    plt = pyplot()
    fig, axes = plt.subplots(2, len(picks), figsize=(panel_size * len(picks),
                                                     panel_size * 2.4), squeeze=False)
    for k, pick in enumerate(picks):
        screen = bones[pick] @ view[:2].T
        _frame_panel(axes[0, k], None, view, screen[0, 0, 0], height)
        for start, end in screen:
            axes[0, k].plot([start[0], end[0]], [start[1], end[1]], color="#dd8452", lw=2,
                            zorder=3)
        _draw_panel(axes[1, k], model, rot[k], pos[k], None, view, pos[k, 0] @ view[0],
                    height, "shapes")
        if times is not None:
            axes[0, k].set_title(f"t = {float(np.asarray(times)[pick]):.2f} s", fontsize=9)
    axes[0, 0].set_ylabel(labels[0])
    axes[1, 0].set_ylabel(labels[1])
    save_figure(fig, path, title)


def animation(model: Model, qs, path, world: World | None = None, fps: float = 30.0,
              style: str = "shapes", azimuth: float = 0.0, elevation: float = 0.0,
              follow: bool = True, size: float = 4.0):
    """An animated GIF of every pose in `qs` (T, nq) at `fps` frames per second; the view
    follows the root unless `follow` is False."""
    rot, pos, view, height = _prepare(model, qs, style, azimuth, elevation)
    plt = pyplot()
    from matplotlib.animation import FuncAnimation, PillowWriter

    fig, ax = plt.subplots(figsize=(size, size))

    def draw(k):
        ax.clear()
        centre = pos[k if follow else 0, 0] @ view[0]
        _draw_panel(ax, model, rot[k], pos[k], world, view, centre, height, style)

    with atomic_path(path) as tmp:
        FuncAnimation(fig, draw, frames=len(pos)).save(tmp, writer=PillowWriter(fps=fps))
    plt.close(fig)


def frames(model: Model, qs, directory, world: World | None = None, style: str = "shapes",
           azimuth: float = 0.0, elevation: float = 0.0, size: float = 4.0):
    """One PNG per pose, `frame_00000.png`, … in `directory`; returns the paths."""
    rot, pos, view, height = _prepare(model, qs, style, azimuth, elevation)
    plt = pyplot()
    paths = []
    for k in range(len(pos)):
        fig, ax = plt.subplots(figsize=(size, size))
        _draw_panel(ax, model, rot[k], pos[k], world, view, pos[k, 0] @ view[0], height, style)
        paths.append(os.path.join(os.fspath(directory), f"frame_{k:05d}.png"))
        with atomic_path(paths[-1]) as tmp:
            fig.savefig(tmp, dpi=80, format="png")
        plt.close(fig)
    return paths
