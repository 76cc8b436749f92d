"""UniVLA for conflictbench: UniVLA's LIBERO client (latent-action history, temporal ensembling) over REST."""

__version__ = "0.2.0"  # the distribution's (pyproject.toml)
