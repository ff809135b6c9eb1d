"""Rigid-body dynamics of one character (batch with `jax.vmap`).

rnea: inverse dynamics; mass_matrix: CRBA; aba: forward dynamics; solve_spd: stable-PD control
solved by name (`dense`, `sparse`, `maba`, `pd`); solve_applied: forward dynamics under given
torques with implicit passive dampers.
"""

from jaxsim.dynamics.aba import aba, articulated_body_solve
from jaxsim.dynamics.common import DEFAULT_GRAVITY
from jaxsim.dynamics.crba import mass_matrix
from jaxsim.dynamics.ltdl import ltdl_factor, ltdl_solve
from jaxsim.dynamics.rnea import bias_torques, rnea
from jaxsim.dynamics.spd import METHODS, pose_error, solve_applied, solve_spd, spd_force

__all__ = ["aba", "articulated_body_solve", "DEFAULT_GRAVITY", "mass_matrix", "ltdl_factor",
           "ltdl_solve", "bias_torques", "rnea", "METHODS", "pose_error", "solve_applied",
           "solve_spd", "spd_force"]
