"""Kinematics of one character: joint transforms, link poses and velocities, centre of mass.

All functions take one character's `q` (nq) / `qd` (nv); batch them with `jax.vmap`.
Link frames: a link's frame is its joint frame after the joint's rotation, so a link's pose in its
parent is (joint_rot · R_joint(q), joint_pos). Body-frame quantities are in link coordinates.
"""

import jax.numpy as jnp
import numpy as np

from jaxsim import rotations, spatial
from jaxsim.model import JOINT_SLOTS, Model
from jaxsim.spatial import mat_mat, mat_vec
from jaxsim.tree import gather_slots, pad_links, scan_outward


def _joint_quaternions(model: Model, q):
    """(n, 4) unit quaternions of the spherical joints' q entries (identity elsewhere)."""
    topo = model.topology
    quats = rotations.quat_identity((topo.n_links,), q.dtype)
    sph = topo.links_of_type("spherical")
    if len(sph):
        idx = topo.q_offsets[sph][:, None] + np.arange(4)
        quats = quats.at[sph].set(rotations.quat_normalize(q[idx]))
    return quats


def joint_angles(model: Model, q):
    """(n,) revolute joint angles (zero elsewhere)."""
    topo = model.topology
    angles = jnp.zeros((topo.n_links,), q.dtype)
    rev = topo.links_of_type("revolute")
    if len(rev):
        angles = angles.at[rev].set(q[topo.q_offsets[rev]])
    return angles


def local_poses(model: Model, q):
    """Each link's rotation and position in its parent's frame (the root's: in the world).

    Returns (R, p) with shapes (n, 3, 3), (n, 3). The Plücker transform parent → link is
    X = plucker(Rᵀ, p).
    """
    topo = model.topology
    joint_rot = rotations.quat_to_matrix(_joint_quaternions(model, q))
    rev = topo.links_of_type("revolute")
    if len(rev):
        joint_rot = joint_rot.at[rev].set(rotations.axis_angle_to_matrix(
            model.joint_axis[rev], q[topo.q_offsets[rev]]))
    rot = mat_mat(model.joint_rot, joint_rot)
    pos = model.joint_pos
    if topo.floating:
        rot = rot.at[0].set(rotations.quat_to_matrix(rotations.quat_normalize(q[3:7])))
        pos = pos.at[0].set(q[0:3])
    return rot, pos


def motion_subspaces(model: Model):
    """(n, 6, 3) motion subspace S of each non-root joint's 3 velocity slots (zero if unused).

    Spherical: S = [I₃; 0]; revolute about axis a: S = [a 0 0; 0]; fixed and root rows: 0.
    """
    topo = model.topology
    s = jnp.zeros((topo.n_links, 6, JOINT_SLOTS), model.mass.dtype)
    sph = topo.links_of_type("spherical")
    if len(sph):
        s = s.at[sph, :3, :3].set(jnp.eye(3, dtype=s.dtype))
    rev = topo.links_of_type("revolute")
    if len(rev):
        s = s.at[rev, :3, 0].set(model.joint_axis[rev])
    return s


def forward_kinematics(model: Model, q):
    """World rotation (n, 3, 3) and origin position (n, 3) of every link frame."""
    rot, pos = local_poses(model, q)

    def step(parent, local):
        (r_p, p_p), (r_l, p_l) = parent, local
        return mat_mat(r_p, r_l), p_p + mat_vec(r_p, p_l)

    r_w, p_w = scan_outward(model.topology, step, (rot[0], pos[0]), pad_links((rot, pos)))
    return r_w[:-1], p_w[:-1]


def link_states(model: Model, q, qd):
    """World rotations (n, 3, 3), origins (n, 3) and body-frame spatial velocities [ω; v] (n, 6)
    of every link, in one outward pass: v_i = X_i v_λ(i) + S_i q̇_i."""
    rot, pos = local_poses(model, q)
    s = motion_subspaces(model)
    slots = gather_slots(model.topology, qd)
    root_v = qd[:6] if model.topology.floating else jnp.zeros(6, qd.dtype)

    def step(parent, data):
        (r_p, p_p, v_p), (r, p, s_i, qd_i) = parent, data
        v = spatial.transform_motion(r.T, p, v_p) + mat_vec(s_i, qd_i)
        return mat_mat(r_p, r), p_p + mat_vec(r_p, p), v

    r_w, p_w, v = scan_outward(model.topology, step, (rot[0], pos[0], root_v),
                               (*pad_links((rot, pos, s)), slots))
    return r_w[:-1], p_w[:-1], v[:-1]


