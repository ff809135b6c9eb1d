"""Helpers shared by the character builders."""

import jax
import numpy as np

from jaxsim import kinematics
from jaxsim.model import Model, rest_pose

# Shape frames have their long axis along Y (as DeepMimic's capsules); these turn Y onto X.
Y_TO_X = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def half_sizes(shape: str, full):
    """Half-sizes of a shape (see `Model`) from DeepMimic's full sizes: a sphere's diameter, a
    capsule's diameter and cylinder length, a box's extents."""
    if shape == "sphere":
        return (full[0] / 2, 0.0, 0.0)
    if shape == "capsule":
        return (full[0] / 2, full[1] / 2, 0.0)
    return tuple(s / 2 for s in full)


def vertical_extent(model: Model, q=None):
    """Lowest and highest point (Y) of the collision shapes in pose q (the rest pose by default)."""
    q = rest_pose(model) if q is None else q
    rot_w, pos_w = jax.jit(kinematics.forward_kinematics)(model, q)
    rots, centres = (np.asarray(a, float) for a in kinematics.shape_poses(model, rot_w, pos_w))
    lows, highs = [], []
    for i, shape in enumerate(model.topology.shape_types):
        if shape == "none":
            continue
        rot, centre = rots[i], centres[i]
        size = np.asarray(model.shape_size[i], float)
        if shape == "sphere":
            reach = size[0]
        elif shape == "capsule":
            reach = abs(rot[1, 1]) * size[1] + size[0]
        else:
            reach = np.abs(rot[1]) @ size
        lows.append(centre[1] - reach)
        highs.append(centre[1] + reach)
    return min(lows), max(highs)
