"""Tasks: environments with pure `reset` and `step` (see `agents.env`)."""
