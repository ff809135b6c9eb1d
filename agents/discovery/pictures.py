"""Pictures of a jump: the peak pose seen along the bar and across it, as the thesis shows its
strategies (Fig. 3.4). Used by the real black box for every evaluation and by the gallery.

Fig. 3.4 shows each strategy's peak pose in a look-up view and a look-down view: from below the
bar, the side of the body facing the ground, and from above, the side facing the sky, which is
what tells a flop (back to the bar, belly up) from a straddle or a dive (belly down). The
gallery's `peak_above_below` draws those two with the camera straight above and straight below,
the bar running across the picture, beside the level view along the bar that shows the height.
Our bodies are flat-shaded shapes, which look the same from the front and the back, so each
panel also draws the body's facing direction (`draw_facing`).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import kinematics, render, rotations


def azimuth_looking_along(direction) -> float:
    """The camera azimuth (degrees, `jaxsim.render.camera`) that looks along −direction."""
    return float(np.degrees(np.arctan2(direction[0], direction[2])))


def bar_directions(env, task):
    """(the bar plane's normal, the bar's length direction) of a jump environment's episode."""
    normal = np.asarray(env.geometry(task)[0], float)
    return normal, np.cross(normal, [0.0, 1.0, 0.0])


_centres_of_mass = jax.jit(jax.vmap(kinematics.center_of_mass, in_axes=(None, 0)))


def peak_index(env, poses) -> int:
    """The control step at which the centre of mass is highest."""
    poses = jnp.asarray(poses, env.model.mass.dtype)
    return int(np.argmax(np.asarray(_centres_of_mass(env.model, poses))[:, 1]))


def peak_views(env, poses, task, path, title=None):
    """The peak pose of an episode (poses (T, nq) at its control steps) seen along the bar and
    facing it, written as a PNG."""
    normal, along = bar_directions(env, task)
    peak = peak_index(env, poses)
    world = env.world_for(task)
    height = float(kinematics.center_of_mass(env.model, jnp.asarray(poses[peak]))[1])
    thing = "bar" if env.kind == "highjump" else "obstacle"
    if title is None:
        title = (f"peak pose (t = {(peak + 1) * env.control_dt:.2f} s, centre of mass "
                 f"{height:.2f} m)")
    render.views(env.model, poses[peak], path, world=world,
                 azimuths=(azimuth_looking_along(along), azimuth_looking_along(normal)),
                 labels=(f"along the {thing}", f"facing the {thing}"), title=title)


def facing_direction(q) -> np.ndarray:
    """The body's facing direction for a pose q: the root's (pelvis's) X axis in world axes,
    whose angle from up is the Stage-1 feature (`agents.tasks.jump`)."""
    return np.asarray(rotations.quat_to_matrix(jnp.asarray(q[3:7])), float)[:, 0]


def draw_facing(ax, q, azimuth: float, elevation: float, length: float = 0.5):
    """The facing direction as the camera (`jaxsim.render.camera`) sees it: an arrow from the
    root, solid where it points towards the camera (the front of the body is the side seen),
    dashed where it points away (the back is seen), and at the root a dot (towards) or a cross
    (away), which stays readable when the arrow points along the line of sight and shrinks to
    a stub. Returns (the arrow, a matplotlib annotation; the marker, a Line2D)."""
    view = render.camera(azimuth, elevation)
    root = np.asarray(q[:3], float)
    facing = facing_direction(q)
    towards = float(view[2] @ facing) >= 0.0
    arrow = ax.annotate("", xy=view[:2] @ (root + length * facing), xytext=view[:2] @ root,
                        zorder=10, annotation_clip=False,
                        arrowprops=dict(arrowstyle="-|>", color="crimson", lw=2.0,
                                        linestyle="-" if towards else (0, (2, 3))))
    (marker,) = ax.plot(*(view[:2] @ root), marker="o" if towards else "x", color="crimson",
                        markersize=5, markeredgewidth=2, zorder=11)
    return arrow, marker


def _bar_only(env, world):
    """`world` with its bar (or obstacle) alone: the landing block would cover a view from
    below."""
    k = world.object_index("bar" if env.kind == "highjump" else "obstacle") - 1    # 0: ground
    return world.replace(ground=False, box_names=world.box_names[k:k + 1],
                         box_center=world.box_center[k:k + 1],
                         box_rotation=world.box_rotation[k:k + 1],
                         box_half_size=world.box_half_size[k:k + 1])


