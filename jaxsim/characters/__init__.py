"""Characters: built-in humanoid, quadruped and snakes, and DeepMimic's character files."""

from jaxsim.characters.athlete import athlete
from jaxsim.characters.common import vertical_extent
from jaxsim.characters.deepmimic import load_deepmimic
from jaxsim.characters.humanoid import humanoid
from jaxsim.characters.quadruped import quadruped
from jaxsim.characters.snake import snake

BUILTIN = {"humanoid": humanoid, "quadruped": quadruped, "snake": snake}

__all__ = ["BUILTIN", "athlete", "humanoid", "load_deepmimic", "quadruped", "snake", "vertical_extent"]
