"""``conflictbench doctor model=univla model.server=http://...``: one request over UniVLA's REST protocol to a server
that behaves as upstream's (a real process on 127.0.0.1)."""

from __future__ import annotations

from univla_standin import start_standin

import conflictbench
from conflictbench.doctor.models import model_checks


def test_a_running_univla_server_answers_one_request_in_the_native_protocol(tmp_path):
    server, url = start_standin(tmp_path)
    try:
        checks = model_checks(["model=univla", f"model.server={url}", "model.checkpoint=stand-in"],
                              conflictbench.plugins())  # fmt: skip
    finally:
        server.stop()
    said = {c.name: c for c in checks}
    assert all(c.passed for c in checks), checks
    assert "native protocol: an action of shape (7,)" in said["request"].text  # one ensembled action per query
