"""A server the run starts is the server the run talks to (#42, section 2), and the token it gives it (section 3).

The model plugin is the one ``conflictbench new-plugin`` writes (openpi's websocket protocol, its numpy stand-in
backend), made to load for a few seconds as a real model does for minutes; its model environment is a bare
``venv`` of this interpreter holding only the server half (conflictbench-serving, the plugin's package and its
``conflictbench_serving`` entry point; never conflictbench), so the run starts the server the way it starts every
model's: ``python -m conflictbench_serving POLICY ...`` there. The squatter is a real process on 127.0.0.1: it reads
the started server's command line, as ``ps`` shows it to any user, binds the port named there before the model has
loaded, and answers ``/healthz`` and openpi's metadata frame as the real server would, minus the fields it cannot
know.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import textwrap
import time
import venv
from pathlib import Path

import numpy as np
import pytest

import conflictbench_serving
from conflictbench import Observation, ServerUnavailable, UserError, sampling_seed
from conflictbench.cli import main as conflictbench_main
from conflictbench.hosting.launch import ServerProcess

NAME = "idprobe"
PACKAGE = f"conflictbench_{NAME}"
TOKEN_VARIABLE = "CONFLICTBENCH_SERVER_TOKEN"
#: How long the stand-in takes to load its "model": long enough for the squatter to move first.
LOAD_S = 1.0
#: What the model environment needs besides the plugin: conflictbench-serving and what it imports to serve openpi.
SERVER_HALF = ("numpy", "numpy.libs", "msgpack", "websockets")

SQUATTER = textwrap.dedent(
    """
    import http, os, sys, time
    import numpy as np
    from websockets.sync.server import serve
    from conflictbench_serving.msgpack_numpy import packb

    checkpoint, connections = sys.argv[1], sys.argv[2]
    print("watching", flush=True)
    port, deadline = None, time.monotonic() + 60
    while port is None and time.monotonic() < deadline:  # what `ps` shows any user on this machine
        for pid in filter(str.isdigit, os.listdir("/proc")):
            try:
                argv = open(f"/proc/{pid}/cmdline", "rb").read().decode(errors="replace").split("\\0")
            except OSError:
                continue
            if "conflictbench_serving" in argv and checkpoint in argv and "--port" in argv:
                port = int(argv[argv.index("--port") + 1])
        time.sleep(0.005)
    print("saw port", port, flush=True)
    if not port:  # nothing named there to take (0: the server binds whatever port the system gives it)
        sys.exit(0)

    def health(connection, request):
        return connection.respond(http.HTTPStatus.OK, "OK\\n") if request.path == "/healthz" else None

    def impostor(connection):
        with open(connections, "a") as log:
            log.write("connected\\n")
        connection.send(packb({"policy_type": "idprobe"}))  # no fingerprint, no model stack: it cannot know them
        for _ in connection:
            connection.send(packb({"actions": np.full((4, 7), 0.5)}))

    with serve(impostor, "127.0.0.1", port, process_request=health, compression=None) as server:
        print("squatting", port, flush=True)
        server.serve_forever()
    """
)


def _site_packages(env: Path) -> Path:
    return next((env / "lib").glob("python3*/site-packages"))


@pytest.fixture(scope="module")
def standin(tmp_path_factory) -> tuple[Path, Path]:
    """The generated plugin's folder (its client half importable from there) and its model environment's python."""
    root = tmp_path_factory.mktemp("identity")
    assert conflictbench_main(["new-plugin", NAME, "--protocol", "openpi", "--dir", str(root)]) == 0
    plugin = root / NAME
    backend = plugin / PACKAGE / "backend.py"
    text = backend.read_text()
    loaded = '    return Backend(folder, gain=float(config.get("gain", 1.0)))\n'
    assert loaded in text
    backend.write_text(
        text.replace("import json\n", "import json\nimport time\n").replace(
            loaded,
            "    time.sleep(float(config.get('load_s', 0)))  # a real model loads for minutes\n"
            "    backend = Backend(folder, gain=float(config.get('gain', 1.0)))\n"
            "    for field in config.get('unsaid', []):  # a server that leaves out what it hosts\n"
            "        backend.metadata.pop(field, None)\n"
            "    if 'model_stack' in config.get('unsaid', []):  # not a dict: conflictbench-serve adds none\n"
            "        backend.metadata = __import__('types').MappingProxyType(backend.metadata)\n"
            "    return backend\n",
        )
    )
    env = root / "model-env"
    venv.create(env, with_pip=False, symlinks=True)
    site, here = _site_packages(env), Path(np.__file__).parents[1]
    for name in SERVER_HALF:
        if (here / name).exists():
            (site / name).symlink_to(here / name)
    (site / "conflictbench_serving").symlink_to(Path(conflictbench_serving.__file__).parent)
    (site / PACKAGE).symlink_to(plugin / PACKAGE)
    info = site / f"{PACKAGE}_server-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {PACKAGE}-server\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text(f"[conflictbench_serving]\n{NAME} = {PACKAGE}.server:SERVED\n")
    sys.path.insert(0, str(plugin))
    yield plugin, env / "bin" / "python"
    sys.path.remove(str(plugin))
    for module in [m for m in sys.modules if m == PACKAGE or m.startswith(f"{PACKAGE}.")]:
        del sys.modules[module]


def checkpoint(folder: Path, **config) -> Path:
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"type": NAME, **config}))
    return folder


def load(standin, folder: Path, **settings):
    from conflictbench_idprobe import client

    _plugin, python = standin
    cfg = client.IdprobeConfig(checkpoint=str(folder), python=str(python), startup_timeout_s=60.0, **settings)
    return client.load(NAME, cfg)


def observation() -> Observation:
    return Observation(
        step=3, instruction="pick up the bowl", eef_pos=np.zeros(3), eef_quat=np.array([1.0, 0, 0, 0]),
        gripper_qpos=np.zeros(2), state=np.arange(8.0) / 10, agentview_image=np.zeros((256, 256, 3), np.uint8),
        wrist_image=None, stream=0, episode_id="e0",
    )  # fmt: skip


def standin_actions(obs: Observation) -> np.ndarray:
    from conflictbench_idprobe.backend import standin_chunk
    from conflictbench_idprobe.protocol import NOISE_SEED_LIMIT

    return standin_chunk(obs.state, sampling_seed(obs) % NOISE_SEED_LIMIT, 1.0)


@pytest.fixture(autouse=True)
def elsewhere(tmp_path, monkeypatch):
    """Runs start here, outside the checkout: ``python -m`` puts the working folder first on the server's path, and
    the checkout's conflictbench there would make the stand-in's environment look like the simulator's."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def squatter(tmp_path):
    """``squatter(checkpoint) -> (process, connections log)``: started and watching; killed at teardown."""
    started: list[subprocess.Popen] = []

    def start(folder: Path) -> tuple[subprocess.Popen, Path]:
        log = tmp_path / "squatter-connections"
        log.touch()
        process = subprocess.Popen(
            [sys.executable, "-c", SQUATTER, str(folder), str(log)], stdout=subprocess.PIPE, text=True
        )
        started.append(process)
        assert process.stdout.readline() == "watching\n"
        return process, log

    yield start
    for process in started:
        process.kill()
        process.wait()


