"""Motion in a source skeleton: what the motion-capture readers (ASF/AMC, BVH) produce.

A `Skeleton` is a tree of bones, parents before children, described by its rest pose in the
world: each bone's frame `rest_frames[b]` (3×3, the bone's axes in world coordinates) and its start
`rest_positions[b]` (the joint it rotates about) and end `rest_tips[b]`, in metres. A
`SkeletonClip` adds, per frame, the root's position and each bone's rotation M_b, expressed in the
bone's own rest frame. Its world pose follows from the rest pose:

    F_b = F_parent · (C_parentᵀ C_b) · M_b          (bone frame in the world, C = rest frame)
    p_b = p_parent + F_parent C_parentᵀ (r_b − r_parent)   (bone start, r = rest position)

This covers both formats: an ASF bone's rest frame is its `axis`, a BVH joint's is the identity.
The world rotation of a bone relative to its rest pose is D_b = F_b C_bᵀ, which is what
retargeting compares between skeletons.

These are NumPy data structures for importing data, not simulation state: they are built once
per file, outside any jitted code.
"""

import dataclasses

import jax
import numpy as np

from jaxsim import kinematics
from jaxsim.model import Model, rest_pose
from jaxsim.motion.clip import Clip, sample_pose


@dataclasses.dataclass(frozen=True)
class Skeleton:
    """A source skeleton's bones in their rest pose (see the module docstring)."""

    names: tuple[str, ...]
    parents: tuple[int, ...]          # -1 for the root; every parent comes before its children
    rest_frames: np.ndarray           # (n, 3, 3)
    rest_positions: np.ndarray        # (n, 3) metres
    rest_tips: np.ndarray             # (n, 3) metres

    @property
    def n_bones(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"skeleton has no bone {name!r}; bones: {', '.join(self.names)}")


@dataclasses.dataclass(frozen=True)
class SkeletonClip:
    """Motion of a `Skeleton`: root positions (T, 3) in metres and bone rotations (T, n, 3, 3)
    in each bone's rest frame, sampled every `frame_time` seconds."""

    skeleton: Skeleton
    frame_time: float
    root_positions: np.ndarray
    rotations: np.ndarray
    source: str = "clip"

    @property
    def n_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def frame_rate(self) -> float:
        return 1.0 / self.frame_time


def axis_rotation(axis: str, angle):
    """Rotation matrices (…, 3, 3) by `angle` radians about the world axis 'X', 'Y' or 'Z'."""
    angle = np.asarray(angle, float)
    c, s = np.cos(angle), np.sin(angle)
    one, zero = np.ones_like(angle), np.zeros_like(angle)
    rows = {
        "X": [[one, zero, zero], [zero, c, -s], [zero, s, c]],
        "Y": [[c, zero, s], [zero, one, zero], [-s, zero, c]],
        "Z": [[c, -s, zero], [s, c, zero], [zero, zero, one]],
    }[axis.upper()]
    return np.stack([np.stack(r, -1) for r in rows], -2)


def euler_to_matrix(axes: str, angles):
    """R = R_{axes[0]}(angles[…, 0]) · R_{axes[1]}(angles[…, 1]) · …: the first axis listed is
    the outermost rotation (BVH's channel convention; ASF/AMC lists its order innermost first,
    so its readers pass the reversed order). Angles in radians, shape (…, len(axes))."""
    angles = np.asarray(angles, float)
    result = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3))
    for k, axis in enumerate(axes):
        result = result @ axis_rotation(axis, angles[..., k])
    return result


def world_pose(clip: SkeletonClip):
    """Bone frames (T, n, 3, 3), starts (T, n, 3) and tips (T, n, 3) in the world."""
    skel = clip.skeleton
    c = skel.rest_frames
    frames = np.empty_like(clip.rotations)
    starts = np.empty(clip.rotations.shape[:2] + (3,))
    for b, p in enumerate(skel.parents):
        if p < 0:
            frames[:, b] = c[b] @ clip.rotations[:, b]
            starts[:, b] = clip.root_positions
        else:
            parent_delta = frames[:, p] @ c[p].T
            frames[:, b] = parent_delta @ c[b] @ clip.rotations[:, b]
            starts[:, b] = starts[:, p] + parent_delta @ (skel.rest_positions[b]
                                                          - skel.rest_positions[p])
    deltas = frames @ np.swapaxes(c, -1, -2)
    tips = starts + np.einsum("tbij,bj->tbi", deltas, skel.rest_tips - skel.rest_positions)
    return frames, starts, tips


def world_deltas(clip: SkeletonClip):
    """D_b = F_b C_bᵀ (T, n, 3, 3): each bone's world rotation away from its rest pose."""
    frames, _, _ = world_pose(clip)
    return frames @ np.swapaxes(clip.skeleton.rest_frames, -1, -2)


def model_skeleton(model: Model) -> Skeleton:
    """A model's links as a skeleton in its rest pose (root at the origin). A bone's tip is the
    mean of its children's joints; for a leaf link it is the shape centre's offset from the joint,
    doubled (the far end of a shape that starts at the joint; for drawing only)."""
    topo = model.topology
    rot, pos = (np.asarray(a, float)
                for a in kinematics.forward_kinematics(model, rest_pose(model)))
    tips = pos.copy()
    for i in range(topo.n_links):
        children = [j for j in range(topo.n_links) if topo.parents[j] == i]
        if children:
            tips[i] = pos[children].mean(axis=0)
        else:
            shape_end = np.asarray(model.shape_pos[i], float) * 2.0
            tips[i] = pos[i] + rot[i] @ shape_end
    return Skeleton(tuple(topo.names), tuple(int(p) for p in topo.parents), rot, pos, tips)


def from_model_clip(model: Model, clip: Clip, frame_rate: float) -> SkeletonClip:
    """Sample a model's clip at `frame_rate` as a skeleton clip of `model_skeleton(model)`.

    A link's rotation in its rest frame is its joint rotation R_joint(q) (the link frame is
    joint_rot · R_joint, and joint_rot is the rest relation between parent and child)."""
    skeleton = model_skeleton(model)
    n_frames = int(np.floor(float(clip.duration) * frame_rate + 1e-9)) + 1
    times = np.arange(n_frames) / frame_rate
    # (compiled: the first call of a process took 20 s op by op, 4 s so)
    poses = jax.jit(jax.vmap(sample_pose, (None, 0)))(clip, np.asarray(times, clip.poses.dtype))
    local_rot, local_pos = jax.jit(jax.vmap(kinematics.local_poses, (None, 0)))(model, poses)
    joint_rot = np.asarray(model.joint_rot, float)
    rotations = np.swapaxes(joint_rot, -1, -2)[None] @ np.asarray(local_rot, float)
    root_positions = np.asarray(local_pos[:, 0], float)
    return SkeletonClip(skeleton, 1.0 / frame_rate, root_positions, rotations,
                        source=f"{model.topology.names[0]} clip")
