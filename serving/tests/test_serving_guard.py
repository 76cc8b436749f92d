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
    before = guard.current()
    try:
        configured = guard.configure(token="t", max_connections=1000)
        assert guard.current() is configured
        assert configured.max_queued >= 1000 and configured.token == "t"
    finally:
        guard._current = before
