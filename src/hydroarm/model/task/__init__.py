"""The task: reference trajectories and task files (settings or a file, and where the run starts)."""
