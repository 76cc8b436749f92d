"""UniVLA for conflictbench: UniVLA's LIBERO client (latent-action history, temporal ensembling) over REST."""

__version__ = "0.1.0"