def _also_frame(ax, points, margin=0.1):
    """Widen a square panel's view, keeping it square, to show screen points (k, 2)."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    low = np.minimum([x0, y0], points.min(0) - margin)
    high = np.maximum([x1, y1], points.max(0) + margin)
    middle, half = (low + high) / 2, (high - low).max() / 2
    ax.set_xlim(middle[0] - half, middle[0] + half)
    ax.set_ylim(middle[1] - half, middle[1] + half)


def _nearest_on_bar(world, q_root):
    """The point of the bar's (the world's first box's) top edge, on its centre line, nearest
    to the point q_root."""
    centre = np.asarray(world.box_center[0], float)
    rotation = np.asarray(world.box_rotation[0], float)
    half = np.asarray(world.box_half_size[0], float)
    along = rotation[:, 2]
    t = np.clip(along @ (np.asarray(q_root, float) - centre), -half[2], half[2])
    return centre + t * along + half[1] * rotation[:, 1]


def peak_above_below(env, poses, task, path, title=None, panel_size: float = 2.4,
                     control_dt: float | None = None):
    """The peak pose of an episode (poses (T, nq) at its control steps) in three panels: along
    the bar (level, over the ground), and from straight above and straight below with the bar
    running across (Fig. 3.4's look-down and look-up views; the bar alone, without the ground
    and block that would hide the body from below, framed on the body and the nearest part of
    the bar), each with the facing direction drawn (`draw_facing`), written as a PNG.
    `control_dt`: the episode's control step (default the environment's; the curriculum's
    schedule changes it with the bar)."""
    normal, along = bar_directions(env, task)
    heights = np.asarray(_centres_of_mass(env.model, jnp.asarray(poses, env.model.mass.dtype)))
    peak = int(np.argmax(heights[:, 1]))                  # as `peak_index`
    world = env.world_for(task)
    q, height = np.asarray(poses[peak]), float(heights[peak, 1])
    thing = "bar" if env.kind == "highjump" else "obstacle"
    facing, bar = azimuth_looking_along(normal), _bar_only(env, world)
    panels = ((f"along the {thing}", world, azimuth_looking_along(along), 0.0),
              ("from above", bar, facing, 90.0), ("from below", bar, facing, -90.0))
    plt = render.pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(panel_size * len(panels),
                                                      panel_size * 1.15), squeeze=False)
    nearest = _nearest_on_bar(bar, q[:3])
    for ax, (label, panel_world, azimuth, elevation) in zip(axes[0], panels):
        render.view_panel(ax, env.model, q, panel_world, azimuth, elevation, label=label)
        draw_facing(ax, q, azimuth, elevation)
        if elevation:
            _also_frame(ax, (render.camera(azimuth, elevation)[:2] @ nearest)[None])
    if title is None:
        facing_up = np.degrees(np.arccos(np.clip(facing_direction(q)[1], -1.0, 1.0)))
        title = (f"peak pose (t = {(peak + 1) * (control_dt or env.control_dt):.2f} s, "
                 f"centre of mass {height:.2f} m, facing {facing_up:.0f}° from up)")
    fig.suptitle(title, fontsize=10)
    fig.supxlabel("red: where the body faces (solid, ●: towards the camera; dashed, ×: away)",
                  fontsize=8, color="crimson")
    render.save_figure(fig, path)


def episode_animation(env, poses, task, path, control_dt: float, max_frames: int = 24,
                      size: float = 2.4):
    """An animated GIF of an episode seen along the bar, small enough to keep in git: at most
    `max_frames` frames (every k-th control step, still in real time) of size × size inches at
    100 dpi."""
    step = max(1, math.ceil(len(poses) / max_frames))
    picks = np.arange(0, len(poses), step)
    _, along = bar_directions(env, task)
    render.animation(env.model, np.asarray(poses)[picks], path, world=env.world_for(task),
                     fps=1.0 / (control_dt * step), azimuth=azimuth_looking_along(along),
                     size=size, times=control_dt * (picks + 1))
