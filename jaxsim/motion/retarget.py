"""Retargeting motion from a source skeleton (CMU ASF, BVH, …) to one of our models.

Each mapped link of the model takes the world rotation of one source bone away from its rest
pose, D_b = F_b C_bᵀ (see `jaxsim.motion.skeleton`). Three corrections make that rotation mean the
same thing on the model:

* facing: the source's world axes differ from ours (CMU faces +Z, our characters face +X, both are
  Y-up), so D is conjugated by the yaw rotation A that maps the source's world to ours;
* rest pose: the skeletons' rest poses differ (CMU stands in a T-pose with its legs splayed 20°,
  our humanoid's arms and legs hang straight down). For a link whose segment has a clear direction
  (a thigh, a shin, an upper arm, …), the alignment R_j is the shortest rotation that turns the
  model's rest segment (joint → first child joint) onto the source's rest segment (bone start →
  `aim` bone start) — so when the source stands in its rest pose, the model stands in it too —
  followed, for segments next to a knee or elbow, by a twist about the segment that lines the
  model's hinge axis up with the source's (CMU's elbow axis is tilted 30° from ours);
* the model's own rest orientation G⁰_j.

The model link's world rotation is then G_j = A D_b Aᵀ R_j G⁰_j. Joint rotations follow
outward from the root, each relative to its parent's *realised* rotation: a spherical joint takes
the full relative rotation; a revolute joint takes the twist angle about its axis, and the rest
(the swing that a one-axis knee or elbow cannot follow) is reported as the off-axis residue.
Unmapped links keep their rest relation to the parent. The root's position is the source root's,
turned by A and scaled by the ratio of the two skeletons' leg lengths (root-to-ankle heights
when standing straight).
"""

import dataclasses
import functools
from typing import Mapping

import jax
import numpy as np

from jaxsim import rotations
from jaxsim.model import Model
from jaxsim.motion.clip import Clip, bucket_length, make_clip
from jaxsim.motion.skeleton import SkeletonClip, axis_rotation, model_skeleton, world_deltas


@dataclasses.dataclass(frozen=True)
class JointMap:
    """Where a model link's rotation comes from: a source bone, and the source bone whose rest
    start marks the end of the segment (None: the rest poses already agree, no alignment)."""

    bone: str
    aim: str | None = None


@dataclasses.dataclass(frozen=True)
class Retargeting:
    """How one source skeleton maps onto one model (joint names on both sides)."""

    joints: Mapping[str, JointMap]
    leg: tuple[str, str, str]                       # source hip, knee, ankle bones
    model_leg: tuple[str, str, str] = ("right_hip", "right_knee", "right_ankle")
    facing_yaw_degrees: float = 0.0                 # source world → our world, about +Y

    @property
    def facing(self) -> np.ndarray:
        return axis_rotation("Y", np.radians(self.facing_yaw_degrees))


def _limbs(bones: Mapping[str, tuple[str, ...]]):
    """Joint maps for the humanoid's limbs from {side: (hip, knee, ankle, shoulder, elbow,
    wrist)} source bone names."""
    table = {}
    for side, (hip, knee, ankle, shoulder, elbow, wrist) in bones.items():
        table[f"{side}_hip"] = JointMap(hip, knee)
        table[f"{side}_knee"] = JointMap(knee, ankle)
        table[f"{side}_ankle"] = JointMap(ankle)
        table[f"{side}_shoulder"] = JointMap(shoulder, elbow)
        table[f"{side}_elbow"] = JointMap(elbow, wrist)
    return table


# CMU Acclaim skeletons (subjects 01–03) onto the DeepMimic humanoid. CMU's subject faces +Z.
CMU_ASF = Retargeting(
    joints={"root": JointMap("root"), "chest": JointMap("thorax", "lowerneck"),
            "neck": JointMap("head"),
            **_limbs({"right": ("rfemur", "rtibia", "rfoot", "rhumerus", "rradius", "rwrist"),
                      "left": ("lfemur", "ltibia", "lfoot", "lhumerus", "lradius", "lwrist")})},
    leg=("rfemur", "rtibia", "rfoot"), facing_yaw_degrees=90.0)

# The cgspeed-style BVH conversion of CMU subject 131 onto the DeepMimic humanoid.
CMU_BVH = Retargeting(
    joints={"root": JointMap("Hips"), "chest": JointMap("Chest2", "Neck"),
            "neck": JointMap("Head"),
            **_limbs({"right": ("RightHip", "RightKnee", "RightAnkle", "RightShoulder",
                                "RightElbow", "RightWrist"),
                      "left": ("LeftHip", "LeftKnee", "LeftAnkle", "LeftShoulder",
                               "LeftElbow", "LeftWrist")})},
    leg=("RightHip", "RightKnee", "RightAnkle"), facing_yaw_degrees=90.0)


