"""Tasks: environments with pure `reset` and `step` (see `agents.rl.env`)."""
