"""The Articulated-Body Algorithm and its SPD modification, MABA (thesis §2.3).

Both solve  (M + diag(K)) q̈ = Q − C  in O(n) with Featherstone's three passes; plain ABA is the
case K = 0, Q = τ. MABA changes two lines of ABA (thesis eqs. 2.18–2.20):

    D_i = S_iᵀ I_iᴬ S_i + K_i            with K_i = K_d,i Δt
    u_i = Q_i − S_iᵀ p_iᴬ                with Q_i = −K_p,i (q_i + Δt q̇_i − q̄_i) − K_d,i q̇_i

and passes 2 and 3 then run unchanged with these D_i and u_i (eqs. 2.24–2.29):

    I_iᵃ = I_iᴬ − U_i D_i⁻¹ U_iᵀ,   p_iᵃ = p_iᴬ + I_iᵃ c_i + U_i D_i⁻¹ u_i,   U_i = I_iᴬ S_i
    a′_i = X_i a_λ(i) + c_i,   q̈_i = D_i⁻¹ (u_i − U_iᵀ a′_i),   a_i = a′_i + S_i q̈_i.

Eq. 2.24 is evaluated in the algebraically equal Joseph form

    I_iᵃ = P_iᵀ I_iᴬ P_i + U_i D_i⁻¹ K_i D_i⁻¹ U_iᵀ,   P_i = 1 − S_i D_i⁻¹ U_iᵀ,

which is first-order insensitive to rounding in D_i⁻¹ and symmetric positive semi-definite by
construction. The plain difference lets rounding grow about tenfold per level of a deep tree (a
22-link snake lost all accuracy in float64); see docs/benchmarks.md.

Every non-root joint type (spherical, revolute, fixed) moves in rotation only, S_i = [T_i; 0] with
T_i 3×3, so the step works on 3-row blocks: U_i = I_iᴬ[:, :3] T_i, D_i = T_iᵀ U_i,top + K_i and,
with W_i = U_i D_i⁻¹ and G_i = I_iᴬ P_i = I_iᴬ − U_i W_iᵀ, the Joseph form is
G_i − W_i (T_iᵀ G_i,top) + W_i K_i W_iᵀ; the result moves to the parent by
`spatial.inertia_to_parent`. About half the arithmetic of the 6×6 products.

The floating root is the base case a_0 = (I_0ᴬ + K_0)⁻¹ (Q_0 − p_0ᴬ), with K_0 = 0 for an
unactuated root and SPD gains for "hand-of-God" tracking.
"""

import jax.numpy as jnp

from jaxsim import spatial
from jaxsim.dynamics.common import (bias_forces, cholesky_solve, external_forces,
                                    gravity_vector, inv3, outward_pass)
from jaxsim.model import Model
from jaxsim.spatial import mat_mat, mat_vec
from jaxsim.tree import gather_slots, pad_links, scan_inward, scan_outward, scatter_slots


def articulated_body_solve(model: Model, q, qd, joint_force, damping, f_ext=None, gravity=None):
    """Solve (M + diag(damping)) q̈ = joint_force − C(q, q̇, f_ext) for q̈ (nv) in O(n).

    `joint_force` is τ for ABA or the SPD force Q for MABA; `damping` is 0 for ABA or K_d Δt for
    MABA (both (nv,)). Unused velocity slots of spherical/revolute/fixed joints get D = 1, u = 0.
    """
    topo = model.topology
    links = outward_pass(model, q, qd, gravity_vector(gravity, q.dtype))
    s, v = links["s"], links["v"]
    c = spatial.cross_motion(v, mat_vec(s, links["qd_slots"]))        # c_i = v_i × S_i q̇_i
    unused = 1.0 - pad_links(jnp.asarray(topo.slot_mask[:-1], q.dtype))
    slot_force = gather_slots(topo, joint_force)
    slot_damping = gather_slots(topo, damping) + unused

    def inward_step(acc, link):
        (ia, pa), (e, r, s_i, c_i, force_i, damping_i) = acc, link
        t_t = s_i[:3].T                                                # S_i = [T_i; 0]
        u_mat = mat_mat(ia[:, :3], s_i[:3])                            # U_i = I_iᴬ S_i
        d_inv = inv3(mat_mat(t_t, u_mat[:3]) + jnp.diag(damping_i))   # (2.19)
        u = force_i - mat_vec(t_t, pa[:3])                             # (2.20)
        w = mat_mat(u_mat, d_inv)                                      # W = U D⁻¹
        g = ia - mat_mat(u_mat, w.T)                                   # Iᴬ P
        ia_art = (g - mat_mat(w, mat_mat(t_t, g[:3]))                  # (2.24), Joseph form
                  + mat_mat(w * damping_i, w.T))
        pa_art = pa + mat_vec(ia_art, c_i) + mat_vec(w, u)             # (2.25)
        return (u_mat, d_inv, u), (spatial.inertia_to_parent(e, r, ia_art),
                                   spatial.transform_force_to_parent(e, r, pa_art))

    (ia_root, pa_root), per_level = scan_inward(
        topo, inward_step, (links["inertia"], bias_forces(links, external_forces(model, f_ext))),
        (links["e"], links["r"], s, c, slot_force, slot_damping))

    if topo.floating:
        a_root = cholesky_solve(ia_root + jnp.diag(damping[:6]), joint_force[:6] - pa_root)
    else:
        a_root = jnp.zeros(6, q.dtype)

    def outward_step(parent, link, level):
        (a_p, _), (e, r, s_i, c_i), (u_mat, d_inv, u) = parent, link, level
        a_prime = spatial.transform_motion(e, r, a_p) + c_i
        qdd_i = mat_vec(d_inv, u - mat_vec(u_mat.T, a_prime))          # (2.29)
        return a_prime + mat_vec(s_i, qdd_i), qdd_i

    _, qdd_slots = scan_outward(topo, outward_step, (a_root, jnp.zeros(3, q.dtype)),
                                (links["e"], links["r"], s, c), per_level)
    return scatter_slots(topo, qdd_slots, a_root)


def aba(model: Model, q, qd, tau, f_ext=None, gravity=None):
    """Forward dynamics q̈ = M⁻¹(τ − C) by the Articulated-Body Algorithm (RBDA §7.3)."""
    return articulated_body_solve(model, q, qd, tau, jnp.zeros_like(qd), f_ext, gravity)