def link_velocities(model: Model, q, qd):
    """Body-frame spatial velocity [ω; v] of every link (n, 6)."""
    return link_states(model, q, qd)[2]


def shape_poses(model: Model, rot_w, pos_w):
    """World rotation (n, 3, 3) and centre (n, 3) of every link's collision shape, from the
    links' world poses."""
    rot = mat_mat(rot_w, model.shape_rot)
    centre = pos_w + mat_vec(rot_w, model.shape_pos)
    return rot, centre


def point_positions(model: Model, q, links, offsets):
    """World positions of points given by link indices (k,) and offsets in those links (k, 3)."""
    r_w, p_w = forward_kinematics(model, q)
    links = np.asarray(links)
    return p_w[links] + (r_w[links] @ offsets[..., None])[..., 0]


def center_of_mass(model: Model, q):
    r_w, p_w = forward_kinematics(model, q)
    com_w = p_w + (r_w @ model.com[..., None])[..., 0]
    return jnp.sum(model.mass[:, None] * com_w, 0) / jnp.sum(model.mass)


def center_of_mass_velocity(model: Model, q, qd):
    """World velocity of the centre of mass from the links' body-frame velocities."""
    r_w, _, v = link_states(model, q, qd)
    v_com_body = v[:, 3:] + jnp.cross(v[:, :3], model.com)
    v_com_w = (r_w @ v_com_body[..., None])[..., 0]
    return jnp.sum(model.mass[:, None] * v_com_w, 0) / jnp.sum(model.mass)


def spatial_momentum(model: Model, q, qd):
    """Total spatial momentum [angular; linear] about the world origin, in world coordinates."""
    r_w, p_w, v = link_states(model, q, qd)
    inertia = spatial.inertia_matrix(model.mass, model.com, model.inertia)
    h_body = (inertia @ v[..., None])[..., 0]
    h_world = spatial.transform_force_to_parent(jnp.swapaxes(r_w, -1, -2), p_w, h_body)
    return jnp.sum(h_world, 0)


def qd_to_qdot(model: Model, q, qd):
    """Time derivative of q (nq) for velocity qd (nv).

    Root: ṗ = R v, q̇_root = ½ q ⊗ (0, ω); spherical: q̇ = ½ q ⊗ (0, ω) (ω in the child frame);
    revolute: θ̇.
    """
    topo = model.topology
    qdot = jnp.zeros_like(q)
    rev = topo.links_of_type("revolute")
    if len(rev):
        qdot = qdot.at[topo.q_offsets[rev]].set(qd[topo.dof_offsets[rev]])

    def quat_rate(quat, omega):
        pure = jnp.concatenate([jnp.zeros(omega.shape[:-1] + (1,), omega.dtype), omega], -1)
        return 0.5 * rotations.quat_multiply(quat, pure)

    qi, vi = topo.spherical_indices
    if len(qi):
        qdot = qdot.at[qi].set(quat_rate(q[qi], qd[vi]))
    if topo.floating:
        rot = rotations.quat_to_matrix(rotations.quat_normalize(q[3:7]))
        qdot = qdot.at[0:3].set(rot @ qd[3:6])
        qdot = qdot.at[3:7].set(quat_rate(q[3:7], qd[0:3]))
    return qdot


def integrate(model: Model, q, qd, dt):
    """Advance q by the velocity qd over dt on the configuration manifold.

    Quaternions are multiplied by the exponential of their body-frame rotation, q ⊗ exp(ω Δt),
    and renormalised; the root position moves by R v Δt (R the root's current orientation);
    revolute angles move by θ̇ Δt. Used with the new velocity, this is semi-implicit Euler.
    """
    topo = model.topology
    q_next = q
    rev = topo.links_of_type("revolute")
    if len(rev):
        q_next = q_next.at[topo.q_offsets[rev]].add(dt * qd[topo.dof_offsets[rev]])

    def rotate(quat, omega):
        turned = rotations.quat_multiply(quat, rotations.rotvec_to_quat(omega * dt))
        return rotations.quat_normalize(turned)

    qi, vi = topo.spherical_indices
    if len(qi):
        q_next = q_next.at[qi].set(rotate(q[qi], qd[vi]))
    if topo.floating:
        rot = rotations.quat_to_matrix(rotations.quat_normalize(q[3:7]))
        q_next = q_next.at[0:3].add(dt * mat_vec(rot, qd[3:6]))
        q_next = q_next.at[3:7].set(rotate(q[3:7], qd[0:3]))
    return q_next
