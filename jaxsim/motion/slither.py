"""A procedural slithering reference for the snakes (the thesis's Snake1–3 tracking task).

Lateral undulation (a serpenoid curve): joint i bends about the vertical axis by
θ_i(t) = A sin(2π f t − 2π i / n_wave), a wave running from head to tail, while the head moves
forward (−X, away from the body, which lies along +X) at a steady speed, on the ground.
"""

import numpy as np

from jaxsim import rotations
from jaxsim.model import Model, rest_pose
from jaxsim.motion.clip import Clip, make_clip


def slither_clip(model: Model, amplitude: float = 0.35, frequency: float = 1.0,
                 segments_per_wave: float = 8.0, speed: float = 0.3,
                 frame_rate: float = 60.0) -> Clip:
    """One looping cycle (1/frequency seconds) of slithering for a snake model."""
    topo = model.topology
    if not topo.floating or any(t != "spherical" for t in topo.joint_types[1:]):
        raise ValueError("slither_clip needs a snake: a free head and spherical joints")
    period = 1.0 / frequency
    n_frames = int(round(period * frame_rate)) + 1
    times = np.linspace(0.0, period, n_frames)
    height = float(model.shape_size[0, 0])
    poses = np.tile(np.asarray(rest_pose(model, height), float), (n_frames, 1))
    up = np.array([0.0, 1.0, 0.0])
    for k, t in enumerate(times):
        poses[k, 0] = -speed * t
        for i in range(1, topo.n_links):
            angle = amplitude * np.sin(2 * np.pi * (frequency * t - i / segments_per_wave))
            o = topo.q_offsets[i]
            poses[k, o:o + 4] = np.asarray(rotations.axis_angle_to_quat(up, np.float64(angle)))
    durations = np.full(n_frames, period / (n_frames - 1))
    return make_clip(model, durations, poses, loop=True, source="slither")
