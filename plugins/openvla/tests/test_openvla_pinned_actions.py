"""Pinned actions, bit for bit, so that a refactor of the client, the transport, the server or the backend cannot
change one: ``openvla`` with the tiny checkpoint behind our server (``model.checkpoint=DIR``), ``openvla-oft``
against the deploy.py stand-in (our server hosts OpenVLA only)."""

from __future__ import annotations

from pathlib import Path

from deploy_standin import start_standin
from openvla_model_env import OPENVLA, needs_model_env

from conflictbench.testing import check_pinned_actions
from conflictbench.testing.plugin_tests import play_pinned_actions
from conflictbench_openvla.checkpoints import fingerprint
from conflictbench_openvla.client import OftConfig, OpenVlaConfig, load

GOLDEN = Path(__file__).parent / "golden"


@needs_model_env
def test_the_tiny_openvla_checkpoint_plays_its_pinned_actions(tiny_checkpoint, monkeypatch):
    OPENVLA.use(monkeypatch, tiny_checkpoint)
    policy = load("openvla", OpenVlaConfig(checkpoint=str(tiny_checkpoint), device="cpu", max_batch=1))
    play_pinned_actions(policy, GOLDEN / "actions-openvla.npz", fingerprint(tiny_checkpoint))


def test_openvla_oft_against_the_deploy_standin_plays_its_pinned_actions(tmp_path):
    server, url = start_standin(tmp_path, "oft")
    try:
        policy = load("openvla-oft", OftConfig(server=url, checkpoint="stand-in", connect_retries=0))
        try:
            check_pinned_actions(policy, GOLDEN / "actions-openvla-oft.npz", "deploy_standin_server.py oft")
        finally:
            policy.close()
    finally:
        server.stop()
