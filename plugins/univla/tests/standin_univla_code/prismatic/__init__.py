"""As UniVLA's package does, this imports the training stack, which a model environment does not have."""

import draccus  # noqa: F401  (not installed anywhere here: importing the package must not be needed)
