"""The univla model environment in tests: a tiny checkpoint for the stand-in UniVLA checkout, built once per session
(``tiny_univla.py``); every process gets ``UNIVLA_CODE`` naming that checkout."""

from __future__ import annotations

from pathlib import Path

from conflictbench.testing import ModelEnvironment

TESTS = Path(__file__).resolve().parent
CODE = TESTS / "standin_univla_code"
UNIVLA = ModelEnvironment("univla", TESTS, extra=lambda checkpoint: {"UNIVLA_CODE": str(CODE)})
needs_model_env, model_env, run_in_model_env = UNIVLA.needs, UNIVLA.env, UNIVLA.run
tiny_checkpoint = UNIVLA.checkpoint_fixture("tiny_univla.py")
