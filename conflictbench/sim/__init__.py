"""Simulation: planning episodes, worker processes that own LIBERO envs, and the runner."""
