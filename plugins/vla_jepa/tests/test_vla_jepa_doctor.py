"""``conflictbench doctor model=vla-jepa model.server=ws://...``: one request over starVLA's websocket protocol to a
server that behaves as upstream's (a real process on 127.0.0.1)."""

from __future__ import annotations

from jepa_standin import start_standin, write_run

import conflictbench
from conflictbench.doctor.models import model_checks


def test_a_running_vla_jepa_server_answers_one_request_in_the_native_protocol(tmp_path):
    server, url = start_standin(tmp_path)
    stats = write_run(tmp_path / "run", window=7)
    try:
        argv = ["model=vla-jepa", f"model.server={url}", "model.checkpoint=stand-in", f"model.stats={stats}"]
        checks = model_checks(argv, conflictbench.plugins())
    finally:
        server.stop()
    said = {c.name: c for c in checks}
    assert all(c.passed for c in checks), checks
    assert "native protocol: an action of shape (8, 7)" in said["request"].text  # the stand-in server's chunk of 8
