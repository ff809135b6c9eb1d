"""The task registry: what `takeoff train` needs to know of a task, in one entry per task.

A config names its task in `run.task` and holds that task's settings in the section of the same
name (`[imitation]`, `[reach]`, `[highjump]`, …). The entry gives the section's dataclass, how to
make the environment from it, and which of its keys a resumed run may not change (those that fix
the networks' sizes or what the checkpoint holds). The trainer and the commands know no task by
name; a new task is one `register` call in its module.
"""

import dataclasses
import importlib
from typing import Any, Callable

BUILTIN = {"imitation": "agents.tasks.imitation", "reach": "agents.tasks.reach",
           "highjump": "agents.tasks.jump", "obstacle": "agents.tasks.jump",
           "runup": "agents.tasks.runup"}


@dataclasses.dataclass(frozen=True)
class Task:
    """One task: `settings` is its config section's frozen dataclass; `make_env(settings,
    data_dir)` builds its environment (`data_dir` is the reference-data directory named by the
    user, or None when `needs_data` is false); `fixed_on_resume` names the settings fields a
    resumed run cannot change; `takes_physics` says its environment applies the `[physics]`
    section (`agents.tasks.physics`), and `vmappable` names its settings fields that its
    environment reads from the task parameters of the same name (`agents.sweep`)."""

    name: str
    settings: type
    make_env: Callable[[Any, Any], Any]
    fixed_on_resume: tuple[str, ...] = ()
    needs_data: bool = True
    takes_physics: bool = False        # its environment applies a config's [physics] section
    vmappable: tuple[str, ...] = ()    # settings fields that are task parameters of the same
                                       # name (a sweep vmaps over them)


_TASKS: dict[str, Task] = {}


def register(task: Task) -> Task:
    if task.name in ("run", "ppo"):
        raise ValueError(f"a task cannot be called {task.name!r}: that is a config section")
    _TASKS[task.name] = task
    return task


def names() -> tuple[str, ...]:
    return tuple(dict.fromkeys((*BUILTIN, *_TASKS)))


def get(name: str) -> Task:
    """The registered task `name` (a built-in one is imported on first use); a ValueError
    listing the tasks there are otherwise."""
    if name not in _TASKS and name in BUILTIN:
        importlib.import_module(BUILTIN[name])
    if name not in _TASKS:
        raise ValueError(f"run.task must be one of {', '.join(names())}; got {name!r}")
    return _TASKS[name]