def test_a_squatter_on_the_port_named_on_the_servers_command_line_is_never_talked_to(standin, tmp_path, squatter):
    folder = checkpoint(tmp_path / "ckpt", load_s=LOAD_S)
    impostor, connections = squatter(folder)
    policy = load(standin, folder)
    policy.start()
    try:
        obs = observation()
        actions = policy.act(obs)
        saw = impostor.stdout.readline()
        assert saw.startswith("saw port "), saw  # it did find the started server's command line
        assert connections.read_text() == "", "the run talked to the squatter"
        np.testing.assert_array_equal(actions, standin_actions(obs))
        from conflictbench_idprobe.checkpoints import fingerprint

        assert policy.metadata["checkpoint_fingerprint"] == fingerprint(folder)
    finally:
        policy.close()


@pytest.mark.parametrize("unsaid", ["checkpoint_fingerprint", "model_stack"])
def test_a_started_server_that_leaves_out_what_it_hosts_is_refused_in_one_line(standin, tmp_path, unsaid):
    """What an impostor cannot know it would leave out: a server started for the run must say both."""
    policy = load(standin, checkpoint(tmp_path / "ckpt", unsaid=[unsaid]))
    with pytest.raises(UserError) as refused:
        policy.start()
    message = str(refused.value)
    assert "\n" not in message and unsaid.split("_")[-1] in message and "started for this run" in message, message
    assert policy.server is None or not policy.server.running  # stopped, not left behind


def test_once_the_started_server_has_exited_nothing_is_sent_to_whoever_takes_its_port(standin, tmp_path):
    policy = load(standin, checkpoint(tmp_path / "ckpt"), connect_retries=1, backoff_s=0.1)
    policy.start()
    try:
        port = policy.server.address[1]
        policy.server.process.kill()
        policy.server.process.wait(10)
        with socket.create_server(("127.0.0.1", port)) as taken:  # the port is free: anyone may listen there now
            taken.settimeout(0.1)
            with pytest.raises(ServerUnavailable, match="started for this run exited with code -9"):
                policy.act(observation())
            with pytest.raises(TimeoutError):
                taken.accept()  # no connection came
    finally:
        policy.close()


