"""Simulation: planning episodes, worker processes that own LIBERO envs, and the runner."""

#: Where the simulator workers run (``run.backend``): processes on this machine, or Ray actors across a cluster.
BACKENDS = ("local", "ray")
