"""Each tiny π checkpoint, served as ``model.checkpoint=DIR`` serves it, plays the actions pinned in ``golden/``
bit for bit: a refactor of the client, the transport, the server or the backend must not change one."""

from __future__ import annotations

from pathlib import Path

import pytest
from tiny_fixtures import TINY_POLICIES, needs_model_env

from conflictbench.testing.plugin_tests import play_pinned_actions
from conflictbench_pi0.checkpoints import fingerprint
from conflictbench_pi0.client import PiConfig, load

GOLDEN = Path(__file__).parent / "golden"


@needs_model_env
@pytest.mark.parametrize("name", TINY_POLICIES)
def test_a_tiny_checkpoint_plays_its_pinned_actions(name, tiny_checkpoints, tiny_env, monkeypatch):
    for key, value in tiny_env.items():
        monkeypatch.setenv(key, value)
    checkpoint = tiny_checkpoints[name]
    policy = load(name, PiConfig(checkpoint=str(checkpoint), device="cpu", max_batch=1))
    play_pinned_actions(policy, GOLDEN / f"actions-{name}.npz", fingerprint(checkpoint))