def _environ(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
    return dict(item.decode(errors="replace").partition("=")[::2] for item in raw if item)


def test_each_started_server_gets_a_fresh_token_in_its_environment_never_on_its_command_line(
    standin, tmp_path, monkeypatch
):
    monkeypatch.setenv(TOKEN_VARIABLE, "the-users-remote-token")  # for model.server=; never a started server's
    tokens = []
    for run in range(2):
        policy = load(standin, checkpoint(tmp_path / f"ckpt{run}"))
        policy.start()
        try:
            pid = policy.server.process.pid
            token = _environ(pid).get(TOKEN_VARIABLE, "")
            assert len(token) >= 32 and token != "the-users-remote-token"
            assert token not in Path(f"/proc/{pid}/cmdline").read_text()
            np.testing.assert_array_equal(policy.act(observation()), standin_actions(observation()))
            tokens.append(token)
            from conflictbench.hosting.openpi import OpenpiTransport

            stranger = OpenpiTransport(f"ws://127.0.0.1:{policy.server.address[1]}")  # another user of this machine
            with pytest.raises((ServerUnavailable, OSError), match="401"):
                stranger.connect(timeout=5)
        finally:
            policy.close()
        assert token not in policy.server.log_path.read_text()  # never logged
    assert tokens[0] != tokens[1]


# ---- ServerProcess with the address reported over its own pipe --------------------------------------------------

REPORTING_SERVER = textwrap.dedent(
    """
    import http.server, os, sys, time
    fd, delay = int(sys.argv[sys.argv.index("--ready-fd") + 1]), float(sys.argv[1])
    time.sleep(delay)
    class Health(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            self.send_response(200)
            self.end_headers()
        def log_message(self, *args):
            pass
    server = http.server.HTTPServer(("127.0.0.1", 0), Health)
    os.write(fd, f"127.0.0.1 {server.server_address[1]}\\n".encode())
    os.close(fd)
    server.serve_forever()
    """
)


def reporting(tmp_path, script: str, *args: str, timeout: float = 20.0) -> ServerProcess:
    return ServerProcess(
        [sys.executable, "-c", script, *args], name="test", reports_address=True, startup_timeout_s=timeout,
        log_dir=tmp_path,
    )  # fmt: skip


def test_the_port_is_the_one_the_started_process_reports_over_its_pipe(tmp_path):
    with reporting(tmp_path, REPORTING_SERVER, "0.5") as process:
        host, port = process.address
        assert host == "127.0.0.1" and port > 0
        with open(f"/proc/{process.process.pid}/net/tcp") as table:  # the process listens there
            assert f":{port:04X} 00000000:0000 0A" in table.read()


@pytest.mark.parametrize(
    "script, timeout, words",
    [
        ("import time; time.sleep(60)", 1.5, "did not say where it listens within 1.5 s"),
        # The others act at once, with time to start on a busy machine before the limit would turn their message into
        # the time-out's (a closed pipe's process is then waited for until the limit: 4 s, not 10).
        ("import os, sys, time; os.close(int(sys.argv[-1])); time.sleep(60)", 4, "closed its ready pipe"),
        ("import os, sys; os.write(int(sys.argv[-1]), b'nonsense\\n'); sys.exit(0)", 10, "not a HOST PORT line"),
        ("import sys; print('no model'); sys.exit(137)", 10, "exited with code 137 while starting"),
    ],
)
def test_a_server_that_does_not_report_its_address_is_unavailable_and_stopped(tmp_path, script, timeout, words):
    process = reporting(tmp_path, script, timeout=timeout)
    started = time.monotonic()
    with pytest.raises(ServerUnavailable, match=words):
        process.start()
    assert process.process is None and time.monotonic() - started < 15


def test_a_server_that_closes_its_pipe_then_exits_with_a_user_error_says_that_error(tmp_path):
    """A server refusing its checkpoint closes the ready pipe, then takes its time to exit (a model stack tearing
    down): its one line is the error, not a pipe closed unsaid."""
    script = ("import os, sys, time; os.close(int(sys.argv[-1])); time.sleep(1.5); "
              "print('the checkpoint does not fit'); sys.exit(2)")  # fmt: skip
    with pytest.raises(UserError, match="^the checkpoint does not fit$"):
        reporting(tmp_path, script, timeout=20).start()