def identity_retargeting(model: Model) -> Retargeting:
    """A model onto itself (a skeleton from `model_skeleton`/`from_model_clip` or its BVH)."""
    topo = model.topology
    joints = {}
    for i, name in enumerate(topo.names):
        if topo.joint_types[i] == "fixed":
            continue
        children = [topo.names[j] for j in range(topo.n_links) if topo.parents[j] == i]
        joints[name] = JointMap(name, children[0] if children else None)
    hip, knee, ankle = _model_leg_chain(model)
    return Retargeting(joints, leg=(hip, knee, ankle), model_leg=(hip, knee, ankle))


def _model_leg_chain(model: Model):
    """The first three-link chain below the root (hip, knee, ankle for a humanoid)."""
    topo = model.topology
    for hip in range(1, topo.n_links):
        if topo.parents[hip] != 0:
            continue
        knees = [j for j in range(topo.n_links) if topo.parents[j] == hip]
        ankles = [j for j in range(topo.n_links) if knees and topo.parents[j] == knees[0]]
        if ankles:
            return topo.names[hip], topo.names[knees[0]], topo.names[ankles[0]]
    raise ValueError("the model has no three-link chain below its root to measure a leg")


@dataclasses.dataclass(frozen=True)
class RetargetResult:
    """The retargeted clip, and per revolute joint the off-axis residue in degrees per frame."""

    clip: Clip
    residue_degrees: dict[str, np.ndarray]
    scale: float


@functools.lru_cache(maxsize=None)
def _compiled(conversion):
    return jax.jit(conversion)


def _per_frame(conversion, *arrays):
    """A `jaxsim.rotations` conversion applied to per-frame arrays (T, …), back as NumPy (float64
    arrays, with float32 precision unless JAX runs with x64).

    The frames are padded (by repeating the last) to a power-of-two count, so clips of any
    length share a few compilations instead of compiling every operation for every length."""
    count = arrays[0].shape[0]
    padded = bucket_length(count, minimum=64)
    arrays = [np.pad(np.asarray(a), [(0, padded - count)] + [(0, 0)] * (a.ndim - 1), "edge")
              for a in arrays]
    return np.asarray(_compiled(conversion)(*arrays), float)[:count]


def _shortest_rotation(u, v):
    """The smallest rotation matrix that turns unit vector u onto unit vector v."""
    axis = np.cross(u, v)
    sin, cos = np.linalg.norm(axis), float(np.dot(u, v))
    if sin < 1e-9:
        if cos > 0:
            return np.eye(3)
        raise ValueError("rest segments point in opposite directions; cannot align them")
    return np.asarray(rotations.axis_angle_to_matrix(axis / sin, np.arctan2(sin, cos)))


def _leg_length(skeleton, hip, knee, ankle):
    """How high a standing skeleton's root is above its ankle: the rest pose's vertical drop
    from the root to the hip joint (CMU's hips hang 10 cm below its root, ours sit level with
    it) plus the thigh and shin lengths (which a rest pose may splay, as CMU's does)."""
    positions = skeleton.rest_positions
    root = skeleton.parents.index(-1)
    return (abs(positions[hip, 1] - positions[root, 1])
            + np.linalg.norm(positions[knee] - positions[hip])
            + np.linalg.norm(positions[ankle] - positions[knee]))


def _unit(v, what):
    norm = np.linalg.norm(v)
    if norm < 1e-9:
        raise ValueError(f"{what} has zero length in the rest pose; choose another aim bone")
    return v / norm


def _hinge_axis(deltas, parent: int, child: int):
    """The source's hinge axis between two bones, in world rest coordinates: the principal
    direction of the child's rotation vectors relative to the parent over the clip (sign
    arbitrary), or None when the joint hardly moves (RMS angle under 5°)."""
    relative = np.swapaxes(deltas[:, parent], -1, -2) @ deltas[:, child]
    vectors = _per_frame(rotations.matrix_to_rotvec, relative)
    if np.sqrt(np.mean(np.sum(vectors**2, -1))) < np.radians(5.0):
        return None
    return np.linalg.svd(vectors, full_matrices=False)[2][0]


def _twist_onto(direction, have, want):
    """Rotation about unit `direction` that best turns `have` onto ±`want` (the sign giving the
    smaller turn), both projected onto the plane normal to `direction`."""
    have = have - np.dot(have, direction) * direction
    want = want - np.dot(want, direction) * direction
    angle = np.arctan2(np.dot(np.cross(have, want), direction), np.dot(have, want))
    angle = (angle + np.pi / 2) % np.pi - np.pi / 2
    return np.asarray(rotations.axis_angle_to_matrix(direction, angle))


