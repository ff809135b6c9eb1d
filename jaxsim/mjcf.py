"""Export a model as MuJoCo MJCF XML, to inspect it in MuJoCo's tools or cross-check dynamics.

Joint mapping: free → <freejoint>, spherical → ball, revolute → hinge, fixed → no joint (the body
is welded to its parent). MuJoCo's ball-joint quaternion is (w, x, y, z) relative to the parent,
as in our q. Note the free joint's velocity differs: MuJoCo uses the world-frame linear velocity
of the body origin, we use the body-frame one (the position and quaternion parts agree).
"""

import xml.etree.ElementTree as ET

import numpy as np

from jaxsim import rotations
from jaxsim.dynamics.common import DEFAULT_GRAVITY
from jaxsim.model import Model


def _fmt(values):
    return " ".join(f"{float(v):.9g}" for v in np.ravel(values))


def _quat(rot):
    return _fmt(np.asarray(rotations.matrix_to_quat(np.asarray(rot, float))))


def to_mjcf(model: Model, name: str = "takeoff_model", gravity=DEFAULT_GRAVITY) -> str:
    """The model as an MJCF document (a string)."""
    topo = model.topology
    p = {k: np.asarray(getattr(model, k), float) for k in
         ("joint_pos", "joint_rot", "joint_axis", "mass", "com", "inertia", "shape_pos",
          "shape_rot", "shape_size", "q_lower", "q_upper")}
    root = ET.Element("mujoco", model=name)
    ET.SubElement(root, "compiler", angle="radian", inertiafromgeom="false")
    ET.SubElement(root, "option", gravity=_fmt(gravity))
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "geom", name="ground", type="plane", size="50 50 0.1",
                  quat=_quat(rotations.axis_angle_to_matrix(np.array([1.0, 0, 0]), -np.pi / 2)))
    elements = {}
    for i, link in enumerate(topo.names):
        parent = world if topo.parents[i] < 0 else elements[topo.parents[i]]
        attrs = {"name": link}
        if not (i == 0 and topo.floating):
            attrs.update(pos=_fmt(p["joint_pos"][i]), quat=_quat(p["joint_rot"][i]))
        body = ET.SubElement(parent, "body", attrs)
        elements[i] = body
        joint_type = topo.joint_types[i]
        dofs = slice(topo.dof_offsets[i], topo.dof_offsets[i + 1])
        if joint_type == "free":
            ET.SubElement(body, "freejoint", name=link)
        elif joint_type == "spherical":
            ET.SubElement(body, "joint", name=link, type="ball")
        elif joint_type == "revolute":
            low, high = p["q_lower"][dofs][0], p["q_upper"][dofs][0]
            attrs = dict(name=link, type="hinge", axis=_fmt(p["joint_axis"][i]))
            if np.isfinite(low) and np.isfinite(high):
                attrs.update(limited="true", range=_fmt([low, high]))
            ET.SubElement(body, "joint", attrs)
        inertia = p["inertia"][i]
        ET.SubElement(body, "inertial", pos=_fmt(p["com"][i]), mass=_fmt([p["mass"][i]]),
                      fullinertia=_fmt([inertia[0, 0], inertia[1, 1], inertia[2, 2],
                                        inertia[0, 1], inertia[0, 2], inertia[1, 2]]))
        shape = topo.shape_types[i]
        size, centre, rot = p["shape_size"][i], p["shape_pos"][i], p["shape_rot"][i]
        if shape == "sphere":
            ET.SubElement(body, "geom", type="sphere", size=_fmt(size[:1]), pos=_fmt(centre))
        elif shape == "capsule":
            tip = rot @ np.array([0.0, size[1], 0.0])
            ET.SubElement(body, "geom", type="capsule", size=_fmt(size[:1]),
                          fromto=_fmt(np.concatenate([centre - tip, centre + tip])))
        elif shape == "box":
            ET.SubElement(body, "geom", type="box", size=_fmt(size), pos=_fmt(centre),
                          quat=_quat(rot))
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")
