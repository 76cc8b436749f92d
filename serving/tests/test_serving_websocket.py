"""The websocket framing and the serve command on their own, with a real server on 127.0.0.1."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import threading
import urllib.request
from contextlib import contextmanager
from pathlib import Path

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


def _refuse(checkpoint, policy: str, naming: str) -> None:
    raise CheckpointError(f"{checkpoint} is no {policy} checkpoint (named {naming}{policy})")


TOY = command.ServedModel(
    environment="toy",
    policies=("toy",),
    protocol="a test protocol",
    check=_refuse,
    backend=lambda checkpoint, device: None,
    server=lambda *args, **kwargs: None,
)


def _serve_command(argv: list[str]) -> int:
    args = command.build_plugin_parser("cb-test", TOY).parse_args(argv)
    return command.serve_command("cb-test", TOY, args)


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--max-batch", "0"], "--max-batch must be at least 1, got 0"),
        (["--device", "tpu"], "--device must be cpu, cuda, cuda:N or auto, got 'tpu'"),
        (["--threads", "0"], "--threads must be at least 1, got 0"),
        ([], "ckpt is no toy checkpoint (named --policy toy)"),
    ],
)
def test_serve_command_user_errors_are_one_line_and_exit_2(capsys, extra, fragment):
    assert _serve_command(["serve", "--policy", "toy", "--checkpoint", "ckpt", *extra]) == 2
    err = capsys.readouterr().err
    assert err == f"cb-test: {err.removeprefix('cb-test: ')}" and err.count("\n") == 1 and fragment in err


def test_argument_errors_are_one_line():
    done = subprocess.run(
        [sys.executable, "-c", "from conflictbench_serving import command; from test_serving_websocket import TOY; "
         "command.build_plugin_parser('cb-test', TOY).parse_args(['serve', '--policy', 'x'])"],
        capture_output=True, text=True, cwd=Path(__file__).parent,
    )  # fmt: skip
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "invalid choice: 'x'" in done.stderr


TOY_PLUGIN = """
from conflictbench_serving.command import ServedModel
from conflictbench_serving.checkpoints import CheckpointError

def check(folder, policy, naming):
    if not folder.is_dir():
        raise CheckpointError(f"no checkpoint folder at {folder} (for {naming}{policy})")

SERVED = ServedModel(environment="toy", policies=("toy", "toy-2"), protocol="toy's protocol", check=check,
                     backend="toy_served:load", server="toy_served:serve")
"""


def _serve(tmp_path: Path, *argv: str) -> subprocess.CompletedProcess:
    """``python -m conflictbench_serving *argv`` with a toy plugin installed as a real distribution (its entry point
    in the ``conflictbench_serving`` group) and a broken one beside it."""
    site = tmp_path / "site"
    (site / "toy_served-1.0.dist-info").mkdir(parents=True, exist_ok=True)
    (site / "toy_served.py").write_text(TOY_PLUGIN)
    (site / "toy_served-1.0.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: toy-served\nVersion: 1.0\n"
    )
    (site / "toy_served-1.0.dist-info" / "entry_points.txt").write_text(
        "[conflictbench_serving]\ntoy = toy_served:SERVED\nbroken = toy_served_missing:SERVED\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "conflictbench_serving", *argv], capture_output=True, text=True,
                          env=env, timeout=60)  # fmt: skip


def test_conflictbench_serve_finds_what_a_plugin_serves_through_its_entry_point(tmp_path):
    listed = _serve(tmp_path, "--list")
    assert listed.returncode == 0
    assert "toy            toy        toy's protocol" in listed.stdout.splitlines()
    assert "toy-2          toy        toy's protocol" in listed.stdout.splitlines()
    assert "the plugin broken failed to load: ModuleNotFoundError" in listed.stderr

    # The plugin's own check runs, before torch is imported, naming the policy the way this command does.
    done = _serve(tmp_path, "toy-2", "--checkpoint", str(tmp_path / "missing"))
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert (
        done.stderr
        == f"conflictbench-serve: no checkpoint folder at {tmp_path / 'missing'} (for conflictbench-serve toy-2)\n"
    )


SERVE_MISTAKES = {
    "unknown policy": (["nope", "--checkpoint", "x"], "no installed plugin serves 'nope' (installed: "),
    "no policy": (["--checkpoint", "x"], "the following arguments are required: POLICY"),
    "no checkpoint": (["toy"], "the following arguments are required: --checkpoint"),
}


@pytest.mark.parametrize("mistake", SERVE_MISTAKES)
def test_conflictbench_serve_mistakes_are_one_line(tmp_path, mistake):
    argv, message = SERVE_MISTAKES[mistake]
    done = _serve(tmp_path, *argv)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
    if argv[0] == "nope":
        assert "toy, toy-2" in done.stderr and "broken (ModuleNotFoundError" in done.stderr


def test_it_imports_neither_conflictbench_nor_torch():
    modules = "batching, checkpoints, command, loop, msgpack_numpy, rest, websocket, zeromq"
    done = subprocess.run(
        [sys.executable, "-c", f"import sys; from conflictbench_serving import {modules}; "
         "print(sorted(m for m in sys.modules if m.split('.')[0] in ('conflictbench', 'torch')))"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert done.stdout.strip() == "[]"
