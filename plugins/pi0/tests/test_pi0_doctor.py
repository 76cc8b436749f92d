"""``conflictbench doctor model=pi05 ...``: the model's lines against openpi's own server (a real process on
127.0.0.1) and, in the model environment, against a server the doctor starts for a tiny checkpoint."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from test_pi0_client import start_openpi_server
from tiny_fixtures import needs_model_env

import conflictbench
from conflictbench.core import UserError
from conflictbench.doctor.models import model_checks

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="module")
def plugins():
    return conflictbench.plugins()


def lines(checks) -> dict[str, tuple[bool, str]]:
    return {c.name: (c.passed, c.text) for c in checks}


def test_a_running_openpi_server_answers_one_request_in_the_native_protocol(tmp_path, plugins):
    server, url = start_openpi_server(tmp_path)
    try:
        said = lines(model_checks(["model=pi05", f"model.server={url}", "model.checkpoint=stand-in"], plugins))
    finally:
        server.stop()
    assert said["load"][0] and url in said["load"][1]
    assert said["request"] == (True, said["request"][1]) and "native protocol" in said["request"][1]
    assert "shape (5, 7)" in said["request"][1]  # pi0.5's chunk of ten, the five that openpi's client executes
    assert said["versions"] == (True, "the server does not say what it runs (a server of conflictbench-serve does)")


def test_a_server_that_is_gone_is_one_failed_line_naming_its_url(tmp_path, plugins):
    server, url = start_openpi_server(tmp_path)
    server.stop()
    argv = ["model=pi05", f"model.server={url}", "model.checkpoint=stand-in", "model.connect_retries=0"]
    checks = model_checks(argv, plugins)
    assert [c.name for c in checks] == ["plugin", "load"] and not checks[-1].passed
    assert url in checks[-1].text


def test_a_missing_model_environment_names_the_set_up_command(tmp_path, plugins):
    (tmp_path / "config.json").write_text('{"type": "pi05"}')  # a pi0.5 checkpoint, as far as a fast check sees
    (tmp_path / "model.safetensors").write_bytes(b"")
    argv = ["model=pi05", f"model.checkpoint={tmp_path}", f"model.python={tmp_path / 'no-python'}"]
    checks = lines(model_checks(argv, plugins))
    passed, text = checks.get("load", (None, ""))
    assert passed is False, checks
    assert "scripts/setup.sh --models pi0" in text


def test_the_doctor_takes_only_one_models_overrides(plugins):
    for argv in (["model=pi05,pi0"], ["run.workers=2", "model=pi05"], ["model=pi05", "model.chekpoint=x"]):
        with pytest.raises(UserError):
            model_checks(argv, plugins)


@needs_model_env
@pytest.mark.model_env
def test_a_tiny_checkpoint_gets_a_server_that_answers_and_says_its_stack(tiny_checkpoints, tiny_env, monkeypatch,
                                                                           plugins):  # fmt: skip
    from server_fixtures import model_process_env

    for name, value in model_process_env(tiny_env).items():
        monkeypatch.setenv(name, value)
    argv = ["model=pi05", f"model.checkpoint={tiny_checkpoints['pi05']}", "model.device=cpu", "model.max_batch=1"]
    said = lines(model_checks(argv, plugins))
    assert all(passed for passed, _ in said.values()), said
    assert said["server"][1].startswith("started (log: ")
    assert "native protocol" in said["request"][1] and "shape (5, 7)" in said["request"][1]
    assert said["versions"][1].startswith("device cpu; torch ") and "lerobot" in said["versions"][1]
