"""The tiny UniVLA checkpoint (the stand-in checkout's code), served as ``model.checkpoint=DIR`` serves it, plays
the actions pinned in ``golden/`` bit for bit (its latent history and ensembling included): a refactor of the
client, the transport, the server or the backend must not change one."""

from __future__ import annotations

from pathlib import Path

from univla_model_env import UNIVLA, needs_model_env

from conflictbench.testing.plugin_tests import play_pinned_actions
from conflictbench_univla.checkpoints import fingerprint
from conflictbench_univla.client import UnivlaConfig, load

GOLDEN = Path(__file__).parent / "golden"


@needs_model_env
def test_the_tiny_checkpoint_plays_its_pinned_actions(tiny_checkpoint, monkeypatch):
    UNIVLA.use(monkeypatch)
    policy = load("univla", UnivlaConfig(checkpoint=str(tiny_checkpoint), device="cpu", max_batch=1))
    play_pinned_actions(policy, GOLDEN / "actions-univla.npz", fingerprint(tiny_checkpoint))
