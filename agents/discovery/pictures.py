"""Pictures of a jump: the peak pose seen along the bar and across it, as the thesis shows its
strategies (Fig. 3.4). Used by the real black box for every evaluation and by the gallery."""

import jax.numpy as jnp
import numpy as np

from jaxsim import kinematics, render


def azimuth_looking_along(direction) -> float:
    """The camera azimuth (degrees, `jaxsim.render.camera`) that looks along −direction."""
    return float(np.degrees(np.arctan2(direction[0], direction[2])))


def bar_directions(env, task):
    """(the bar plane's normal, the bar's length direction) of a jump environment's episode."""
    normal = np.asarray(env.geometry(task)[0], float)
    return normal, np.cross(normal, [0.0, 1.0, 0.0])


def peak_index(env, poses) -> int:
    """The control step at which the centre of mass is highest."""
    heights = [float(kinematics.center_of_mass(env.model, jnp.asarray(q))[1]) for q in poses]
    return int(np.argmax(heights))


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
