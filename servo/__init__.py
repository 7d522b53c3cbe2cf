"""The 125 Hz servo loop, control objects, trajectories, runners, tools and the CLI."""
