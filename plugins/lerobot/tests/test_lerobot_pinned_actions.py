"""Each tiny checkpoint, served as ``model.checkpoint=DIR`` serves it, plays the actions pinned in ``golden/`` bit for
bit: a refactor of the client, the transport, the server or the backend must not change one. Two actions a chunk
(``model.n_action_steps=2``), so the pinned steps refill every queue three times and Diffusion's and Multi-task
DiT's observation histories enter."""

from __future__ import annotations

from pathlib import Path

import pytest
from lerobot_fixtures import LEROBOT, TINY_TYPES, needs_model_env

from conflictbench.testing.plugin_tests import play_pinned_actions
from conflictbench_lerobot.checkpoints import fingerprint
from conflictbench_lerobot.client import LeRobotConfig, load

GOLDEN = Path(__file__).parent / "golden"


@needs_model_env
@pytest.mark.parametrize("policy_type", TINY_TYPES)
def test_each_tiny_checkpoint_plays_its_pinned_actions(policy_type, tiny_lerobot_checkpoints, monkeypatch):
    checkpoint = tiny_lerobot_checkpoints[policy_type]
    LEROBOT.use(monkeypatch, checkpoint)
    policy = load("lerobot", LeRobotConfig(checkpoint=str(checkpoint), device="cpu", n_action_steps=2))
    play_pinned_actions(policy, GOLDEN / f"actions-{policy_type}.npz", fingerprint(checkpoint))
