"""Featherstone's spatial vector algebra (RBDA, ch. 2).

Motion vectors are [ω; v] and force vectors [n; f]. A Plücker transform from frame A to frame B
is given by the rotation E (A coordinates → B coordinates) and the position r of B's origin in A
coordinates:

    ᴮX_A = [[E, 0], [−E r̃, E]]      (motion),      ᴮX_A* = [[E, −E r̃], [0, E]]   (force).

All functions act on one vector/matrix and broadcast over leading axes.
"""

import jax.numpy as jnp

from jaxsim.rotations import skew


def mat_vec(a, v):
    """a @ v for small matrices, as a sum of column-times-entry products.

    XLA on CPU runs batches of tiny `dot`s slowly, and a `dot` or a reduction ends a fusion. Written
    as a short sum of elementwise products (one term per inner index), the product fuses with the
    operations around it into one loop (docs/design.md, "Performance notes").
    """
    return sum(a[..., :, k] * v[..., k:k + 1] for k in range(a.shape[-1]))


def mat_mat(a, b):
    """a @ b for small matrices, as a sum of outer products of a's columns and b's rows."""
    return sum(a[..., :, k:k + 1] * b[..., k:k + 1, :] for k in range(a.shape[-1]))


def transpose(a):
    return jnp.swapaxes(a, -1, -2)


def cross_motion(v, u):
    """v × u for motion vectors (the crm operator applied to u)."""
    w, vl = v[..., :3], v[..., 3:]
    uw, ul = u[..., :3], u[..., 3:]
    return jnp.concatenate([jnp.cross(w, uw), jnp.cross(w, ul) + jnp.cross(vl, uw)], -1)


def cross_force(v, f):
    """v ×* f for a motion vector v and a force vector f (the crf operator applied to f)."""
    w, vl = v[..., :3], v[..., 3:]
    n, fl = f[..., :3], f[..., 3:]
    return jnp.concatenate([jnp.cross(w, n) + jnp.cross(vl, fl), jnp.cross(w, fl)], -1)


def crm(v):
    """6×6 matrix of v× (motion cross product)."""
    w, vl = skew(v[..., :3]), skew(v[..., 3:])
    zero = jnp.zeros_like(w)
    return jnp.concatenate(
        [jnp.concatenate([w, zero], -1), jnp.concatenate([vl, w], -1)], -2)


def crf(v):
    """6×6 matrix of v×* = −crm(v)ᵀ."""
    return -jnp.swapaxes(crm(v), -1, -2)


def plucker(rotation, translation):
    """Motion transform ᴮX_A from E (A→B coordinates) and r (B's origin in A coordinates)."""
    zero = jnp.zeros_like(rotation)
    lower_left = -rotation @ skew(translation)
    return jnp.concatenate(
        [jnp.concatenate([rotation, zero], -1), jnp.concatenate([lower_left, rotation], -1)], -2)


def transform_motion(rotation, translation, v):
    """ᴮX_A v without forming the 6×6 matrix: [E ω; E(v − r × ω)]."""
    w, vl = v[..., :3], v[..., 3:]
    return jnp.concatenate(
        [mat_vec(rotation, w), mat_vec(rotation, vl - jnp.cross(translation, w))], -1)


def transform_force_to_parent(rotation, translation, f):
    """ᴮX_Aᵀ f: a force in B coordinates expressed in A coordinates: [Eᵀn + r × Eᵀf; Eᵀf]."""
    et = transpose(rotation)
    n, fl = mat_vec(et, f[..., :3]), mat_vec(et, f[..., 3:])
    return jnp.concatenate([n + jnp.cross(translation, fl), fl], -1)


def inertia_to_parent(rotation, translation, inertia):
    """ᴮX_Aᵀ I ᴮX_A: a 6×6 (articulated) inertia in B coordinates expressed in A coordinates,
    with X = plucker(E, r), by 3×3 blocks instead of two 6×6 products (about 40% of the work).

    X = diag(E, E) · T with T = [[1, 0], [−r̃, 1]]. Rotating first, J = diag(Eᵀ, Eᵀ) I diag(E, E)
    has blocks J_xy = Eᵀ I_xy E, and then Tᵀ J T = [[J_aa + r̃ J_ba − N r̃, N], [J_ba − J_bb r̃, J_bb]]
    with N = J_ab + r̃ J_bb. All four blocks are transformed, not three and a transpose: an
    articulated inertia of a deep chain is nearly singular, and imposing symmetry here cost 1000×
    in accuracy on the 195-DoF snake (tests/test_dynamics.py).
    """
    et = transpose(rotation)
    r = skew(translation)

    def rotate(block):
        return mat_mat(et, mat_mat(block, rotation))
    j_aa, j_ab = rotate(inertia[..., :3, :3]), rotate(inertia[..., :3, 3:])
    j_ba, j_bb = rotate(inertia[..., 3:, :3]), rotate(inertia[..., 3:, 3:])
    n = j_ab + mat_mat(r, j_bb)
    top = jnp.concatenate([j_aa + mat_mat(r, j_ba) - mat_mat(n, r), n], -1)
    bottom = jnp.concatenate([j_ba - mat_mat(j_bb, r), j_bb], -1)
    return jnp.concatenate([top, bottom], -2)


def inertia_matrix(mass, com, rot_inertia):
    """6×6 spatial inertia of a rigid body about its frame origin.

    `com` is the centre of mass and `rot_inertia` the 3×3 rotational inertia about the centre of
    mass, both in body coordinates: I = [[Ī_c + m c̃ c̃ᵀ, m c̃], [m c̃ᵀ, m 1]] (RBDA eq. 2.63).
    """
    c = skew(com)
    m = mass[..., None, None]
    eye = jnp.broadcast_to(jnp.eye(3, dtype=c.dtype), c.shape)
    ct = jnp.swapaxes(c, -1, -2)
    upper = jnp.concatenate([rot_inertia + m * (c @ ct), m * c], -1)
    lower = jnp.concatenate([m * ct, m * eye], -1)
    return jnp.concatenate([upper, lower], -2)
