"""takeoff agents: tasks, networks, PPO, the P-VAE and the `takeoff` command line."""
