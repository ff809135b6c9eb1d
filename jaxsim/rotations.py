"""Rotation representations and conversions.

Quaternions are (w, x, y, z) as in DeepMimic's pose files. Rotation vectors (exponential
coordinates) are axis * angle. The 6D representation is the first two columns of the rotation
matrix (Zhou et al., 2019), as used for the P-VAE pose features (thesis §3.4.2).

Every function works on a single rotation and broadcasts over leading axes, and every one is
differentiable with finite gradients at the identity: the divisions by the rotation angle that
appear in the textbook formulas are replaced by their Taylor series below a small angle. The one
exception is `is_rotation_matrix`, a NumPy check for validating user input.
"""

import jax.numpy as jnp
import numpy as np

# Below this squared angle the exp/log maps use Taylor series instead of sin(θ)/θ-style ratios.
_SMALL_ANGLE_SQ = 1e-8


def skew(v):
    """The 3×3 matrix ṽ with ṽ u = v × u."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = jnp.zeros_like(x)
    return jnp.stack(
        [
            jnp.stack([zero, -z, y], -1),
            jnp.stack([z, zero, -x], -1),
            jnp.stack([-y, x, zero], -1),
        ],
        -2,
    )


def quat_identity(shape=(), dtype=jnp.float32):
    return jnp.zeros(shape + (4,), dtype).at[..., 0].set(1.0)


def quat_normalize(q):
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)


def quat_conjugate(q):
    return q * jnp.array([1.0, -1.0, -1.0, -1.0], q.dtype)


def quat_multiply(a, b):
    """Hamilton product a ⊗ b (apply b first, then a, when both act on vectors)."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return jnp.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def quat_to_matrix(q):
    """Rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return jnp.stack(
        [
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(m):
    """Unit quaternion (w ≥ 0) of a rotation matrix, by Shepperd's method.

    All four candidate formulas are evaluated and the numerically safest one is selected, so the
    function is branch-free (jit/vmap friendly); the unselected candidates never divide by zero.
    """
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    trace = m00 + m11 + m22
    pivots = jnp.stack([trace, m00, m11, m22], -1)
    choice = jnp.argmax(pivots, axis=-1)

    def safe_sqrt(x):
        return jnp.sqrt(jnp.maximum(x, 1e-12))

    sw = safe_sqrt(1 + trace) * 2
    sx = safe_sqrt(1 + m00 - m11 - m22) * 2
    sy = safe_sqrt(1 - m00 + m11 - m22) * 2
    sz = safe_sqrt(1 - m00 - m11 + m22) * 2
    cand_w = jnp.stack(
        [0.25 * sw, (m[..., 2, 1] - m[..., 1, 2]) / sw, (m[..., 0, 2] - m[..., 2, 0]) / sw,
         (m[..., 1, 0] - m[..., 0, 1]) / sw], -1)
    cand_x = jnp.stack(
        [(m[..., 2, 1] - m[..., 1, 2]) / sx, 0.25 * sx, (m[..., 0, 1] + m[..., 1, 0]) / sx,
         (m[..., 0, 2] + m[..., 2, 0]) / sx], -1)
    cand_y = jnp.stack(
        [(m[..., 0, 2] - m[..., 2, 0]) / sy, (m[..., 0, 1] + m[..., 1, 0]) / sy, 0.25 * sy,
         (m[..., 1, 2] + m[..., 2, 1]) / sy], -1)
    cand_z = jnp.stack(
        [(m[..., 1, 0] - m[..., 0, 1]) / sz, (m[..., 0, 2] + m[..., 2, 0]) / sz,
         (m[..., 1, 2] + m[..., 2, 1]) / sz, 0.25 * sz], -1)
    candidates = jnp.stack([cand_w, cand_x, cand_y, cand_z], -2)
    q = jnp.take_along_axis(candidates, choice[..., None, None], axis=-2)[..., 0, :]
    q = q * jnp.where(q[..., :1] < 0, -1.0, 1.0)
    return quat_normalize(q)


def _angle_and_sinc_terms(v):
    """θ² and a safe θ for rotation vectors v (θ = |v|, replaced by 1 where θ is tiny)."""
    theta_sq = jnp.sum(v * v, axis=-1)
    small = theta_sq < _SMALL_ANGLE_SQ
    theta = jnp.sqrt(jnp.where(small, 1.0, theta_sq))
    return theta_sq, theta, small


def rotvec_to_quat(v):
    """Exponential map: rotation vector (axis·angle) → unit quaternion."""
    theta_sq, theta, small = _angle_and_sinc_terms(v)
    half_sinc = jnp.where(small, 0.5 - theta_sq / 48.0, jnp.sin(theta / 2) / theta)
    w = jnp.where(small, 1.0 - theta_sq / 8.0, jnp.cos(theta / 2))
    return jnp.concatenate([w[..., None], v * half_sinc[..., None]], -1)


def quat_to_rotvec(q):
    """Logarithm map: unit quaternion → rotation vector with angle in [0, π] (shortest arc)."""
    q = q * jnp.where(q[..., :1] < 0, -1.0, 1.0)
    w, xyz = q[..., 0], q[..., 1:]
    s_sq = jnp.sum(xyz * xyz, axis=-1)
    small = s_sq < _SMALL_ANGLE_SQ
    s = jnp.sqrt(jnp.where(small, 1.0, s_sq))
    # angle / s, with angle = 2 atan2(s, w); series 2/w · (1 − s²/(3w²)) near s = 0.
    w_safe = jnp.where(small, w, 1.0)
    ratio = jnp.where(small, 2.0 / w_safe * (1.0 - s_sq / (3.0 * w_safe**2)),
                      2.0 * jnp.arctan2(s, w) / s)
    return xyz * ratio[..., None]


def relative_rotvec(q0, q1):
    """log(q₀⁻¹ ⊗ q₁): the rotation vector, in q₀'s frame, of the rotation that takes q₀ to q₁
    (shortest arc)."""
    return quat_to_rotvec(quat_multiply(quat_conjugate(q0), q1))


def rotvec_to_matrix(v):
    """Rodrigues' formula, R = I + sinc(θ) ṽ + (1 − cos θ)/θ² ṽ²."""
    theta_sq, theta, small = _angle_and_sinc_terms(v)
    a = jnp.where(small, 1.0 - theta_sq / 6.0, jnp.sin(theta) / theta)
    b = jnp.where(small, 0.5 - theta_sq / 24.0, (1.0 - jnp.cos(theta)) / (theta * theta))
    k = skew(v)
    eye = jnp.broadcast_to(jnp.eye(3, dtype=v.dtype), k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def matrix_to_rotvec(m):
    return quat_to_rotvec(matrix_to_quat(m))


def axis_angle_to_quat(axis, angle):
    """Quaternion of a rotation by `angle` about the unit vector `axis`."""
    half = 0.5 * angle
    return jnp.concatenate([jnp.cos(half)[..., None], axis * jnp.sin(half)[..., None]], -1)


def axis_angle_to_matrix(axis, angle):
    """Rodrigues' formula for a unit axis: R = I + sin θ ã + (1 − cos θ) ã²."""
    k = skew(axis)
    eye = jnp.broadcast_to(jnp.eye(3, dtype=k.dtype), k.shape)
    s, c = jnp.sin(angle)[..., None, None], jnp.cos(angle)[..., None, None]
    return eye + s * k + (1.0 - c) * (k @ k)


def is_rotation_matrix(m, atol: float = 1e-6) -> bool:
    """Whether `m` is a 3×3 proper rotation: finite, orthogonal (within atol) and with
    determinant +1, so not a reflection."""
    m = np.asarray(m, float)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        return False
    return bool(np.allclose(m @ m.T, np.eye(3), atol=atol) and np.linalg.det(m) > 0)


def euler_xyz_to_matrix(angles):
    """R = Rz(θz) · Ry(θy) · Rx(θx): rotate about X first, then Y, then Z (fixed axes).

    This is how DeepMimic's `AttachThetaX/Y/Z` angles are read.
    """
    angles = jnp.asarray(angles)
    ex, ey, ez = jnp.eye(3, dtype=angles.dtype)
    rx = axis_angle_to_matrix(ex, angles[..., 0])
    ry = axis_angle_to_matrix(ey, angles[..., 1])
    rz = axis_angle_to_matrix(ez, angles[..., 2])
    return rz @ ry @ rx


def matrix_to_6d(m):
    """6D rotation features: the first two columns of R, concatenated (column 0, then column 1)."""
    return jnp.concatenate([m[..., :, 0], m[..., :, 1]], -1)


def sixd_to_matrix(d6):
    """Nearest rotation to a 6D feature by Gram–Schmidt on its two columns."""
    a, b = d6[..., :3], d6[..., 3:]
    c0 = a / jnp.linalg.norm(a, axis=-1, keepdims=True)
    b = b - jnp.sum(c0 * b, -1, keepdims=True) * c0
    c1 = b / jnp.linalg.norm(b, axis=-1, keepdims=True)
    c2 = jnp.cross(c0, c1)
    return jnp.stack([c0, c1, c2], -1)
