"""jaxsim: articulated rigid-body simulation in JAX (takeoff's simulator).

Not to be confused with the unrelated PyPI project of the same import name (ami-iit's `jaxsim`).

Submodules and the names below load on first use (PEP 562), so that `import jaxsim.allocator`
or `jaxsim.atomic` does not import JAX: the command line restarts itself with `jaxsim.allocator`
before paying for that import.
"""

import importlib

_SUBMODULES = ("characters", "contact", "dynamics", "kinematics", "limits", "motion", "rotations",
               "simulation", "spatial", "tracking", "world", "xla_options")
_NAMES = {"LinkSpec": "builder", "build_model": "builder", "to_mjcf": "mjcf", "Model": "model",
          "ModelError": "model", "State": "model", "Topology": "model", "rest_pose": "model"}

__all__ = [*_SUBMODULES, *_NAMES]


def __getattr__(name):
    if name in _SUBMODULES:
        return importlib.import_module(f"jaxsim.{name}")
    if name in _NAMES:
        return getattr(importlib.import_module(f"jaxsim.{_NAMES[name]}"), name)
    raise AttributeError(f"module 'jaxsim' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *__all__])
