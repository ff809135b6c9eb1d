"""The built-in humanoid: DeepMimic's 15-link, 34-DoF character, scalable to any body size.

Proportions, masses (45 kg in all), shapes, joint limits, torque limits and PD gains follow
DeepMimic's `humanoid3d` character and controller. Y is up, the character faces +X, and its left
side is −Z.
"""

from typing import Mapping

import numpy as np

from jaxsim.builder import LinkSpec, build_model
from jaxsim.characters.common import half_sizes, vertical_extent

# name, parent, joint, joint position, shape, shape position, shape full sizes, mass,
# kp, kd, torque limit, (lower limits), (upper limits)
_TABLE = [
    ("root", None, "free", (0, 0, 0), "sphere", (0, 0.07, 0), (0.18,), 6.0,
     0, 0, np.inf, (), ()),
    ("chest", "root", "spherical", (0, 0.236151, 0), "sphere", (0, 0.12, 0), (0.22,), 14.0,
     1000, 100, 200, (-1.2, -1.2, -1.2), (1.2, 1.2, 1.2)),
    ("neck", "chest", "spherical", (0, 0.223894, 0), "sphere", (0, 0.175, 0), (0.205,), 2.0,
     100, 10, 50, (-1, -1, -1), (1, 1, 1)),
    ("right_hip", "root", "spherical", (0, 0, 0.084887), "capsule", (0, -0.21, 0), (0.11, 0.3),
     4.5, 500, 50, 200, (-1.2, -1, -1.57), (1.2, 1, 2.57)),
    ("right_knee", "right_hip", "revolute", (0, -0.421546, 0), "capsule", (0, -0.2, 0),
     (0.1, 0.31), 3.0, 500, 50, 150, (-3.14,), (0,)),
    ("right_ankle", "right_knee", "spherical", (0, -0.40987, 0), "box", (0.045, -0.0225, 0),
     (0.177, 0.055, 0.09), 1.0, 400, 40, 90, (-1, -1, -1.57), (1, 1, 1.57)),
    ("right_shoulder", "chest", "spherical", (-0.02405, 0.2435, 0.18311), "capsule",
     (0, -0.14, 0), (0.09, 0.18), 1.5, 400, 40, 100, (-3.14, -1.5, -0.7), (0.5, 1.5, 3.14)),
    ("right_elbow", "right_shoulder", "revolute", (0, -0.274788, 0), "capsule", (0, -0.12, 0),
     (0.08, 0.135), 1.0, 300, 30, 60, (0,), (3.14,)),
    ("right_wrist", "right_elbow", "fixed", (0, -0.258947, 0), "sphere", (0, 0, 0), (0.08,), 0.5,
     0, 0, np.inf, (), ()),
    ("left_hip", "root", "spherical", (0, 0, -0.084887), "capsule", (0, -0.21, 0), (0.11, 0.3),
     4.5, 500, 50, 200, (-1.2, -1, -1.57), (1.2, 1, 2.57)),
    ("left_knee", "left_hip", "revolute", (0, -0.421546, 0), "capsule", (0, -0.2, 0),
     (0.1, 0.31), 3.0, 500, 50, 150, (-3.14,), (0,)),
    ("left_ankle", "left_knee", "spherical", (0, -0.40987, 0), "box", (0.045, -0.0225, 0),
     (0.177, 0.055, 0.09), 1.0, 400, 40, 90, (-1, -1, -1.57), (1, 1, 1.57)),
    ("left_shoulder", "chest", "spherical", (-0.02405, 0.2435, -0.18311), "capsule",
     (0, -0.14, 0), (0.09, 0.18), 1.5, 400, 40, 100, (-0.5, -1.5, -0.7), (3.14, 1.5, 3.14)),
    ("left_elbow", "left_shoulder", "revolute", (0, -0.274788, 0), "capsule", (0, -0.12, 0),
     (0.08, 0.135), 1.0, 300, 30, 60, (0,), (3.14,)),
    ("left_wrist", "left_elbow", "fixed", (0, -0.258947, 0), "sphere", (0, 0, 0), (0.08,), 0.5,
     0, 0, np.inf, (), ()),
]

# Body segments that `segment_scales` can lengthen, and the links that make them up.
SEGMENTS = {
    "pelvis": ("root",), "torso": ("chest",), "head": ("neck",),
    "thigh": ("right_hip", "left_hip"), "shin": ("right_knee", "left_knee"),
    "foot": ("right_ankle", "left_ankle"),
    "upper_arm": ("right_shoulder", "left_shoulder"), "forearm": ("right_elbow", "left_elbow"),
    "hand": ("right_wrist", "left_wrist"),
}
REFERENCE_MASS = 45.0
END_EFFECTORS = ("right_ankle", "left_ankle", "right_wrist", "left_wrist", "neck")


def _links(length_scale: Mapping[str, float], mass_scale: float):
    links = []
    for (name, parent, joint, joint_pos, shape, shape_pos, size, mass, kp, kd, tau_max, low,
         high) in _TABLE:
        parent_scale = length_scale.get(parent, 1.0) if parent else 1.0
        own = length_scale.get(name, 1.0)
        half = np.array(half_sizes(shape, size), float)
        if shape == "capsule":
            half[1] *= own          # a longer limb, not a thicker one
        else:
            half *= own             # spheres and boxes (head, feet, hands) grow as a whole
        links.append(LinkSpec(
            name=name, parent=parent, joint=joint, joint_pos=np.array(joint_pos) * parent_scale,
            shape=shape, shape_pos=np.array(shape_pos) * own, shape_size=half,
            mass=mass * mass_scale, kp=kp, kd=kd, torque_limit=tau_max,
            q_lower=low if low else -np.inf, q_upper=high if high else np.inf))
    return links


def _scaled(links, factor):
    for link in links:
        link.joint_pos = np.asarray(link.joint_pos) * factor
        link.shape_pos = np.asarray(link.shape_pos) * factor
        link.shape_size = np.asarray(link.shape_size) * factor
    return links


def humanoid(height: float | None = None, mass: float = REFERENCE_MASS,
             segment_scales: Mapping[str, float] | None = None, dtype=None):
    """DeepMimic's humanoid (1.62 m, 45 kg), optionally resized.

    `segment_scales` lengthens segments (keys of `SEGMENTS`, e.g. {"thigh": 1.1}: capsules get
    longer, spheres and boxes grow as a whole, child joints move out); then the whole
    body is scaled uniformly to `height` metres (shoe sole to top of head, standing), and masses
    are scaled to a total of `mass` kg. Inertias follow from the shapes. So the thesis's athlete
    is `humanoid(height=1.70, mass=60)`.
    """
    segment_scales = dict(segment_scales or {})
    unknown = set(segment_scales) - set(SEGMENTS)
    if unknown:
        raise ValueError(f"humanoid: unknown segment(s) {sorted(unknown)}; "
                         f"known: {', '.join(SEGMENTS)}")
    for key, value in segment_scales.items():
        if not value > 0:
            raise ValueError(f"humanoid: segment_scales[{key!r}] must be positive, got {value}")
    if not mass > 0 or (height is not None and not height > 0):
        raise ValueError(f"humanoid: height and mass must be positive, got {height}, {mass}")
    length_scale = {link: s for seg, s in segment_scales.items() for link in SEGMENTS[seg]}
    links = _links(length_scale, mass / REFERENCE_MASS)
    kwargs = {} if dtype is None else {"dtype": dtype}
    if height is not None:
        low, high = vertical_extent(build_model(links, "humanoid"))
        links = _scaled(links, height / (high - low))
    return build_model(links, source="humanoid", **kwargs)
