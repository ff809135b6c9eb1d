"""Recursive Newton–Euler inverse dynamics (RBDA §5.3, with a floating or fixed base)."""

import jax.numpy as jnp

from jaxsim import spatial
from jaxsim.dynamics.common import bias_forces, external_forces, gravity_vector, outward_pass
from jaxsim.model import Model
from jaxsim.tree import from_levels, scan_inward, scatter_slots


def rnea(model: Model, q, qd, qdd, f_ext=None, gravity=None):
    """Generalised forces τ (nv) that produce accelerations `qdd`: τ = M(q) q̈ + C(q, q̇, f_ext).

    `f_ext` (n_links, 6) are spatial forces on the links in link coordinates; gravity defaults to
    (0, −9.81, 0). For a floating base, τ[:6] is the spatial force the world would have to apply
    to the root (zero when `qdd` is physically consistent).
    """
    links = outward_pass(model, q, qd, gravity_vector(gravity, q.dtype), qdd)
    ia = (links["inertia"] @ links["a"][..., None])[..., 0]
    forces = ia + bias_forces(links, external_forces(model, f_ext))

    def step(f_i, link):
        e, r, s_i = link
        return s_i.T @ f_i, spatial.transform_force_to_parent(e, r, f_i)

    f_root, tau_levels = scan_inward(model.topology, step, forces,
                                      (links["e"], links["r"], links["s"]))
    tau_slots = from_levels(model.topology, jnp.zeros_like(links["qd_slots"][0]), tau_levels)
    return scatter_slots(model.topology, tau_slots, f_root)


def bias_torques(model: Model, q, qd, f_ext=None, gravity=None):
    """C(q, q̇, f_ext) of M q̈ + C = τ (thesis eq. 2.5): RNEA with q̈ = 0."""
    return rnea(model, q, qd, jnp.zeros_like(qd), f_ext, gravity)
