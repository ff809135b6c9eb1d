"""Motion data: clips sampled at any time, DeepMimic motion files, a procedural slither."""

from jaxsim.motion.clip import (Clip, link_positions, make_clip, sample_pose, sample_velocity)
from jaxsim.motion.deepmimic import MotionFileError, load_motion
from jaxsim.motion.slither import slither_clip

__all__ = ["Clip", "link_positions", "make_clip", "sample_pose", "sample_velocity",
           "MotionFileError", "load_motion", "slither_clip"]
