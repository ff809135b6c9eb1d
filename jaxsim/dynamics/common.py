"""Per-link quantities shared by the dynamics algorithms, and the first (outward) pass."""

import jax.numpy as jnp

from jaxsim import kinematics, spatial
from jaxsim.model import Model
from jaxsim.spatial import mat_vec
from jaxsim.tree import gather_slots, pad_links, scan_outward

DEFAULT_GRAVITY = (0.0, -9.81, 0.0)


def gravity_vector(gravity, dtype):
    return jnp.asarray(DEFAULT_GRAVITY if gravity is None else gravity, dtype)


def external_forces(model: Model, f_ext):
    """(n, 6) link-frame spatial forces, zeros when none are given."""
    if f_ext is None:
        return jnp.zeros((model.n_links, 6), model.mass.dtype)
    return jnp.asarray(f_ext, model.mass.dtype)


def inv3(m):
    """Inverse of 3×3 matrices by the adjugate: columns r1×r2, r2×r0, r0×r1 over det."""
    r0, r1, r2 = m[..., 0, :], m[..., 1, :], m[..., 2, :]
    cols = jnp.stack([jnp.cross(r1, r2), jnp.cross(r2, r0), jnp.cross(r0, r1)], -1)
    det = jnp.sum(r0 * cols[..., :, 0], -1)
    return cols / det[..., None, None]


def cholesky_solve(a, b):
    """x = a⁻¹ b for small symmetric positive-definite matrices a (…, n, n) and vectors b (…, n),
    by a Cholesky factorisation a = L Lᵀ written out entry by entry (n is static and small).

    `jnp.linalg.solve` calls LAPACK per matrix, which neither fuses with the work around it nor
    runs along a batch held innermost (`jaxsim.batch_last`); these elementwise operations do both.
    """
    n = a.shape[-1]
    low = {}
    for j in range(n):
        low[j, j] = jnp.sqrt(a[..., j, j] - sum(low[j, k] ** 2 for k in range(j)))
        for i in range(j + 1, n):
            low[i, j] = (a[..., i, j] - sum(low[i, k] * low[j, k] for k in range(j))) / low[j, j]
    y = []
    for i in range(n):                                             # L y = b
        y.append((b[..., i] - sum(low[i, k] * y[k] for k in range(i))) / low[i, i])
    x = [None] * n
    for i in reversed(range(n)):                                   # Lᵀ x = y
        x[i] = (y[i] - sum(low[k, i] * x[k] for k in range(i + 1, n))) / low[i, i]
    return jnp.stack(x, -1)


def outward_pass(model: Model, q, qd, gravity, qdd=None):
    """Pass 1 of RNEA/ABA: body-frame velocity v_i, gravity g_i in link coordinates and, when
    `qdd` is given, acceleration a_i = X_i a_λ(i) + S_i q̈_i + v_i × S_i q̇_i (RBDA eq. 5.7–5.9).

    Gravity is applied as the external force I_i [0; g_i] on every link, which keeps the floating
    base case identical to the fixed one. Returns the link data used by the later passes; all
    per-link arrays carry the n+1 link axis of `jaxsim.tree`.
    """
    topo = model.topology
    rot, pos = kinematics.local_poses(model, q)
    s = kinematics.motion_subspaces(model)
    qd_slots = gather_slots(topo, qd)
    g_root = mat_vec(rot[0].T, gravity)
    v_root = qd[:6] if topo.floating else jnp.zeros(6, qd.dtype)
    data = pad_links((jnp.swapaxes(rot, -1, -2), pos, s))
    if qdd is None:
        def step(parent, link):
            (v_p, g_p), (e, r, s_i, qd_i) = parent, link
            return spatial.transform_motion(e, r, v_p) + mat_vec(s_i, qd_i), mat_vec(e, g_p)

        v, g = scan_outward(topo, step, (v_root, g_root), (*data, qd_slots))
        a = None
    else:
        a_root = qdd[:6] if topo.floating else jnp.zeros(6, qd.dtype)

        def step(parent, link):
            (v_p, a_p, g_p), (e, r, s_i, qd_i, qdd_i) = parent, link
            vj = mat_vec(s_i, qd_i)
            v_i = spatial.transform_motion(e, r, v_p) + vj
            a_i = (spatial.transform_motion(e, r, a_p) + mat_vec(s_i, qdd_i)
                   + spatial.cross_motion(v_i, vj))
            return v_i, a_i, mat_vec(e, g_p)

        v, a, g = scan_outward(topo, step, (v_root, a_root, g_root),
                               (*data, qd_slots, gather_slots(topo, qdd)))
    inertia = pad_links(spatial.inertia_matrix(model.mass, model.com, model.inertia))
    return dict(e=data[0], r=data[1], s=data[2], qd_slots=qd_slots, v=v, a=a, g=g,
                inertia=inertia)


def bias_forces(links, f_ext):
    """p_i = v_i ×* I_i v_i − f_ext,i − I_i [0; g_i]: velocity-product, external and gravity
    forces on each link (RBDA eq. 7.2 with gravity as an external force). n+1 link axis."""
    inertia, v, g = links["inertia"], links["v"], links["g"]
    iv = mat_vec(inertia, v)
    gravity_force = mat_vec(inertia[..., 3:], g)
    return spatial.cross_force(v, iv) - pad_links(f_ext) - gravity_force