def _rest_alignments(source: SkeletonClip, deltas, model: Model, rule: Retargeting):
    """R_j for every mapped link (identity where the map has no aim bone).

    A segment that carries a hinge (a revolute joint at its end or its start: thigh and shin for
    the knee, upper arm and forearm for the elbow) is also twisted about its direction so that
    the source's hinge axis, found from the clip's motion, lines up with the model's."""
    skel, target = source.skeleton, model_skeleton(model)
    topo = model.topology
    align = {}
    for name, joint in rule.joints.items():
        if joint.aim is None:
            align[name] = np.eye(3)
            continue
        link = topo.link_index(name)
        children = [j for j in range(topo.n_links) if topo.parents[j] == link]
        if not children:
            raise ValueError(f"link {name!r} has no child to aim with; map it without an aim")
        model_dir = _unit(target.rest_positions[children[0]] - target.rest_positions[link],
                          f"model segment {name!r}")
        source_dir = rule.facing @ _unit(skel.rest_positions[skel.index(joint.aim)]
                                         - skel.rest_positions[skel.index(joint.bone)],
                                         f"source segment {joint.bone!r} → {joint.aim!r}")
        rotation = _shortest_rotation(model_dir, source_dir)
        hinge = next((j for j in (link, children[0]) if topo.joint_types[j] == "revolute"
                      and topo.parents[j] >= 0 and topo.names[topo.parents[j]] in rule.joints
                      and topo.names[j] in rule.joints), None)
        if hinge is not None:
            upper = rule.joints[topo.names[topo.parents[hinge]]].bone
            axis = _hinge_axis(deltas, skel.index(upper),
                               skel.index(rule.joints[topo.names[hinge]].bone))
            if axis is not None:
                model_axis = target.rest_frames[hinge] @ np.asarray(model.joint_axis[hinge], float)
                rotation = _twist_onto(source_dir, rotation @ model_axis,
                                       rule.facing @ axis) @ rotation
        align[name] = rotation
    return align, target


def retarget(source: SkeletonClip, model: Model, rule: Retargeting) -> RetargetResult:
    """Convert a source clip to a (non-looping) clip of `model`; see the module docstring."""
    topo = model.topology
    unknown = sorted(set(rule.joints) - set(topo.names))
    if unknown:
        raise ValueError(f"retargeting names links the model lacks: {', '.join(unknown)}")
    skel = source.skeleton
    deltas = world_deltas(source)
    facing = rule.facing
    align, target = _rest_alignments(source, deltas, model, rule)
    joint_rot = np.asarray(model.joint_rot, float)
    n_frames = source.n_frames

    world = np.empty((n_frames, topo.n_links, 3, 3))
    poses = np.zeros((n_frames, topo.nq))
    residues = {}
    for i, name in enumerate(topo.names):
        kind = topo.joint_types[i]
        parent_world = world[:, topo.parents[i]] if i > 0 else np.eye(3)
        rest_relation = joint_rot[i] if i > 0 else np.eye(3)
        if name in rule.joints and kind != "fixed":
            d = deltas[:, skel.index(rule.joints[name].bone)]
            wanted = facing @ d @ facing.T @ align[name] @ target.rest_frames[i]
            local = rest_relation.T @ np.swapaxes(parent_world, -1, -2) @ wanted
        else:
            local = np.broadcast_to(np.eye(3), (n_frames, 3, 3))
        offset = topo.q_offsets[i]
        if kind in ("free", "spherical"):
            start = offset + (3 if kind == "free" else 0)
            poses[:, start:start + 4] = _per_frame(rotations.matrix_to_quat, local)
        elif kind == "revolute":
            axis = np.asarray(model.joint_axis[i], float)
            angle, residue = _twist_angle(local, axis)
            poses[:, offset] = angle
            residues[name] = np.degrees(residue)
            local = _per_frame(rotations.axis_angle_to_matrix, _frames_of(axis, angle), angle)
        world[:, i] = parent_world @ rest_relation @ local

    source_leg = _leg_length(skel, *(skel.index(b) for b in rule.leg))
    model_leg = _leg_length(target, *(topo.link_index(n) for n in rule.model_leg))
    scale = model_leg / source_leg
    if topo.floating:
        poses[:, 0:3] = scale * source.root_positions @ facing.T
    durations = np.full(n_frames, source.frame_time)
    clip = make_clip(model, durations, poses, loop=False, source=source.source)
    return RetargetResult(clip, residues, float(scale))


def _twist_angle(local, axis):
    """Angle of the twist of rotations `local` (T, 3, 3) about `axis`, and the angle of the
    remaining swing (radians): local = swing · R_axis(angle)."""
    quat = _per_frame(rotations.matrix_to_quat, local)
    angle = 2.0 * np.arctan2(quat[:, 1:] @ axis, quat[:, 0])  # w ≥ 0, so |angle| ≤ π
    twist = _per_frame(rotations.axis_angle_to_matrix, _frames_of(axis, angle), angle)
    swing = local @ np.swapaxes(twist, -1, -2)
    return angle, np.linalg.norm(_per_frame(rotations.matrix_to_rotvec, swing), axis=-1)


def _frames_of(vector, per_frame):
    """`vector` repeated for every frame of `per_frame`."""
    return np.broadcast_to(vector, (len(per_frame),) + np.shape(vector))
