"""A built-in dog-like quadruped with 72 DoF (the thesis's Dog, Table 2.1).

23 links: a free pelvis, two spine links, neck, head, four legs of four spherical joints each
(shoulder/hip, elbow/knee, wrist/ankle, toe) and a two-link tail: 6 + 22 × 3 = 72 DoF. The deepest
root-to-leaf path (pelvis → spine → chest → front leg → toe) has 6 + 6 × 3 = 24 DoF. Proportions
are those of a medium-sized dog; the masses add up to 39.3 kg. It faces +X with Y up.
"""

import numpy as np

from jaxsim.builder import LinkSpec, build_model
from jaxsim.characters.common import Y_TO_X

_LIMIT = 1.2


def _bone(name, parent, pos, mass, length, radius, along_x=False, kp=300.0, kd=30.0,
          torque_limit=150.0):
    """A capsule link hanging down (−Y) from its joint, or pointing along X."""
    half = max(length / 2 - radius, 1e-3)
    direction = np.array([1.0, 0, 0]) if along_x else np.array([0, -1.0, 0])
    return LinkSpec(name=name, parent=parent, joint="spherical", joint_pos=pos, mass=mass,
                    shape="capsule", shape_pos=direction * length / 2,
                    shape_rot=Y_TO_X if along_x else None, shape_size=(radius, half, 0),
                    kp=kp, kd=kd, torque_limit=torque_limit, q_lower=-_LIMIT, q_upper=_LIMIT)


def _leg(side, front):
    z = 0.11 if side == "right" else -0.11
    prefix = f"{side}_{'front' if front else 'hind'}"
    parent = "chest" if front else "pelvis"
    top = (0.12, -0.06, z) if front else (-0.1, -0.04, z)
    names = (["shoulder", "elbow", "wrist", "toe"] if front else ["hip", "knee", "ankle", "toe"])
    lengths = (0.24, 0.22, 0.12, 0.06) if front else (0.26, 0.24, 0.14, 0.06)
    masses = (2.0, 1.2, 0.5, 0.2) if front else (2.5, 1.4, 0.6, 0.2)
    radii = (0.045, 0.035, 0.03, 0.025)
    links, pos = [], top
    for joint, length, mass, radius in zip(names, lengths, masses, radii):
        links.append(_bone(f"{prefix}_{joint}", parent, pos, mass, length, radius))
        parent, pos = links[-1].name, (0.0, -length, 0.0)
    return links


def quadruped(dtype=None):
    """The built-in 72-DoF dog."""
    links = [
        LinkSpec(name="pelvis", parent=None, joint="free", mass=5.0, shape="box",
                 shape_size=(0.1, 0.08, 0.1)),
        _bone("spine", "pelvis", (0.1, 0.0, 0.0), 5.0, 0.22, 0.09, along_x=True, kp=600, kd=60,
              torque_limit=300),
        _bone("chest", "spine", (0.22, 0.0, 0.0), 8.0, 0.2, 0.11, along_x=True, kp=600, kd=60,
              torque_limit=300),
        _bone("neck", "chest", (0.2, 0.06, 0.0), 1.5, 0.16, 0.05, along_x=True, kp=200, kd=20),
        LinkSpec(name="head", parent="neck", joint="spherical", joint_pos=(0.16, 0.04, 0.0),
                 mass=2.0, shape="box", shape_pos=(0.08, 0.0, 0.0), shape_size=(0.1, 0.06, 0.06),
                 kp=100, kd=10, torque_limit=80, q_lower=-_LIMIT, q_upper=_LIMIT),
    ]
    for front in (True, False):
        for side in ("right", "left"):
            links += _leg(side, front)
    links += [
        _bone("tail_base", "pelvis", (-0.12, 0.04, 0.0), 0.4, 0.18, 0.025, along_x=True, kp=50,
              kd=5, torque_limit=30),
        _bone("tail_tip", "tail_base", (0.18, 0.0, 0.0), 0.2, 0.18, 0.02, along_x=True, kp=50,
              kd=5, torque_limit=30),
    ]
    # The tail points backwards: turn its base 180° about Y.
    links[-2].joint_rot = np.diag([-1.0, 1.0, -1.0])
    kwargs = {} if dtype is None else {"dtype": dtype}
    return build_model(links, source="quadruped", **kwargs)
