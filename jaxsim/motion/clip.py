"""Motion clips: keyframed poses of one character, sampled at any time.

A `Clip` holds frame start times and poses in the character's q layout (DeepMimic's pose layout:
root position, root quaternion, then per joint a quaternion or an angle). Between frames, positions
and angles are interpolated linearly and quaternions by slerp, q(s) = q₀ ⊗ exp(s log(q₀⁻¹ q₁)).
Velocities are the exact derivative of that interpolant, in the generalised-velocity layout:
body-frame rotation rates log(q₀⁻¹ q₁)/Δt for the root and the spherical joints (constant within a
frame interval), the root's linear velocity in its body frame, and angle rates.

A looping clip repeats: time wraps, and each completed cycle carries the root's horizontal (X, Z)
displacement over one cycle, so a walk keeps walking forward. A non-looping clip holds its first
frame before t = 0 and its last frame after its end, and its velocity there is zero; at t = 0 and
t = duration themselves it is the first and the last interval's. `Clip` is a pytree (times and
poses are arrays) with its character's topology as static metadata, so sampling is jittable and
vmappable over time.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import kinematics, rotations
from jaxsim.model import Model, Topology


@dataclasses.dataclass(frozen=True)
class Clip:
    """Frame start times (F,), poses (F, nq), and whether the clip loops (static)."""

    times: jax.Array
    poses: jax.Array
    topology: Topology
    loop: bool

    @property
    def duration(self):
        return self.times[-1]

    @property
    def n_frames(self) -> int:
        return self.poses.shape[0]


jax.tree_util.register_dataclass(Clip, data_fields=["times", "poses"],
                                 meta_fields=["topology", "loop"])


def _rotation_indices(topology: Topology):
    """Indices of every quaternion in q (k, 4) and of its rotation rate in qd (k, 3): the root's
    first (when it floats), then the spherical joints'."""
    quats, rates = topology.spherical_indices
    if topology.floating:
        quats = np.concatenate([np.arange(3, 7)[None], quats])
        rates = np.concatenate([np.arange(0, 3)[None], rates])
    return quats, rates


def _cycle_offset(clip: Clip):
    """Horizontal root displacement over one cycle (X, Z; Y is kept)."""
    delta = clip.poses[-1, :3] - clip.poses[0, :3]
    return delta * jnp.array([1.0, 0.0, 1.0], delta.dtype)


def _locate(clip: Clip, t):
    """Frame index k, fraction s ∈ [0, 1] within frame k, interval length and completed cycles."""
    duration = clip.duration
    if clip.loop:
        cycles = jnp.floor(t / duration)
        local = t - cycles * duration
    else:
        cycles = jnp.zeros_like(t)
        local = jnp.clip(t, 0.0, duration)
    k = jnp.clip(jnp.searchsorted(clip.times, local, side="right") - 1, 0, clip.n_frames - 2)
    interval = clip.times[k + 1] - clip.times[k]
    s = jnp.clip((local - clip.times[k]) / interval, 0.0, 1.0)
    return k, s, interval, cycles


def sample_pose(clip: Clip, t):
    """The pose q (nq) at time t (seconds)."""
    k, s, _, cycles = _locate(clip, t)
    q0, q1 = clip.poses[k], clip.poses[k + 1]
    pose = q0 + s * (q1 - q0)
    quats, _ = _rotation_indices(clip.topology)
    turned = rotations.quat_multiply(
        q0[quats], rotations.rotvec_to_quat(s * rotations.relative_rotvec(q0[quats], q1[quats])))
    pose = pose.at[quats].set(turned)
    if clip.topology.floating:
        pose = pose.at[:3].add(cycles * _cycle_offset(clip))
    return pose


def sample_velocity(clip: Clip, t):
    """The generalised velocity qd (nv) at time t: the derivative of `sample_pose`."""
    topo = clip.topology
    k, _, interval, _ = _locate(clip, t)
    q0, q1 = clip.poses[k], clip.poses[k + 1]
    qd = jnp.zeros(topo.nv, clip.poses.dtype)
    rev = topo.links_of_type("revolute")
    if len(rev):
        qd = qd.at[topo.dof_offsets[rev]].set(
            (q1[topo.q_offsets[rev]] - q0[topo.q_offsets[rev]]) / interval)
    quats, rates = _rotation_indices(topo)
    qd = qd.at[rates].set(rotations.relative_rotvec(q0[quats], q1[quats]) / interval)
    if topo.floating:
        rot = rotations.quat_to_matrix(sample_pose(clip, t)[3:7])
        qd = qd.at[3:6].set(rot.T @ ((q1[:3] - q0[:3]) / interval))
    if clip.loop:
        return qd
    return jnp.where((t >= 0) & (t <= clip.duration), qd, jnp.zeros_like(qd))


def link_positions(model: Model, clip: Clip, times):
    """World positions of every link origin at the given times, (T, n_links, 3)."""
    poses = jax.vmap(lambda t: sample_pose(clip, t))(jnp.asarray(times, clip.poses.dtype))
    return jax.vmap(lambda q: kinematics.forward_kinematics(model, q)[1])(poses)


def make_clip(model: Model, frame_durations, poses, loop: bool, source: str = "clip") -> Clip:
    """A validated clip for `model` from per-frame durations (F,) and poses (F, nq).

    Quaternions are normalised. Errors name `source` and the offending frame.
    """
    topo = model.topology
    durations = np.asarray(frame_durations, float)
    poses = np.array(poses, float)
    if poses.ndim != 2 or poses.shape[0] < 2:
        raise ValueError(f"{source}: a clip needs at least 2 frames of poses, got shape "
                         f"{poses.shape}")
    if poses.shape[1] != topo.nq:
        raise ValueError(f"{source}: poses have {poses.shape[1]} numbers per frame, but the "
                         f"character ({topo.n_links} joints: {', '.join(topo.names)}) needs "
                         f"nq = {topo.nq}")
    bad = np.flatnonzero(~np.isfinite(poses).all(1))
    if len(bad):
        raise ValueError(f"{source}: frame {bad[0]} has non-finite values")
    if durations.shape != (poses.shape[0],) or np.any(durations[:-1] <= 0) or \
            not np.all(np.isfinite(durations)):
        raise ValueError(f"{source}: every frame but the last needs a positive duration")
    quats, _ = _rotation_indices(topo)
    norms = np.linalg.norm(poses[:, quats], axis=-1)
    if np.any(norms < 1e-6):
        frame, slot = np.argwhere(norms < 1e-6)[0]
        raise ValueError(f"{source}: frame {frame} has a zero quaternion at q[{quats[slot][0]}]")
    poses[:, quats] /= norms[..., None]
    times = np.concatenate([[0.0], np.cumsum(durations[:-1])])
    dtype = model.mass.dtype
    return Clip(jnp.asarray(times, dtype), jnp.asarray(poses, dtype), topo, bool(loop))


def bucket_length(count: int, minimum: int = 16) -> int:
    """The next power of two ≥ count (and ≥ minimum). Padding per-frame arrays to such lengths
    lets clips of many lengths share a few compilations of the same function."""
    return max(minimum, 1 << (max(count, 1) - 1).bit_length())
