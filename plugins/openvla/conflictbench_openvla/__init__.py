"""OpenVLA and OpenVLA-OFT for conflictbench: their LIBERO clients over ``deploy.py``'s REST protocol."""

__version__ = "0.2.0"  # the distribution's (pyproject.toml)
