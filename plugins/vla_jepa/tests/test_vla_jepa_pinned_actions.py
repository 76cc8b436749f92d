"""The tiny VLA-JEPA checkpoint, served as ``model.checkpoint=DIR`` serves it, plays the actions pinned in
``golden/`` bit for bit: a refactor of the client, the transport, the server or the backend must not change one."""

from __future__ import annotations

from pathlib import Path

from jepa_model_env import VLA_JEPA, needs_model_env

from conflictbench.testing.plugin_tests import play_pinned_actions
from conflictbench_vla_jepa.checkpoints import fingerprint
from conflictbench_vla_jepa.client import VlaJepaConfig, load

GOLDEN = Path(__file__).parent / "golden"


@needs_model_env
def test_the_tiny_checkpoint_plays_its_pinned_actions(tiny_checkpoint, monkeypatch):
    VLA_JEPA.use(monkeypatch, tiny_checkpoint)
    policy = load("vla-jepa", VlaJepaConfig(checkpoint=str(tiny_checkpoint), device="cpu", max_batch=1))
    play_pinned_actions(policy, GOLDEN / "actions-vla-jepa.npz", fingerprint(tiny_checkpoint))
