"""``conflictbench-serve``'s token and bounds (#42, section 3): the token from the environment or a file, never the
command line, never printed; the bounds as options; the guard every server of ours then uses; and ``--ready-fd``,
where a run that starts the server reads the port it bound."""

from __future__ import annotations

import dataclasses
import os
import signal
import sys

import numpy as np
import pytest

from conflictbench_serving import command, guard

SECRET = "s3cret-token-of-this-test-0123456789"


@pytest.fixture(autouse=True)
def kept():
    """serve_command sets SIGTERM's handler and the process-wide guard: both put back after each test."""
    handler, before = signal.getsignal(signal.SIGTERM), guard.current()
    yield
    signal.signal(signal.SIGTERM, handler)
    guard.configure(**dataclasses.asdict(before))


@pytest.fixture(autouse=True)
def in_a_model_environment(monkeypatch):
    monkeypatch.setitem(sys.modules, "conflictbench", None)  # not importable, as in a model environment
    monkeypatch.setitem(sys.modules, "torch", None)  # a backend of numpy alone: served without it


@pytest.fixture
def no_token(monkeypatch):
    monkeypatch.delenv(guard.TOKEN_VARIABLE, raising=False)


class Backend:
    def __init__(self, checkpoint, device: str) -> None:
        self.metadata = {"policy_type": "toy"}

    def infer_batch(self, rows):
        return [np.asarray(row) for row in rows]


def serve(tmp_path, *extra: str, host: str = "127.0.0.1") -> tuple[int, dict]:
    """``conflictbench-serve toy --checkpoint TMP ...``: the exit code, and the guard and environment the server saw."""
    seen: dict = {}

    def server(loaded, host, port, max_batch, on_ready):
        seen["guard"], seen["environment"] = guard.current(), dict(os.environ)
        on_ready(host, 4321)

    model = command.ServedModel(
        environment="toy", policies=("toy",), protocol="a test protocol", check=lambda *args: None,
        backend=Backend, server=server,
    )  # fmt: skip
    argv = ["toy", "--checkpoint", str(tmp_path), "--host", host, "--port", "0", *extra]
    return command.serve_command("cb-test", model, command.build_parser().parse_args(argv)), seen


def test_the_token_in_the_environment_guards_the_server_and_leaves_the_environment(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(guard.TOKEN_VARIABLE, SECRET)
    code, seen = serve(tmp_path)
    assert code == 0 and seen["guard"].token == SECRET
    assert guard.TOKEN_VARIABLE not in seen["environment"]  # the model's code and its processes never see it
    assert SECRET not in capsys.readouterr().err and SECRET not in repr(seen["guard"])


def test_a_token_file_guards_the_server_one_readable_by_others_is_warned_of(tmp_path, capsys, no_token):
    token_file = tmp_path / "token"
    token_file.write_text(SECRET + "\n")
    token_file.chmod(0o600)
    code, seen = serve(tmp_path, "--token-file", str(token_file))
    assert code == 0 and seen["guard"].token == SECRET and "warning" not in capsys.readouterr().err
    token_file.chmod(0o644)
    code, seen = serve(tmp_path, "--token-file", str(token_file))
    err = capsys.readouterr().err
    assert code == 0 and f"--token-file {token_file} is readable by other users (chmod 600 it)" in err
    assert SECRET not in err


@pytest.mark.parametrize(
    "content, words", [(None, "cannot read it (FileNotFoundError)"), ("", "must be one word"), ("a b", "one word")]
)
def test_a_token_file_that_cannot_serve_is_one_line_and_exit_code_2(tmp_path, capsys, no_token, content, words):
    token_file = tmp_path / "token"
    if content is not None:
        token_file.write_text(content)
    code, seen = serve(tmp_path, "--token-file", str(token_file))
    err = capsys.readouterr().err
    assert code == command.USER_ERROR and seen == {} and err.count("\n") == 1 and words in err, err


def test_there_is_no_token_option_for_the_command_line_ps_shows_every_user(tmp_path, capsys):
    with pytest.raises(SystemExit) as refused:
        command.build_parser().parse_args(["toy", "--checkpoint", str(tmp_path), "--token", SECRET])
    assert refused.value.code == command.USER_ERROR and "unrecognized arguments: --token" in capsys.readouterr().err


def test_the_bounds_are_options_mapped_to_the_guard_and_bad_ones_are_one_line(tmp_path, capsys, no_token):
    code, seen = serve(tmp_path, "--max-message-mib", "1.5", "--max-connections", "600")
    assert code == 0 and seen["guard"].token is None
    assert seen["guard"].max_message_bytes == 3 * 2**19 and seen["guard"].max_connections == 600
    assert seen["guard"].max_queued >= 600  # every connection may have a request waiting
    capsys.readouterr()
    for option, value in (("--max-message-mib", "0"), ("--max-connections", "0")):
        code, seen = serve(tmp_path, option, value)
        err = capsys.readouterr().err
        assert code == command.USER_ERROR and seen == {} and err.startswith(f"cb-test: {option} must be"), err


def test_a_server_open_to_the_network_without_a_token_says_so(tmp_path, capsys, no_token):
    assert serve(tmp_path, host="0.0.0.0")[0] == 0
    assert "warning: no token: anyone who reaches 0.0.0.0:4321 may use this model" in capsys.readouterr().err
    assert serve(tmp_path)[0] == 0  # this machine's users alone: said nowhere, as before
    assert "warning" not in capsys.readouterr().err


def test_ready_fd_gets_host_and_port_once_listening_and_closes(tmp_path, no_token):
    reading, writing = os.pipe()
    try:
        code, _seen = serve(tmp_path, "--ready-fd", str(writing))
        assert code == 0
        assert os.read(reading, 100) == b"127.0.0.1 4321\n"
        assert os.read(reading, 100) == b""  # closed: every writer gone
    finally:
        os.close(reading)


def test_ready_fd_that_is_not_open_is_one_line_and_exit_code_2(tmp_path, capsys, no_token):
    reading, writing = os.pipe()
    os.close(reading)
    os.close(writing)
    code, seen = serve(tmp_path, "--ready-fd", str(writing))
    err = capsys.readouterr().err
    assert code == command.USER_ERROR and seen == {} and f"--ready-fd {writing}: no open pipe there" in err, err


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_help_names_the_environment_variable_not_a_value(capsys):
    with pytest.raises(SystemExit):
        command.build_parser().parse_args(["--help"])
    out = capsys.readouterr().out
    assert guard.TOKEN_VARIABLE in out and "--token-file" in out and "--ready-fd" in out
