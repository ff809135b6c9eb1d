"""jaxsim: articulated rigid-body simulation in JAX (takeoff's simulator).

Not to be confused with the unrelated PyPI project of the same import name (ami-iit's `jaxsim`).
"""

from jaxsim import (characters, contact, dynamics, kinematics, limits, motion, rotations,
                    simulation, spatial, tracking, world)
from jaxsim.builder import LinkSpec, build_model
from jaxsim.mjcf import to_mjcf
from jaxsim.model import Model, ModelError, State, Topology, rest_pose

__all__ = ["characters", "contact", "dynamics", "kinematics", "limits", "motion", "rotations",
           "simulation", "spatial", "tracking", "world", "LinkSpec",
           "build_model", "to_mjcf", "Model", "ModelError", "State", "Topology", "rest_pose"]
