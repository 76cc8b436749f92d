"""``conflictbench doctor model=gr00t model.server=tcp://...``: one request over ZeroMQ to a server that behaves as
NVIDIA's (a real process on 127.0.0.1), and a server that never answers named in one failed line."""

from __future__ import annotations

from gr00t_standin import start_standin

import conflictbench
from conflictbench.doctor.models import model_checks


def test_a_running_gr00t_server_answers_one_request_in_the_native_protocol(tmp_path):
    server, url = start_standin(tmp_path)
    try:
        argv = ["model=gr00t", f"model.server={url}", "model.checkpoint=stand-in"]
        checks = model_checks(argv, conflictbench.plugins())
    finally:
        server.stop()
    said = {c.name: c for c in checks}
    assert all(c.passed for c in checks), checks
    assert "native protocol: an action of shape (8, 7)" in said["request"].text  # GR00T's client runs 8 of 16
    assert "does not say what it runs" in said["versions"].text  # NVIDIA's server reports no stack


def test_a_gr00t_server_that_is_gone_fails_the_load_line_with_its_url(tmp_path):
    server, url = start_standin(tmp_path)
    server.stop()
    argv = ["model=gr00t", f"model.server={url}", "model.checkpoint=stand-in", "model.connect_retries=0",
            "model.connect_timeout_s=1"]  # fmt: skip
    checks = model_checks(argv, conflictbench.plugins())
    assert [c.name for c in checks] == ["plugin", "load"] and not checks[-1].passed and url in checks[-1].text
