"""The websocket framing and the serve command on their own, with a real server on 127.0.0.1."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import threading
import urllib.request
from contextlib import contextmanager

import numpy as np
import pytest
from websockets.exceptions import ConnectionClosedError
from websockets.sync.client import connect

from conflictbench_serving import command
from conflictbench_serving.batching import Batcher
from conflictbench_serving.checkpoints import CheckpointError, fingerprint
from conflictbench_serving.msgpack_numpy import packb, unpackb
from conflictbench_serving.websocket import FatalRequest, WebsocketPolicyServer


async def _double(frame: bytes | str, session: dict) -> bytes:
    """Answers a packed array with it doubled (through the batcher); a text frame ends the connection."""
    if isinstance(frame, str):
        raise FatalRequest(f"no text please: {frame}")
    session["count"] = session.get("count", 0) + 1
    answer, timing = await SERVER.batcher.submit(unpackb(frame))
    return packb({"answer": answer, "count": session["count"], "batch_size": timing["batch_size"]})


SERVER = WebsocketPolicyServer(
    _double, packb({"hosted": "doubler"}), Batcher(lambda rows: [2 * r for r in rows], 2, True)
)


@contextmanager
def running(server: WebsocketPolicyServer):
    bound: dict = {}
    ready = threading.Event()

    def main() -> None:
        async def go() -> None:
            bound["stop"] = asyncio.Event()
            bound["loop"] = asyncio.get_running_loop()
            await server.run("127.0.0.1", 0, bound["stop"], lambda host, port: (bound.update(port=port), ready.set()))

        asyncio.run(go())

    thread = threading.Thread(target=main, daemon=True)
    thread.start()
    assert ready.wait(10), "the server did not bind"
    try:
        yield bound["port"]
    finally:
        bound["loop"].call_soon_threadsafe(bound["stop"].set)
        thread.join(10)


def test_metadata_first_then_one_reply_per_request_and_fatal_requests_close_only_their_connection():
    with running(SERVER) as port:
        url = f"ws://127.0.0.1:{port}"
        with connect(url, proxy=None) as healthy, connect(url, proxy=None) as offender:
            assert unpackb(healthy.recv()) == {"hosted": "doubler"}
            offender.recv()
            offender.send("hello")
            assert offender.recv() == "no text please: hello"
            with pytest.raises(ConnectionClosedError) as closed:  # then code 1011
                offender.recv()
            assert closed.value.rcvd.code == 1011
            for count in (1, 2):
                healthy.send(packb(np.arange(3.0)))
                reply = unpackb(healthy.recv())
                np.testing.assert_array_equal(reply["answer"], [0.0, 2.0, 4.0])
                assert reply["count"] == count and reply["batch_size"] == 1
        assert urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=5).read() == b"OK\n"


def test_the_codec_is_openpis_byte_for_byte():
    openpi = pytest.importorskip("openpi_client.msgpack_numpy")
    value = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "s": np.int64(7), "t": "text", "l": [1, 2]}
    assert packb(value) == openpi.Packer().pack(value)
    back = openpi.unpackb(packb(value))
    np.testing.assert_array_equal(back["a"], value["a"])
    assert back["s"] == 7 and back["s"].dtype == np.int64
    with pytest.raises(TypeError, match="cannot be sent"):
        packb(np.zeros(2, dtype=complex))


def test_the_fingerprint_follows_content_not_path(tmp_path):
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    for folder in ("a", "b"):
        (tmp_path / folder / "w.bin").write_bytes(b"weights")
    same = fingerprint([tmp_path / "a" / "w.bin"]) == fingerprint([tmp_path / "b" / "w.bin"])
    (tmp_path / "b" / "w.bin").write_bytes(b"weightz")
    assert same and fingerprint([tmp_path / "a" / "w.bin"]) != fingerprint([tmp_path / "b" / "w.bin"])


def _serve_command(argv: list[str], check=None, load=None, serve=None) -> int:
    parser = command.build_parser("cb-test", "test", ["toy"], "a test protocol")
    args = parser.parse_args(argv)

    def refuse(checkpoint, policy):
        raise CheckpointError(f"{checkpoint} is no {policy} checkpoint")

    return command.serve_command("cb-test", "toy", args, check or refuse, load or (lambda c, d: None), serve or None)


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--max-batch", "0"], "--max-batch must be at least 1, got 0"),
        (["--device", "tpu"], "--device must be cpu, cuda, cuda:N or auto, got 'tpu'"),
        (["--threads", "0"], "--threads must be at least 1, got 0"),
        ([], "ckpt is no toy checkpoint"),
    ],
)
def test_serve_command_user_errors_are_one_line_and_exit_2(capsys, extra, fragment):
    assert _serve_command(["serve", "--policy", "toy", "--checkpoint", "ckpt", *extra]) == 2
    err = capsys.readouterr().err
    assert err == f"cb-test: {err.removeprefix('cb-test: ')}" and err.count("\n") == 1 and fragment in err


def test_argument_errors_are_one_line():
    done = subprocess.run(
        [sys.executable, "-c", "from conflictbench_serving import command; "
         "command.build_parser('cb-test', 'd', ['toy'], 'p').parse_args(['serve', '--policy', 'x'])"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "invalid choice: 'x'" in done.stderr


def test_it_imports_neither_conflictbench_nor_torch():
    modules = "batching, checkpoints, command, msgpack_numpy, websocket"
    done = subprocess.run(
        [sys.executable, "-c", f"import sys; from conflictbench_serving import {modules}; "
         "print(sorted(m for m in sys.modules if m.split('.')[0] in ('conflictbench', 'torch')))"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert done.stdout.strip() == "[]"
