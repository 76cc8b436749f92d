"""The guard's settings: defaults that fit a run, values checked, the token never shown."""

import pytest

from conflictbench_serving import guard
from conflictbench_serving.guard import Guard


def test_defaults_fit_a_run_and_the_largest_request():
    default = Guard()
    assert default.max_connections >= 64  # a sensible run.workers
    assert default.max_queued >= default.max_connections
    # three 512x512 RGB cameras, base64'd by json-numpy, fit with room to spare; a 200 MiB frame does not
    assert 3 * 512 * 512 * 3 * 4 / 3 < default.max_message_bytes < 200 * 2**20
    assert default.max_message_bytes == guard.message_bytes() == 12 * 2**20


def test_bad_values_are_refused_in_one_line():
    with pytest.raises(ValueError, match="max_queued"):
        Guard(max_connections=10, max_queued=5)
    with pytest.raises(ValueError, match="max_message_bytes"):
        Guard(max_message_bytes=0)
    with pytest.raises(ValueError, match="token"):
        Guard(token="")


def test_the_token_is_checked_and_never_shown():
    guarded = Guard(token="s3cret")
    assert guarded.admits("s3cret") and not guarded.admits("s3cre") and not guarded.admits(None)
    assert Guard().admits(None)
    assert "s3cret" not in repr(guarded) and "s3cret" not in str(guarded)


def test_configure_sets_what_servers_use_and_raises_the_queue_with_the_connections():
    before = guard._current
    try:
        configured = guard.configure(token="t", max_connections=1000)
        assert guard.current() is configured
        assert configured.max_queued >= 1000 and configured.token == "t"
    finally:
        guard._current = before


def test_the_first_guard_reads_the_token_and_the_message_bound_from_the_environment(monkeypatch):
    before = guard._current
    monkeypatch.setenv(guard.TOKEN_VARIABLE, "from-env")
    monkeypatch.setenv(guard.MESSAGE_LIMIT_VARIABLE, "1000")
    try:
        guard._current = None
        assert guard.current().token == "from-env" and guard.current().max_message_bytes == 1000
        monkeypatch.setenv(guard.MESSAGE_LIMIT_VARIABLE, "lots")
        guard._current = None
        with pytest.raises(ValueError, match="CONFLICTBENCH_MAX_MESSAGE_BYTES must be a positive number"):
            guard.current()
    finally:
        guard._current = before


def test_the_authorization_header_carries_the_token_as_openpi_client_sends_its_api_key():
    header = guard.authorization("s3cret")
    assert header == {"Authorization": "Api-Key s3cret"} and guard.authorization(None) == {}
    assert Guard(token="s3cret").admits_header(header["Authorization"])
    assert not Guard(token="s3cret").admits_header("Bearer s3cret")
    assert not Guard(token="s3cret").admits_header(None) and Guard().admits_header(None)
