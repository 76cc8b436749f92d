"""The paired-episode viewer: a static HTML site from an episode store (``conflictbench view DIR``)."""

from .build import Built, build_site
from .pairs import Selection

__all__ = ["Built", "Selection", "build_site"]
