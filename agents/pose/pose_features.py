"""Pose features for the P-VAE and the PD targets it decodes to (thesis §3.4.2, eq. 3.4).

Encoder input, per pose: every non-root link's position relative to the root, in the root's frame,
then every actuated joint's rotation relative to its parent in the 6D representation (the first
two columns of the rotation matrix). Everything is in the root's frame, so the root's position and
its whole orientation (heading, and also its lean) are left out: a pose means the same wherever
the character stands and however its pelvis is turned.

Decoder output ("PD target"): per actuated joint in link order, the 6D rotation of a spherical
joint or the angle of a revolute one. A decoded target becomes joint targets in exponential
coordinates (a rotation vector per spherical joint, an angle per revolute joint): the space in which
the policy's offset is added (eq. 3.4) and from which `exp_to_pose` builds a full pose vector.

All functions act on one pose and are jittable and differentiable; vmap them over a batch.
"""

import dataclasses

import jax.numpy as jnp
import numpy as np

from jaxsim import kinematics, rotations
from jaxsim.model import Model


@dataclasses.dataclass(frozen=True)
class PoseLayout:
    """Which links are actuated and where each one's numbers sit in the vectors of per-joint
    blocks (joints in link order): index arrays, so conversions run on all joints at once."""

    spherical: tuple[int, ...]
    revolute: tuple[int, ...]
    n_links: int

    @classmethod
    def of(cls, model: Model) -> "PoseLayout":
        topo = model.topology
        return cls(tuple(int(i) for i in topo.links_of_type("spherical")),
                   tuple(int(i) for i in topo.links_of_type("revolute")), topo.n_links)

    @property
    def actuated(self) -> tuple[int, ...]:
        return tuple(sorted(self.spherical + self.revolute))

    @property
    def feature_size(self) -> int:
        return 3 * (self.n_links - 1) + 6 * len(self.actuated)

    @property
    def target_size(self) -> int:
        return 6 * len(self.spherical) + len(self.revolute)

    @property
    def exp_size(self) -> int:
        """Size of the joint targets in exponential coordinates (and of the action offset)."""
        return 3 * len(self.spherical) + len(self.revolute)

    def _blocks(self, spherical_size):
        """(spherical (k_s, size), revolute (k_r,)) indices of each joint's block in a vector
        whose blocks have `spherical_size` numbers per spherical joint and one per revolute."""
        start, sph, rev = 0, [], []
        for link in self.actuated:
            if link in self.spherical:
                sph.append(np.arange(start, start + spherical_size))
                start += spherical_size
            else:
                rev.append(start)
                start += 1
        return np.array(sph, int).reshape(-1, spherical_size), np.array(rev, int)

    @property
    def target_index(self):
        return self._blocks(6)

    @property
    def exp_index(self):
        return self._blocks(3)

    @property
    def order(self):
        """(spherical, revolute) positions of those joints within `actuated`."""
        return (np.array([self.actuated.index(i) for i in self.spherical], int),
                np.array([self.actuated.index(i) for i in self.revolute], int))


def _local_rotations(model: Model, q):
    """Each link's rotation relative to its parent link (n, 3, 3), without the rest placement."""
    rot, _ = kinematics.local_poses(model, q)
    return jnp.swapaxes(model.joint_rot, -1, -2) @ rot


def pose_features(model: Model, q):
    """Encoder features of pose q: root-frame link positions, then 6D joint rotations."""
    layout = PoseLayout.of(model)
    rot, pos = kinematics.forward_kinematics(model, q)
    relative = (pos[1:] - pos[0]) @ rot[0]          # rows: R_rootᵀ (p − p_root)
    local = _local_rotations(model, q)[np.array(layout.actuated)]
    return jnp.concatenate([relative.reshape(-1), rotations.matrix_to_6d(local).reshape(-1)])


def pd_target(model: Model, q):
    """Decoder target of pose q: 6D rotation per spherical joint, angle per revolute joint."""
    layout = PoseLayout.of(model)
    sph, rev = layout.target_index
    target = jnp.zeros(layout.target_size, q.dtype)
    target = target.at[sph].set(rotations.matrix_to_6d(
        _local_rotations(model, q)[np.array(layout.spherical, int)]))
    return target.at[rev].set(kinematics.joint_angles(model, q)[np.array(layout.revolute, int)])


def target_to_exp(model: Model, target):
    """Decoder target → joint targets in exponential coordinates (rotation vectors, angles).
    6D blocks are projected to the nearest rotation first, so any decoder output is valid."""
    layout = PoseLayout.of(model)
    (sph_t, rev_t), (sph_e, rev_e) = layout.target_index, layout.exp_index
    exp = jnp.zeros(layout.exp_size, target.dtype)
    exp = exp.at[sph_e].set(rotations.matrix_to_rotvec(rotations.sixd_to_matrix(target[sph_t])))
    return exp.at[rev_e].set(target[rev_t])


def exp_to_pose(model: Model, joint_targets, root=None):
    """A full pose vector (nq) from joint targets in exponential coordinates; the root part is
    `root` (7 numbers) or the origin with the identity orientation."""
    layout, topo = PoseLayout.of(model), model.topology
    sph_e, rev_e = layout.exp_index
    q = jnp.zeros(topo.nq, joint_targets.dtype)
    if topo.floating:
        q = q.at[:7].set(jnp.asarray([0, 0, 0, 1, 0, 0, 0] if root is None else root, q.dtype))
    quats, _ = topo.spherical_indices
    q = q.at[quats].set(rotations.rotvec_to_quat(joint_targets[sph_e]))
    return q.at[topo.q_offsets[np.array(layout.revolute, int)]].set(joint_targets[rev_e])


def exp_rotations(model: Model, joint_targets):
    """Rotation matrices (k, 3, 3) of the actuated joints (link order) given in exponential
    coordinates."""
    layout = PoseLayout.of(model)
    sph_e, rev_e = layout.exp_index
    sph_at, rev_at = layout.order
    mats = jnp.zeros((len(layout.actuated), 3, 3), joint_targets.dtype)
    mats = mats.at[sph_at].set(rotations.rotvec_to_matrix(joint_targets[sph_e]))
    axes = model.joint_axis[np.array(layout.revolute, int)].astype(joint_targets.dtype)
    return mats.at[rev_at].set(rotations.axis_angle_to_matrix(axes, joint_targets[rev_e]))


def joint_angle_errors(model: Model, target_a, target_b):
    """Angle (radians) between the two decoder targets' rotations, per actuated joint (k,)."""
    rot_a = exp_rotations(model, target_to_exp(model, target_a))
    rot_b = exp_rotations(model, target_to_exp(model, target_b))
    relative = jnp.swapaxes(rot_a, -1, -2) @ rot_b
    return jnp.linalg.norm(rotations.matrix_to_rotvec(relative), axis=-1)
