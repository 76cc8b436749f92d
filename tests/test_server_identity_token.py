"""The token of a running server (``model.server=``, #42 section 3): read from ``CONFLICTBENCH_SERVER_TOKEN`` or
``model.token_file``, never from the run's config; sent on every request, the connection's ping and metadata
included; a refused one stops the run in one line, at once. Servers are conflictbench-serving's own, real, on
127.0.0.1."""

from __future__ import annotations

import dataclasses
import http.client
import http.server
import threading

import pytest

from conflictbench import HostedConfig, HostedPolicy, PolicyClient, ServerUnavailable, Transport, UserError
from conflictbench.testing.plugin_tests import server_in_thread

SECRET = "run-token-0123456789abcdefghijklmnop"
TOKEN_VARIABLE = "CONFLICTBENCH_SERVER_TOKEN"


def test_the_token_comes_from_token_file_else_the_environment_and_counts_for_no_identity(tmp_path, monkeypatch):
    monkeypatch.delenv(TOKEN_VARIABLE, raising=False)
    assert HostedPolicy.configured_token(HostedConfig()) is None
    monkeypatch.setenv(TOKEN_VARIABLE, SECRET)
    assert HostedPolicy.configured_token(HostedConfig()) == SECRET
    token_file = tmp_path / "token"
    token_file.write_text("from-the-file\n")
    assert HostedPolicy.configured_token(HostedConfig(token_file=str(token_file))) == "from-the-file"
    assert "token_file" in HostedConfig.identity_exempt  # where a token is kept is no part of what a model is
    assert all(SECRET not in str(value) for value in dataclasses.asdict(HostedConfig()).values())  # nor in its config


@pytest.mark.parametrize("content, words", [(None, "cannot read it (FileNotFoundError)"), ("a b\n", "one word")])
def test_a_token_file_that_cannot_serve_is_one_line(tmp_path, content, words):
    token_file = tmp_path / "token"
    if content is not None:
        token_file.write_text(content)
    with pytest.raises(UserError) as refused:
        HostedPolicy.configured_token(HostedConfig(token_file=str(token_file)))
    assert str(refused.value) == f"model.token_file={token_file}: " + (
        "cannot read it (FileNotFoundError)" if content is None else "the token must be one word, on one line"
    )
    assert words in str(refused.value) and "a b" not in str(refused.value)


def test_a_token_file_other_users_can_read_is_warned_of_as_the_server_does(tmp_path, capsys):
    token_file = tmp_path / "token"
    token_file.write_text("  the-token \n")  # the same rules as conflictbench-serve --token-file: one word, trimmed
    token_file.chmod(0o600)
    assert HostedPolicy.configured_token(HostedConfig(token_file=str(token_file))) == "the-token"
    assert capsys.readouterr().err == ""
    token_file.chmod(0o644)
    assert HostedPolicy.configured_token(HostedConfig(token_file=str(token_file))) == "the-token"
    warned = f"conflictbench: warning: model.token_file={token_file} is readable by other users (chmod 600 it)\n"
    assert capsys.readouterr().err == warned


# ---- GR00T's ZeroMQ client against our ZeroMQ server with a token: the ping and the metadata carry it -----------


@pytest.fixture
def zeromq_server():
    pytest.importorskip("zmq")
    from conflictbench_serving.batching import Batcher
    from conflictbench_serving.guard import Guard
    from conflictbench_serving.zeromq import ZmqPolicyServer

    def infer(rows):
        return rows

    from conflictbench_gr00t.checkpoints import POLICY_TYPE

    metadata = {"policy_type": POLICY_TYPE, "checkpoint_fingerprint": "f" * 12}
    make = lambda: ZmqPolicyServer(Batcher(infer, 1, True, name="t"), metadata, guard=Guard(token=SECRET))  # noqa: E731
    with server_in_thread(make) as (_server, port):
        yield f"tcp://127.0.0.1:{port}"


def gr00t(url: str, **settings):
    from conflictbench_gr00t.client import Gr00tConfig, load

    return load("gr00t", Gr00tConfig(server=url, checkpoint="gr00t-libero", connect_retries=0, **settings))


def test_gr00t_sends_the_environments_token_on_its_ping_and_metadata(zeromq_server, monkeypatch, capsys):
    monkeypatch.setenv(TOKEN_VARIABLE, SECRET)
    policy = gr00t(zeromq_server)
    try:
        assert policy.identity["checkpoint"] == "f" * 12  # it read the metadata: the server admitted it
    finally:
        policy.close()
    monkeypatch.setenv(TOKEN_VARIABLE, "not-the-token")
    # model.api_token, as before: the same token, deprecated (Hydra saves it with the run's config, ps shows it)
    with pytest.warns(DeprecationWarning, match="model.api_token .*CONFLICTBENCH_SERVER_TOKEN or model.token_file"):
        policy = gr00t(zeromq_server, api_token=SECRET)
    policy.close()
    warned = [line for line in capsys.readouterr().err.splitlines() if "api_token" in line]
    assert len(warned) == 1 and "warning: model.api_token is deprecated" in warned[0] and SECRET not in warned[0]


@pytest.mark.parametrize("token", [None, "not-the-token"], ids=["none", "wrong"])
def test_gr00t_without_the_servers_token_is_refused_in_one_line(zeromq_server, monkeypatch, token):
    monkeypatch.delenv(TOKEN_VARIABLE, raising=False)
    if token:
        monkeypatch.setenv(TOKEN_VARIABLE, token)
    with pytest.raises(ServerUnavailable, match="Unauthorized") as refused:
        gr00t(zeromq_server, connect_timeout_s=2.0)
    assert "\n" not in str(refused.value) and SECRET not in str(refused.value)


# ---- a transport that says the server refused its token: the client does not ask again ------------------------


class _Unauthorized(http.server.BaseHTTPRequestHandler):
    asked = 0

    def do_GET(self):
        type(self).asked += 1
        self.send_response(401)
        self.send_header("Content-Length", "0")
        self.end_headers()

    def log_message(self, *args):
        pass


class TokenChecked(Transport):
    """What a protocol's transport does on HTTP 401 (the websocket upgrade's, REST's): PermissionError."""

    def connect(self, timeout: float) -> None:
        connection = http.client.HTTPConnection("127.0.0.1", int(self.url.rsplit(":", 1)[1]), timeout=timeout)
        try:
            connection.request("GET", "/")
            status = connection.getresponse().status
        finally:
            connection.close()
        if status == 401:
            raise PermissionError("the server answered HTTP 401 Unauthorized")

    def exchange(self, request, timeout):
        raise AssertionError("never reached")


def test_a_refused_token_stops_at_once_with_where_the_token_comes_from():
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Unauthorized)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        client = PolicyClient(f"http://127.0.0.1:{server.server_address[1]}", TokenChecked, connect_retries=5)
        _Unauthorized.asked = 0
        with pytest.raises(ServerUnavailable) as refused:
            client.open()
        assert _Unauthorized.asked == 1  # not 5 retries (15 s of backoff) with the same token
        assert "HTTP 401" in str(refused.value) and "set CONFLICTBENCH_SERVER_TOKEN, or model.token_file" in str(
            refused.value
        )
        assert "\n" not in str(refused.value)
    finally:
        server.shutdown()
        server.server_close()
