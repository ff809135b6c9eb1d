"""Pictures of a simulation: PNG frames, a filmstrip image and an animated GIF.

An orthographic camera (azimuth about the vertical axis, elevation above the horizon) projects the
bodies, drawn as their collision shapes (spheres as discs, capsules as rounded bars, boxes as the
hull of their corners) or as sticks between joints, back to front, over the ground line (when the
world has a ground; `world=None` stands for flat ground at height 0) and the world's static boxes.
Over a ground the view keeps the ground near the bottom of each panel; without one it frames
everything drawn, wherever it is. Optional `markers`, world points such as a task's goal (see
`animation`), are drawn over the bodies. Needs matplotlib (`pip install 'takeoff[render]'`);
nothing else in takeoff imports this module.
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
MARKER_COLOR = "#c44e52"


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


# One compiled function for every call (per model structure and number of poses), rather than
# a new one, compiled again, each time a picture is drawn.
_batch_kinematics = jax.jit(jax.vmap(kinematics.forward_kinematics, in_axes=(None, 0)))


def _poses(model: Model, qs):
    qs = jnp.asarray(qs, model.mass.dtype)
    rot, pos = _batch_kinematics(model, qs)
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


def _has_ground(world: World | None):
    return world is None or world.ground


def _draw_world(ax, world: World | None, view):
    """The ground, if the world has one (as a horizontal line at its height above the origin;
    an incline is drawn flat), and the static boxes."""
    if _has_ground(world):
        ground_y = 0.0
        if world is not None:
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


def _draw_markers(ax, points, view):
    """World points (k, 3) as rings with a dot, over everything else."""
    if len(points):
        screen = np.asarray(points, float) @ view[:2].T
        ax.plot(*screen.T, "o", ms=11, mfc="none", mec=MARKER_COLOR, mew=2, zorder=5)
        ax.plot(*screen.T, "o", ms=3, color=MARKER_COLOR, zorder=5)


def _markers(markers, n):
    """`markers` as one (k, 3) set of world points per frame, (n, k, 3): given fixed (k, 3) or
    per frame (n, k, 3); None draws none."""
    if markers is None:
        return np.zeros((n, 0, 3))
    markers = np.asarray(markers, float)
    if markers.ndim == 2:
        markers = np.broadcast_to(markers, (n,) + markers.shape)
    if markers.ndim != 3 or markers.shape[0] != n or markers.shape[2] != 3:
        raise ValueError(f"markers must be world points (k, 3), or (frames, k, 3) with one "
                         f"set per frame ({n} frames), got shape {markers.shape}")
    return markers


def _ground_box(height):
    """The view over a ground, relative to the panel's horizontal centre: (x_low, x_high,
    y_low, y_high), the ground just above the bottom and `height` above it, square-ish."""
    return (-0.5 * height, 0.5 * height, -0.1, height)


def _fitted_box(model, rot, pos, view, style, centres, markers):
    """The view without a ground, relative to each panel's horizontal centre: a square, the
    same for every frame, around everything drawn in all frames (bodies and markers)."""
    offsets = []
    for k in range(len(pos)):
        if style == "shapes":
            shapes = [polygon for _, polygon in _shape_polygons(model, rot[k], pos[k], view)]
        else:
            shapes = []
        drawn = np.concatenate(shapes + [pos[k] @ view[:2].T, markers[k] @ view[:2].T])
        offsets.append(drawn - np.array([centres[k], 0.0]))
    offsets = np.concatenate(offsets)
    low, high = offsets.min(0), offsets.max(0)
    middle, half = 0.5 * (low + high), 0.5 * (high - low).max() + 0.15
    return (middle[0] - half, middle[0] + half, middle[1] - half, middle[1] + half)


def _frame_panel(ax, world, view, centre, box):
    """The world and the view `box` (see `_ground_box`) around the horizontal centre `centre`
    (screen units)."""
    _draw_world(ax, world, view)
    ax.set_xlim(centre + box[0], centre + box[1])
    ax.set_ylim(box[2], box[3])
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def _draw_panel(ax, model: Model, rot_w, pos_w, world, view, centre, box, style,
                points=()):
    """One pose of `model` in its panel, and the marker points (k, 3)."""
    _frame_panel(ax, world, view, centre, box)
    _draw_pose(ax, model, rot_w, pos_w, view, style, "#4c72b0")
    _draw_markers(ax, points, view)


def _prepare(model, qs, style, azimuth, elevation, world=None, markers=None, follow=True):
    """Poses, camera, each frame's horizontal centre (its root's, or the first frame's unless
    `follow`), the view box (see `_ground_box`) and the markers (frames, k, 3)."""
    _check_style(style)
    rot, pos = _poses(model, qs)
    view = camera(azimuth, elevation)
    markers = _markers(markers, len(pos))
    centres = pos[:, 0] @ view[0] if follow else np.full(len(pos), pos[0, 0] @ view[0])
    if _has_ground(world):
        box = _ground_box(max(2.0, float(pos[..., 1].max()) + 0.5))
    else:
        box = _fitted_box(model, rot, pos, view, style, centres, markers)
    return rot, pos, view, centres, box, markers


def filmstrip(model: Model, qs, path, world: World | None = None, n_panels: int = 8,
              style: str = "shapes", azimuth: float = 0.0, elevation: float = 0.0,
              times=None, title: str | None = None, panel_size: float = 2.2, markers=None):
    """A row of `n_panels` evenly spaced poses from `qs` (T, nq), each panel centred on the
    root, saved as a PNG. `times` (T,) labels the panels; `markers` as in `animation`."""
    qs = np.asarray(qs)
    picks = np.linspace(0, len(qs) - 1, min(n_panels, len(qs))).round().astype(int)
    rot, pos, view, centres, box, markers = _prepare(
        model, qs[picks], style, azimuth, elevation, world, _markers(markers, len(qs))[picks])
    plt = pyplot()
    fig, axes = plt.subplots(1, len(picks), figsize=(panel_size * len(picks), panel_size * 1.3),
                             squeeze=False)
    for k, ax in enumerate(axes[0]):
        _draw_panel(ax, model, rot[k], pos[k], world, view, centres[k], box, style, markers[k])
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
        rot, pos, view, centres, box, _ = _prepare(model, np.asarray(q)[None], style, azimuth,
                                                   elevation, world)
        _draw_panel(ax, model, rot[0], pos[0], world, view, centres[0], box, style)
        if labels is not None:
            ax.set_title(labels[k], fontsize=9)
    save_figure(fig, path, title)


def view_panel(ax, model: Model, q, world: World | None = None, azimuth: float = 0.0,
               elevation: float = 0.0, style: str = "shapes", label: str | None = None):
    """Draw one pose q (nq,) into the matplotlib axes `ax` as each panel of `views` is drawn,
    so that a figure can combine panels with different cameras or worlds."""
    rot, pos, view, centres, box, _ = _prepare(model, np.asarray(q)[None], style, azimuth,
                                               elevation, world)
    _draw_panel(ax, model, rot[0], pos[0], world, view, centres[0], box, style)
    if label is not None:
        ax.set_title(label, fontsize=9)


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
    rot, pos, view, centres, box, _ = _prepare(model, qs, style, azimuth, elevation)
    plt = pyplot()
    rows = -(-len(qs) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(panel_size * columns,
                                                     panel_size * 1.2 * rows), squeeze=False)
    for k, ax in enumerate(axes.ravel()):
        if k < len(qs):
            _draw_panel(ax, model, rot[k], pos[k], world=None, view=view,
                        centre=centres[k], box=box, style=style)
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
    rot, pos, view, centres, box, _ = _prepare(model, qs[picks], "shapes", azimuth, elevation)
    box = _ground_box(max(box[3], float(bones[picks][..., 1].max()) + 0.5))
    plt = pyplot()
    fig, axes = plt.subplots(2, len(picks), figsize=(panel_size * len(picks),
                                                     panel_size * 2.4), squeeze=False)
    for k, pick in enumerate(picks):
        screen = bones[pick] @ view[:2].T
        _frame_panel(axes[0, k], None, view, screen[0, 0, 0], box)
        for start, end in screen:
            axes[0, k].plot([start[0], end[0]], [start[1], end[1]], color="#dd8452", lw=2,
                            zorder=3)
        _draw_panel(axes[1, k], model, rot[k], pos[k], None, view, centres[k], box,
                    "shapes")
        if times is not None:
            axes[0, k].set_title(f"t = {float(np.asarray(times)[pick]):.2f} s", fontsize=9)
    axes[0, 0].set_ylabel(labels[0])
    axes[1, 0].set_ylabel(labels[1])
    save_figure(fig, path, title)


def animation(model: Model, qs, path, world: World | None = None, fps: float = 30.0,
              style: str = "shapes", azimuth: float = 0.0, elevation: float = 0.0,
              follow: bool = True, size: float = 4.0, markers=None, times=None):
    """An animated GIF of every pose in `qs` (T, nq), one frame each, at `fps` frames per
    second; the view follows the root unless `follow` is False. `markers` are world points
    drawn over the bodies, such as a task's goal (an environment's `markers(task)`): (k, 3) for
    the whole clip or (T, k, 3), one set per frame. Each frame is labelled with its number and
    time (`times` (T,), seconds; k / fps by default), which also keeps consecutive frames
    distinct, so that Pillow, which merges identical ones, writes all T."""
    rot, pos, view, centres, box, markers = _prepare(model, qs, style, azimuth, elevation,
                                                     world, markers, follow)
    times = np.arange(len(pos)) / fps if times is None else np.asarray(times, float)
    plt = pyplot()
    from PIL import Image

    fig, ax = plt.subplots(figsize=(size, size))
    images = []
    for k in range(len(pos)):
        ax.clear()
        _draw_panel(ax, model, rot[k], pos[k], world, view, centres[k], box, style, markers[k])
        ax.set_title(f"{k + 1}/{len(pos)}   t = {times[k]:.2f} s", fontsize=9)
        fig.canvas.draw()
        images.append(Image.fromarray(np.asarray(fig.canvas.buffer_rgba())).convert("RGB"))
    plt.close(fig)
    # GIF delays are whole centiseconds: round the frames' start times, not each delay, so
    # that the clip lasts T / fps (30 fps: 30, 30, 40, 30, ... ms). Under 20 ms browsers slow
    # a GIF down, so no delay is shorter.
    starts = np.round(np.arange(len(images) + 1) * 100.0 / fps)
    delays = [10 * max(int(d), 2) for d in np.diff(starts)]
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=delays, loop=0)


def frames(model: Model, qs, directory, world: World | None = None, style: str = "shapes",
           azimuth: float = 0.0, elevation: float = 0.0, size: float = 4.0, markers=None):
    """One PNG per pose, `frame_00000.png`, … in `directory`; returns the paths. `markers` as
    in `animation`."""
    rot, pos, view, centres, box, markers = _prepare(model, qs, style, azimuth, elevation,
                                                     world, markers)
    plt = pyplot()
    paths = []
    for k in range(len(pos)):
        fig, ax = plt.subplots(figsize=(size, size))
        _draw_panel(ax, model, rot[k], pos[k], world, view, centres[k], box, style, markers[k])
        paths.append(os.path.join(os.fspath(directory), f"frame_{k:05d}.png"))
        with atomic_path(paths[-1]) as tmp:
            fig.savefig(tmp, dpi=80, format="png")
        plt.close(fig)
    return paths
