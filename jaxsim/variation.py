"""Body variations: a model with its segments scaled, its masses, PD gains and torque limits
multiplied, as a pure function of arrays (so a sweep vmaps it over body shapes and a sensitivity
study differentiates through it).

Scaling segment i by s_i means the link is the same link s_i times bigger in every length of
its own frame: the joints of its children (`joint_pos` of each child), its centre of mass, its
collision shape's placement and half-sizes are multiplied by s_i, and its rotational inertia
by s_i² (I = Σ m r², the mass kept). A mass factor k_i multiplies link i's mass and inertia. The
root's own placement (`joint_pos[0]`) is not a length of any segment and is kept.
"""

import jax.numpy as jnp

from jaxsim.model import Model


def scaled_body(model: Model, length=None, mass=None, pd_gain=None, torque_limit=None) -> Model:
    """`model` with per-link `length` and `mass` factors ((n_links,) arrays) and per-DoF
    `pd_gain` (kp and kd alike) and `torque_limit` factors ((nv,) arrays; an unlimited joint,
    torque limit inf, stays unlimited); None keeps a field. Factors of 1 give the model back
    exactly."""
    changes = {}
    if length is not None:
        length = jnp.asarray(length, model.mass.dtype)
        parents = jnp.asarray(model.topology.parents[1:])
        parent_scale = jnp.concatenate([jnp.ones(1, length.dtype), length[parents]])
        changes.update(joint_pos=model.joint_pos * parent_scale[:, None],
                       com=model.com * length[:, None],
                       shape_pos=model.shape_pos * length[:, None],
                       shape_size=model.shape_size * length[:, None],
                       inertia=model.inertia * (length**2)[:, None, None])
    if mass is not None:
        mass = jnp.asarray(mass, model.mass.dtype)
        changes.update(mass=model.mass * mass,
                       inertia=changes.get("inertia", model.inertia) * mass[:, None, None])
    if pd_gain is not None:
        pd_gain = jnp.asarray(pd_gain, model.kp.dtype)
        changes.update(kp=model.kp * pd_gain, kd=model.kd * pd_gain)
    if torque_limit is not None:
        limit = model.torque_limit                     # (inf: no limit, left so, and with a
        finite = jnp.isfinite(limit)                   # zero gradient rather than inf · 0)
        scaled = jnp.where(finite, limit, 0.0) * jnp.asarray(torque_limit, limit.dtype)
        changes.update(torque_limit=jnp.where(finite, scaled, limit))
    return model.replace(**changes)
