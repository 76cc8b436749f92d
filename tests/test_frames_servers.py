"""A frame from a stranger cannot crash a server: the π server (our websocket server) in its own process, on
127.0.0.1, sent the ~100-byte frame that made it exit with a segmentation fault (issue #42), answers it with a
one-line error and goes on serving other clients."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import msgpack
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

pi0 = pytest.importorskip("conflictbench_pi0.protocol")

TIMEOUT_S = 30
# The π server around a numpy stand-in (the model is not what is tested), in a process of its own: a segmentation
# fault must not take the test with it.
SERVER = textwrap.dedent(
    """
    import numpy as np
    from conflictbench_pi0.server import serve

    class StandIn:
        metadata = {"policy_type": "pi0"}

        def infer_batch(self, requests):
            return [np.full((10, 7), float(len(request["prompt"])), np.float32) for request in requests]

    serve(StandIn(), "127.0.0.1", 0, max_batch=2, on_ready=lambda host, port: print(port, flush=True))
    """
)
OBJECTS = {b"__ndarray__": True, b"data": b"\x41" * 16, b"dtype": "|O", b"shape": [2]}  # two pointers: 0x4141...
# The request's image is a list holding that array: the server's error message describes it (repr), which
# dereferences the pointers.
CRASHING_FRAME = msgpack.packb(
    {"observation/image": [OBJECTS], "observation/wrist_image": 0, "observation/state": 0, "prompt": 0}
)


def _observation() -> dict:
    image = np.zeros((224, 224, 3), np.uint8)
    return {
        "observation/image": image,
        "observation/wrist_image": image,
        "observation/state": np.zeros(8),
        "prompt": "go",
    }


@pytest.fixture
def pi_server():
    process = subprocess.Popen([sys.executable, "-c", SERVER], stdout=subprocess.PIPE, text=True)
    try:
        port = int(process.stdout.readline() or 0)
        assert port, f"the server did not start (exit code {process.poll()})"
        yield f"ws://127.0.0.1:{port}", process
    finally:
        process.terminate()
        process.wait(TIMEOUT_S)


def test_an_object_array_frame_is_answered_with_one_line_and_the_server_goes_on(pi_server):
    url, process = pi_server
    assert len(CRASHING_FRAME) < 200
    with connect(url, proxy=None, open_timeout=TIMEOUT_S) as stranger:
        stranger.recv(timeout=TIMEOUT_S)
        stranger.send(CRASHING_FRAME)
        try:
            answer = stranger.recv(timeout=TIMEOUT_S)
        except ConnectionClosed:
            answer = None
    assert isinstance(answer, str) and "\n" not in answer.strip()
    assert "dtype '|O'" in answer and "refused" in answer
    # Alive is proved by an answer to another client, not by poll() at once (a dying server may not have exited yet)
    with connect(url, proxy=None, open_timeout=TIMEOUT_S) as client:
        client.recv(timeout=TIMEOUT_S)
        client.send(pi0.packb(_observation()))
        reply = pi0.unpackb(client.recv(timeout=TIMEOUT_S))
    np.testing.assert_array_equal(reply["actions"], np.full((10, 7), 2.0, np.float32))
    assert process.poll() is None, f"the server died (exit code {process.poll()})"
