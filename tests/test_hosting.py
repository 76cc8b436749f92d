"""HostedPolicy: the lifecycle every model plugin shares, with a real server process and no plugin.

The "model environment" here is this interpreter with a one-file server module on ``PYTHONPATH``: it answers
``/healthz`` and JSON ``POST`` requests with an action that says which checkpoint and batch shape it serves.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import textwrap
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from conflictbench import HostedConfig, HostedPolicy, HttpJsonTransport, Observation, ServerUnavailable, UserError
from conflictbench.sim.episode_rows import stack_pins
from conflictbench.sim.identity_change import stack_changes

SERVER_MODULE = textwrap.dedent(
    """
    import argparse, http.server, json, os, pathlib, sys

    def main():
        parser = argparse.ArgumentParser()
        parser.add_argument("command")
        for flag in ("--policy", "--checkpoint", "--host", "--device"):
            parser.add_argument(flag)
        parser.add_argument("--port", type=int)
        parser.add_argument("--max-batch", type=int)
        args = parser.parse_args()
        folder = pathlib.Path(args.checkpoint)
        if (folder / "refuse").exists():
            print(f"hosted_echo: {folder} holds weights of another model", flush=True)
            sys.exit(2)
        weight = float((folder / "weights.txt").read_text())
        lives = int((folder / "lives").read_text()) if (folder / "lives").exists() else -1

        class Handler(http.server.BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"
            def log_message(self, *a):
                pass
            def _send(self, status, payload):
                body = json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
            def do_GET(self):
                self._send(200 if self.path == "/healthz" else 404, "OK")
            def do_POST(self):
                nonlocal lives
                request = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                if lives == 0:
                    os._exit(7)  # the model process dies
                lives -= 1
                self._send(200, [weight, args.max_batch, 0.01 * request["step"], 0, 0, 0, -1])

        http.server.ThreadingHTTPServer((args.host, args.port), Handler).serve_forever()

    if __name__ == "__main__":
        main()
    """
)


@dataclass
class EchoConfig(HostedConfig):
    request_timeout_s: float = 10.0
    connect_retries: int = 1
    backoff_s: float = 0.1


# The lifecycle under test is the one every plugin uses; the echo server is found by the former path,
# HostedPolicy.server_module (kept until 0.4.0, with its warning), since it is no installed plugin.
with pytest.warns(DeprecationWarning, match=r"EchoPolicy\.server_module .*0\.4\.0"):

    class EchoPolicy(HostedPolicy):
        needs_images = False
        environment = "echo"
        server_module = "hosted_echo"
        transport = HttpJsonTransport
        url_scheme = "http"
        default_max_steps = {"libero_spatial": 7, "libero_goal": 9}

        @classmethod
        def inspect_checkpoint(cls, name, folder):
            if not (folder / "weights.txt").is_file():
                raise UserError(f"{folder} is not an echo checkpoint")
            return folder

        @classmethod
        def fingerprint(cls, folder):
            return hashlib.sha256((folder / "weights.txt").read_bytes()).hexdigest()[:12]

        def encode(self, observation):
            return {"step": observation.step}

        def decode(self, reply, observation):
            return np.asarray(reply, dtype=np.float64)


def observation(step: int) -> Observation:
    state = np.array([0.1, 0.2, 1.0, 0.0, 0.0, 0.0, 0.04, -0.04])
    return Observation(
        step=step, instruction="x", eef_pos=state[:3], eef_quat=np.array([0, 0, 0, 1.0]), gripper_qpos=state[6:],
        state=state,
    )  # fmt: skip


@pytest.fixture
def model_env(tmp_path, monkeypatch) -> Path:
    """This interpreter, with the server module importable (the started server inherits the environment)."""
    modules = tmp_path / "modules"
    modules.mkdir()
    (modules / "hosted_echo.py").write_text(SERVER_MODULE)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(modules), os.environ.get("PYTHONPATH", "")]))
    return Path(sys.executable)


def checkpoint(folder: Path, weight: float = 0.5, **files: str) -> Path:
    folder.mkdir(parents=True)
    (folder / "weights.txt").write_text(str(weight))
    for name, text in files.items():
        (folder / name).write_text(text)
    return folder


def load(folder: Path, python: Path, **settings) -> EchoPolicy:
    return EchoPolicy.load("echo", EchoConfig(checkpoint=str(folder), python=str(python), **settings))


def test_the_server_starts_only_when_asked_serves_and_stops_with_the_policy(tmp_path, model_env):
    policy = load(checkpoint(tmp_path / "ckpt", 0.5), model_env, max_batch=3)
    assert policy.server is None and policy.client is None  # loading plays nothing: no server yet
    assert {k: policy.identity[k] for k in ("checkpoint", "max_batch")} == {
        "checkpoint": EchoPolicy.fingerprint(tmp_path / "ckpt"),
        "max_batch": 3,
    }
    policy.start()
    try:
        process = policy.server.process
        assert policy.server.running
        np.testing.assert_allclose(policy.act(observation(4)), [0.5, 3, 0.04, 0, 0, 0, -1])
    finally:
        policy.close()
    assert process.poll() is not None  # stopped with the policy


def test_identity_follows_the_checkpoints_content_not_its_path(tmp_path, model_env):
    same = [load(checkpoint(tmp_path / name, 0.5), model_env).identity for name in ("a", "b")]
    other = load(checkpoint(tmp_path / "c", 0.25), model_env).identity
    assert same[0] == same[1] != other


def test_max_steps_default_to_the_models_own_budget_and_a_setting_overrides_every_suite(tmp_path, model_env):
    folder = checkpoint(tmp_path / "ckpt")
    assert load(folder, model_env).max_steps == {"libero_spatial": 7, "libero_goal": 9}
    assert load(folder, model_env, max_steps=3).max_steps == {"libero_spatial": 3, "libero_goal": 3}


@pytest.mark.parametrize(
    "settings, message",
    [
        (
            {"checkpoint": ""},
            "model=echo needs model.checkpoint=DIR (a local checkpoint folder) or model.server=http://",
        ),
        ({"server": "http://127.0.0.1:9", "checkpoint": ""}, "also needs model.checkpoint=NAME"),
        ({"checkpoint": "{missing}"}, "is not an echo checkpoint"),
        ({"python": "/no/such/python"}, "no model environment at /no/such/python"),
        ({"python": "{unprepared}"}, "cannot run the echo server"),
        ({"device": "gpu"}, "model.device must be cpu, cuda, cuda:N or auto"),
        ({"max_batch": 0}, "model.max_batch must be >= 1, got 0"),
        ({"max_steps": -1}, "model.max_steps must be >= 0, got -1"),
    ],
)
def test_user_mistakes_are_user_errors_before_anything_starts(tmp_path, monkeypatch, model_env, settings, message):
    values = {"missing": tmp_path / "nope", "unprepared": sys.executable}
    if settings.get("python") == "{unprepared}":  # a Python without the server module
        monkeypatch.delenv("PYTHONPATH")
    cfg = {"checkpoint": str(checkpoint(tmp_path / "ckpt")), "python": str(model_env)}
    cfg.update({key: value.format(**values) if isinstance(value, str) else value for key, value in settings.items()})
    with pytest.raises(UserError, match=message.replace("(", r"\(").replace(")", r"\)")):
        EchoPolicy.load("echo", EchoConfig(**cfg))


def test_a_server_refusing_its_checkpoint_is_a_user_error_with_its_own_words(tmp_path, model_env):
    policy = load(checkpoint(tmp_path / "ckpt", refuse=""), model_env)
    with pytest.raises(UserError, match="holds weights of another model"):
        policy.start()
    assert policy.server is None or not policy.server.running


def test_a_started_server_that_dies_is_named_with_its_exit_code_and_log(tmp_path, model_env):
    policy = load(checkpoint(tmp_path / "ckpt", lives="1"), model_env)
    policy.start()
    try:
        policy.act(observation(0))
        with pytest.raises(ServerUnavailable, match=r"exited with code 7; its log: .*echo-.*\.log"):
            policy.act(observation(1))
    finally:
        policy.close()


def test_a_non_http_protocol_says_when_it_is_ready_with_its_own_check(tmp_path, model_env):
    asked = []

    class Pinged(EchoPolicy):
        def ready_check(self, url):
            def ready() -> bool:
                asked.append(url)
                return self._answers(url)

            return ready

        @staticmethod
        def _answers(url: str) -> bool:
            import urllib.request

            with urllib.request.build_opener(urllib.request.ProxyHandler({})).open(f"{url}/healthz", timeout=1):
                return True

    policy = Pinged.load("echo", EchoConfig(checkpoint=str(checkpoint(tmp_path / "ckpt")), python=str(model_env)))
    policy.start()
    try:
        assert asked and all(url.startswith("http://127.0.0.1:") for url in asked)
        assert policy.act(observation(0))[0] == 0.5
    finally:
        policy.close()


# -- a plugin that declares `served`: its server is conflictbench-serve's, found through the entry point ----------
SERVED_MODULE = textwrap.dedent(
    """
    import http.server, json, pathlib
    from conflictbench_serving.checkpoints import CheckpointError
    from conflictbench_serving.command import ServedModel

    def check(folder, policy, naming):
        if not (folder / "weights.txt").is_file():
            raise CheckpointError(f"{folder} is not an echo checkpoint (see {naming}{policy})")

    class Echo:
        def __init__(self, folder):
            self.folder, self.metadata = folder, {"policy_type": "echo"}
            self.weight = float((folder / "weights.txt").read_text())

    def load(checkpoint, device):
        return Echo(pathlib.Path(checkpoint))

    def serve(backend, host, port, max_batch, on_ready):
        if (backend.folder / "upgraded").exists():  # a package upgraded between the run's probe and the server's start
            backend.metadata["model_stack"]["packages"]["echo-served"] = "9.9"
        class Handler(http.server.BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"
            def log_message(self, *a):
                pass
            def _send(self, status, payload):
                body = json.dumps(payload).encode()
                self.send_response(status)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
            def do_GET(self):
                if self.path == "/metadata":
                    return self._send(200, backend.metadata)
                self._send(200 if self.path == "/healthz" else 404, "OK")
            def do_POST(self):
                request = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                self._send(200, [backend.weight, max_batch, 0.01 * request["step"], 0, 0, 0, -1])

        server = http.server.ThreadingHTTPServer((host, port), Handler)
        on_ready(host, server.server_address[1])
        server.serve_forever()

    SERVED = ServedModel(environment="echo", policies=("echo",), protocol="JSON over HTTP", check=check,
                         backend=load, server=serve, url_scheme="http")
    """
)
#: conflictbench-serve imports torch before loading a model; this test's model needs none of it, and the
#: simulator's environment has none: the two names the command asks of it.
TORCH_STANDIN = "class cuda:\n    is_available = staticmethod(lambda: False)\n\n\ndef set_num_threads(n):\n    pass\n"


def served_site(folder: Path, version: str = "1.0") -> Path:
    """A folder holding an installed plugin: a distribution of that version with a ``conflictbench_serving`` entry
    point."""
    info = folder / f"echo_served-{version}.dist-info"
    info.mkdir(parents=True)
    (folder / "echo_served.py").write_text(SERVED_MODULE)
    (folder / "torch.py").write_text(TORCH_STANDIN)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: echo-served\nVersion: {version}\n")
    (info / "entry_points.txt").write_text("[conflictbench_serving]\necho = echo_served:SERVED\n")
    return folder


@pytest.fixture
def served_env(tmp_path, monkeypatch) -> Path:
    """This interpreter with an installed plugin (a distribution with a ``conflictbench_serving`` entry point)."""
    site = served_site(tmp_path / "served-site")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]))
    monkeypatch.syspath_prepend(str(site))
    return Path(sys.executable)


def served_echo():
    import echo_served

    class ServedEcho(HostedPolicy):
        served = echo_served.SERVED
        transport = HttpJsonTransport
        url_scheme = "http"
        default_max_steps = {"libero_spatial": 7}
        fingerprint = staticmethod(EchoPolicy.fingerprint)
        encode, decode = EchoPolicy.encode, EchoPolicy.decode

    return ServedEcho


def test_a_policy_declaring_served_is_hosted_by_conflictbench_serve(tmp_path, served_env):
    policy = served_echo().load("echo", EchoConfig(checkpoint=str(checkpoint(tmp_path / "ckpt", 0.25)),
                                                   python=str(served_env), max_batch=2))  # fmt: skip
    policy.start()
    try:
        assert policy.server.argv[1:4] == ["-m", "conflictbench_serving", "echo"]
        np.testing.assert_allclose(policy.act(observation(3)), [0.25, 2, 0.03, 0, 0, 0, -1])
        assert "conflictbench-serve: serving echo from" in policy.server.log_tail()
    finally:
        policy.close()


def test_a_policy_declaring_served_checks_its_checkpoint_with_the_declared_check(tmp_path, served_env, monkeypatch):
    served = served_echo()
    with pytest.raises(UserError, match=r"nope is not an echo checkpoint \(see model=echo\)$"):
        served.load("echo", EchoConfig(checkpoint=str(tmp_path / "nope"), python=str(served_env)))
    without = os.environ["PYTHONPATH"].split(os.pathsep, 1)[1]  # the model environment lacks the plugin
    monkeypatch.setenv("PYTHONPATH", without)
    with pytest.raises(UserError, match=r"cannot run the echo server \(LookupError: no installed plugin serves 'echo'"):
        served.load("echo", EchoConfig(checkpoint=str(checkpoint(tmp_path / "ckpt")), python=str(served_env)))


def test_the_model_stack_is_known_before_the_server_starts_and_is_what_the_server_reports(
    tmp_path, served_env, monkeypatch
):
    """Part of every episode's identity, read from the model environment's files (no server, no torch), with
    ``model.device=auto`` decided then; the started server says the same in its metadata."""
    served = served_echo()
    policy = served.load("echo", EchoConfig(checkpoint=str(checkpoint(tmp_path / "ckpt")), python=str(served_env)))
    assert policy.server is None
    stack = policy.identity["model_stack"]
    assert stack["device"] == "cpu" == policy.device  # auto: no CUDA build of torch here
    assert stack["packages"]["echo-served"] == "1.0" and stack["packages"]["numpy"] == np.__version__
    assert "pip" not in stack["packages"]  # installers run no model
    policy.start()
    try:
        argv = policy.server.argv
        assert argv[argv.index("--device") + 1] == "cpu"  # the server runs where the identity says
        with urllib.request.urlopen(f"http://127.0.0.1:{policy.server.address[1]}/metadata") as reply:  # its report
            assert json.loads(reply.read())["model_stack"] == stack
    finally:
        policy.close()

    other = served_site(tmp_path / "upgraded-site", "1.1")  # the plugin upgraded in the model environment
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(other), os.environ["PYTHONPATH"].split(os.pathsep, 1)[1]]))
    upgraded = served.load("echo", EchoConfig(checkpoint=str(checkpoint(tmp_path / "ckpt2")), python=str(served_env)))
    assert upgraded.identity["model_stack"]["packages"]["echo-served"] == "1.1"
    before, now = stack_pins(stack), stack_pins(upgraded.identity["model_stack"])
    assert before[0] == "device=cpu" and "echo-served==1.0" in before
    assert stack_changes(before, now) == "echo-served 1.0 -> 1.1"
    assert stack_changes(before, ("unreported",)) == "reported -> unreported"


def test_a_server_that_does_not_say_its_stack_is_counted_unreported_and_the_run_says_so(tmp_path, model_env, capsys):
    policy = load(checkpoint(tmp_path / "ckpt"), model_env)
    policy.start()
    try:
        url = policy.server.health_url.removesuffix("/healthz")
        given = EchoPolicy.load("echo", EchoConfig(server=url, checkpoint="echo-weights"))
        try:
            assert given.identity == {"checkpoint": "echo-weights", "max_batch": 1, "model_stack": "unreported"}
        finally:
            given.close()
    finally:
        policy.close()
    said = capsys.readouterr().err
    assert said.count("does not say what model stack it runs") == 1 and url in said


def test_a_started_server_on_another_stack_than_the_probe_said_is_refused(tmp_path, served_env):
    """The identity counted the stack before the server started; a server that then runs on another one would store
    its episodes under the wrong identity."""
    pytest.importorskip("json_numpy")
    from conflictbench.hosting.rest import JsonNumpyTransport

    class ReadsMetadata(served_echo()):  # deploy.py's REST client: it reads our server's GET /metadata on connecting
        transport = JsonNumpyTransport

    folder = checkpoint(tmp_path / "ckpt", upgraded="")
    policy = ReadsMetadata.load("echo", EchoConfig(checkpoint=str(folder), python=str(served_env)))
    said = r"another stack than its environment's files said \(echo-served 1.0 -> 9.9\): its episodes would be stored"
    with pytest.raises(UserError, match=said):
        policy.start()
    assert not policy.server.running  # stopped
