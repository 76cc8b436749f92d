"""The VLA-JEPA model environment in tests: a tiny random-weight checkpoint built once per session (its tiny
backbone's hub id resolves in the checkpoint's own hub cache, which every process loading it gets)."""

from __future__ import annotations

from pathlib import Path

from conflictbench.testing import ModelEnvironment

TESTS = Path(__file__).resolve().parent
VLA_JEPA = ModelEnvironment("vla_jepa", TESTS, extra=lambda checkpoint: {"HF_HUB_CACHE": str(checkpoint / "hub")})
needs_model_env, model_env, run_in_model_env, MODEL_PYTHON = VLA_JEPA.needs, VLA_JEPA.env, VLA_JEPA.run, VLA_JEPA.python
tiny_checkpoint = VLA_JEPA.checkpoint_fixture("tiny_jepa.py")
