"""Motion data: clips sampled at any time, DeepMimic motion files, a procedural slither, and
motion capture (ASF/AMC, BVH) as skeleton clips."""

from jaxsim.motion.asf import load_amc, load_asf
from jaxsim.motion.bvh import load_bvh, save_bvh
from jaxsim.motion.clip import (Clip, link_positions, make_clip, sample_pose, sample_velocity)
from jaxsim.motion.deepmimic import MotionFileError, load_motion
from jaxsim.motion.skeleton import (Skeleton, SkeletonClip, from_model_clip, model_skeleton,
                                    world_deltas, world_pose)
from jaxsim.motion.slither import slither_clip

__all__ = ["Clip", "link_positions", "make_clip", "sample_pose", "sample_velocity",
           "MotionFileError", "load_motion", "slither_clip",
           "Skeleton", "SkeletonClip", "world_pose", "world_deltas", "model_skeleton",
           "from_model_clip", "load_asf", "load_amc", "load_bvh", "save_bvh"]
