"""The character's state as the policy sees it (thesis §3.4.1; DeepMimic, Peng et al. 2018).

`body_observation` lists, for one character: the root height; every non-root link's position
relative to the root; every link's rotation as a unit quaternion (w ≥ 0, so that q and −q, the
same rotation, give one observation); every link's linear velocity (of its frame origin) and
angular velocity. Vectors are in world axes by default. With `facing_invariant`, everything is
expressed in the root's heading frame instead (the world turned by the root's yaw about +Y, the
vertical), so the observation does not change when the character is turned about the vertical
or moved horizontally.
"""

import jax.numpy as jnp

from jaxsim import kinematics, rotations
from jaxsim.model import Model

_UP = (0.0, 1.0, 0.0)


def observation_size(model: Model) -> int:
    """1 (root height) + 3 per non-root link (position) + 4 per link (quaternion) + 6 per link
    (linear and angular velocity)."""
    n = model.n_links
    return 1 + 3 * (n - 1) + 4 * n + 6 * n


def heading_rotation(root_rot):
    """The rotation about +Y by the root's yaw: the angle of the root's X axis projected on the
    ground plane, as DeepMimic measures heading (atan2(−x_z, x_x); 0 when the X axis is
    vertical)."""
    x_axis = root_rot[:, 0]
    yaw = jnp.arctan2(-x_axis[2], x_axis[0])
    return rotations.axis_angle_to_matrix(jnp.asarray(_UP, root_rot.dtype), yaw)


def body_observation(model: Model, q, qd, facing_invariant: bool = False):
    """The observation vector (`observation_size(model)`,) of the state (q, qd); pure and
    jittable. `kinematics.link_states` gives body-frame velocities; they are rotated to the world
    (and then to the heading frame, with `facing_invariant`)."""
    rot_w, pos_w, v_body = kinematics.link_states(model, q, qd)
    frame = heading_rotation(rot_w[0]).T if facing_invariant else jnp.eye(3, dtype=q.dtype)
    to_frame = frame @ rot_w                                      # link axes → observation axes
    relative = (pos_w[1:] - pos_w[0]) @ frame.T                   # rows: frame (p − p_root)
    angular = (to_frame @ v_body[:, :3, None])[..., 0]
    linear = (to_frame @ v_body[:, 3:, None])[..., 0]
    return jnp.concatenate([pos_w[0, 1:2], relative.reshape(-1),
                            rotations.matrix_to_quat(to_frame).reshape(-1),
                            linear.reshape(-1), angular.reshape(-1)])
