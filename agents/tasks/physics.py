"""The `[physics]` config section: the body and the world a task runs in, as factors on its
defaults, carried in the task parameters (`params["physics"]`) so a sweep vmaps over them and a
sensitivity study differentiates with respect to them.

Every key is a factor, 1 by default (the task as it is):

    length_scale          every segment of the body (`jaxsim.variation.scaled_body`: a segment
                          s times bigger, its mass kept)
    leg_length_scale      the thighs and shins (links named *_hip and *_knee), times the above
    arm_length_scale      the upper arms and forearms (*_shoulder and *_elbow)
    mass_scale            every link's mass (and inertia)
    pd_gain_scale         every joint's kp and kd
    torque_limit_scale    every joint's torque limit
    gravity_scale, friction_scale, contact_stiffness_scale, contact_damping_scale
                          the world's

A task that takes the section (its registry entry says `takes_physics`) builds each episode's
model and world with `varied`; a body scaled at the reset is put back down on its support
(the jump tasks: on the take-off foot), so longer legs stand on the ground rather than in it.
"""

import dataclasses
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from agents.config import check_positive
from jaxsim.variation import scaled_body

LEG_SEGMENTS = ("_hip", "_knee")          # the DeepMimic humanoids' thigh and shin links
ARM_SEGMENTS = ("_shoulder", "_elbow")    # upper arm, forearm
WORLD_FACTORS = {"gravity_scale": "gravity", "friction_scale": "friction",
                 "contact_stiffness_scale": "contact_stiffness",
                 "contact_damping_scale": "contact_damping"}


@dataclass(frozen=True)
class PhysicsSettings:
    """The `[physics]` section (see the module docstring)."""

    length_scale: float = 1.0
    leg_length_scale: float = 1.0
    arm_length_scale: float = 1.0
    mass_scale: float = 1.0
    pd_gain_scale: float = 1.0
    torque_limit_scale: float = 1.0
    gravity_scale: float = 1.0
    friction_scale: float = 1.0
    contact_stiffness_scale: float = 1.0
    contact_damping_scale: float = 1.0

    def __post_init__(self):
        check_positive(self, names())


def names() -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(PhysicsSettings))


def params_of(settings: PhysicsSettings, dtype) -> dict:
    """The section as task parameters: {key: () array}."""
    return {name: jnp.asarray(getattr(settings, name), dtype) for name in names()}


def segment_links(model, suffixes) -> np.ndarray:
    """(n_links,) bools: the links whose names end with one of `suffixes`."""
    return np.array([name.endswith(suffixes) for name in model.topology.names])


def check_fits(model, settings: PhysicsSettings, key_prefix="physics"):
    """A ValueError naming the key when a segment factor other than 1 would change nothing
    because the character has no such segments (a robot arm has no legs)."""
    for name, suffixes in (("leg_length_scale", LEG_SEGMENTS),
                           ("arm_length_scale", ARM_SEGMENTS)):
        if getattr(settings, name) != 1.0 and not segment_links(model, suffixes).any():
            raise ValueError(f"{key_prefix}.{name}: the character has no links named "
                             f"*{' or *'.join(suffixes)}; its links are "
                             f"{', '.join(model.topology.names)}")


def varied(model, world, physics: dict):
    """(model, world) with the factors of `physics` (task parameters, `params_of`) applied."""
    legs = segment_links(model, LEG_SEGMENTS)
    arms = segment_links(model, ARM_SEGMENTS)
    one = jnp.ones((), model.mass.dtype)
    length = (physics["length_scale"]
              * jnp.where(legs, physics["leg_length_scale"], one)
              * jnp.where(arms, physics["arm_length_scale"], one))
    links, dofs = model.n_links, model.nv
    model = scaled_body(model, length=length,
                        mass=jnp.broadcast_to(physics["mass_scale"], (links,)),
                        pd_gain=jnp.broadcast_to(physics["pd_gain_scale"], (dofs,)),
                        torque_limit=jnp.broadcast_to(physics["torque_limit_scale"], (dofs,)))
    world = world.replace(**{field: getattr(world, field) * physics[factor]
                             for factor, field in WORLD_FACTORS.items()})
    return model, world
