"""The GR00T model environment in tests: a tiny random-weight checkpoint built once per session (its base model
and VLM processor in a Hugging Face cache of its own, which every process loading it gets as ``HF_HOME``)."""

from __future__ import annotations

from pathlib import Path

from conflictbench.testing import ModelEnvironment

TESTS = Path(__file__).resolve().parent
GR00T = ModelEnvironment("gr00t", TESTS, extra=lambda checkpoint: {"HF_HOME": str(checkpoint / "hf_home")})
needs_model_env, model_env, run_in_model_env, MODEL_PYTHON = GR00T.needs, GR00T.env, GR00T.run, GR00T.python
tiny_groot_checkpoint = GR00T.checkpoint_fixture("tiny_groot.py", name="tiny_groot_checkpoint")
