"""takeoff's learning side, grouped by job:

    agents.pose      pose data from motion capture and the pose VAE (thesis §3.4.2)
    agents.rl        the env interface, networks, PPO, the rollout and the training loop (§3.4.1)
    agents.tasks     the tasks (imitation, reach, the jumps of §3.6), their registry and helpers
    agents.commands  the `takeoff` command line and what its subcommands run

`agents.config`, `agents.datadir` and `agents.checkpoint` are shared by all of them.

Modules that used to sit directly in `agents` (`agents.pvae`, `agents.trainer`, `agents.cli`, …)
can still be imported by their old names: each resolves to the module in its package.
"""

import importlib
import importlib.abc
import importlib.util
import sys

MOVED = {
    **dict.fromkeys(("pose_features", "pose_dataset", "pvae", "pvae_report"), "pose"),
    **dict.fromkeys(("env", "networks", "ppo", "rollout", "trainer"), "rl"),
    "observations": "tasks",
    **dict.fromkeys(("cli", "train_commands", "pvae_commands", "strategy_search"), "commands"),
}


class _OldNames(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports `agents.<old>` as the moved module itself (one module object, two names)."""

    def find_spec(self, fullname, path=None, target=None):
        package, _, name = fullname.rpartition(".")
        if package == __name__ and name in MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        name = spec.name.rpartition(".")[2]
        return importlib.import_module(f"{__name__}.{MOVED[name]}.{name}")

    def exec_module(self, module):
        """The moved module ran when it was imported by its new name."""


sys.meta_path.append(_OldNames())
