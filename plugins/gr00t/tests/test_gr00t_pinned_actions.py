"""The tiny GR00T checkpoint, served as ``model.checkpoint=DIR`` serves it, plays the actions pinned in
``golden/`` bit for bit: a refactor of the client, the transport, the server or the backend must not change one."""

from __future__ import annotations

from pathlib import Path

from groot_model_env import GR00T, needs_model_env

from conflictbench.testing.plugin_tests import play_pinned_actions
from conflictbench_gr00t.checkpoints import fingerprint
from conflictbench_gr00t.client import Gr00tConfig, load

GOLDEN = Path(__file__).parent / "golden"


@needs_model_env
def test_the_tiny_checkpoint_plays_its_pinned_actions(tiny_groot_checkpoint, monkeypatch):
    GR00T.use(monkeypatch, tiny_groot_checkpoint)
    policy = load("gr00t", Gr00tConfig(checkpoint=str(tiny_groot_checkpoint), device="cpu", max_batch=1))
    play_pinned_actions(policy, GOLDEN / "actions-gr00t.npz", fingerprint(tiny_groot_checkpoint))
