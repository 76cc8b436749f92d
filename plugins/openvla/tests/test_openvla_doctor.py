"""``conflictbench doctor model=openvla|openvla-oft model.server=http://...``: one request over upstream's REST
protocol to servers that behave as its deploy.py (real FastAPI processes on 127.0.0.1)."""

from __future__ import annotations

import pytest
from deploy_standin import start_standin

import conflictbench
from conflictbench.doctor.models import model_checks


@pytest.mark.parametrize("model, kind, shape", [("openvla", "openvla", "(7,)"), ("openvla-oft", "oft", "(8, 7)")])
def test_a_running_deploy_server_answers_one_request_in_the_native_protocol(tmp_path, model, kind, shape):
    server, url = start_standin(tmp_path, kind)
    try:
        checks = model_checks([f"model={model}", f"model.server={url}", "model.checkpoint=stand-in"],
                              conflictbench.plugins())  # fmt: skip
    finally:
        server.stop()
    said = {c.name: c for c in checks}
    assert all(c.passed for c in checks), checks
    assert f"native protocol: an action of shape {shape}" in said["request"].text
