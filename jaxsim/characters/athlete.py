"""The thesis's athlete (Table 3.2): 60 kg, 1.70 m, the DeepMimic humanoid's shapes.

Loaded from the paper's own character file (`jump/characters/humanoid3d_jumper60kg.txt` of the
reference data: every DeepMimic mass × 4/3, knee torque limits 400 N·m, elbows 50 N·m, no limit
given for hips, ankles and shoulders) rather than built with `humanoid(height=1.70, mass=60)`,
because the file is the character the thesis's policies were trained on: its shapes, mass
distribution and joint limits are the release's, where our scaled humanoid would only match the
totals. PD gains are DeepMimic's controller file's.

Torque limits (thesis §3.6.2: hips, knees and ankles "from biomechanics estimations for a human
athlete performing a Fosbury flop", the other joints as DeepMimic's humanoid). The thesis's
reference [84] cannot be resolved from our copy of the text, so these are round values of the
peak net joint moments of the take-off leg reported by inverse-dynamics studies of high-jump
and running-jump take-offs (knee extension about 400 N·m, as the release's file has; hip
about 300 N·m; ankle plantar flexion about 250 N·m), per degree of freedom:
    hips 300 N·m, knees 400 N·m, ankles 250 N·m;
and from DeepMimic's `humanoid3d.txt`: chest 200, neck 50, shoulders 100, elbows 60 N·m (the
release's file keeps 50 for the elbows, which we keep).
"""

import numpy as np

from jaxsim.characters.deepmimic import load_deepmimic

BIOMECHANICS_TORQUE_LIMITS = {"hip": 300.0, "knee": 400.0, "ankle": 250.0}   # N·m, per DoF
DEEPMIMIC_TORQUE_LIMITS = {"chest": 200.0, "neck": 50.0, "shoulder": 100.0}   # where the file has none


def athlete(character_path, controller_path, dtype=None):
    """The 60 kg athlete from its character file and DeepMimic's controller file, with the
    torque limits of the module docstring (`Model.torque_limit`, one per DoF): the biomechanics
    values on hips, knees and ankles; DeepMimic's where the file gives none."""
    model = load_deepmimic(character_path, controller_path, dtype=dtype)
    limit = np.asarray(model.torque_limit, float)
    values = {}
    for name in model.topology.names:
        joint = name.rpartition("_")[2]
        dofs = joint_dofs(model, name)
        if joint in BIOMECHANICS_TORQUE_LIMITS:
            values[name] = BIOMECHANICS_TORQUE_LIMITS[joint]
        elif joint in DEEPMIMIC_TORQUE_LIMITS and not np.all(np.isfinite(limit[dofs])):
            values[name] = DEEPMIMIC_TORQUE_LIMITS[joint]
    return scaled_torque_limits(model, values)


def joint_dofs(model, link: str) -> np.ndarray:
    """The velocity indices of the joint of `link`."""
    offsets = model.topology.dof_offsets
    i = model.topology.link_index(link)
    return np.arange(offsets[i], offsets[i + 1])


def scaled_torque_limits(model, values: dict, scale: float = 1.0):
    """`model` with the torque limits of the joints of the links named in `values` set to
    value × `scale` (N·m per DoF); a value of None keeps the joint's own limit, × `scale`."""
    limit = np.array(model.torque_limit, float)
    for link, value in values.items():
        dofs = joint_dofs(model, link)
        limit[dofs] = (limit[dofs] if value is None else value) * scale
    return model.replace(torque_limit=np.asarray(limit, model.torque_limit.dtype))
