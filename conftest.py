"""For every test in this tree (core, serving and each plugin's): where compiled LIBERO scenes are kept.

Tests start hundreds of short runs, each in new processes that would compile their scenes again (~5 s each);
a shared cache of compiled models (conflictbench/sim/compiled_models.py) loads them instead. Set
CONFLICTBENCH_MODEL_CACHE to move it, or to an empty value to compile every time.
"""

import os
from pathlib import Path

os.environ.setdefault("CONFLICTBENCH_MODEL_CACHE", str(Path.home() / ".cache" / "conflictbench" / "compiled-models"))
