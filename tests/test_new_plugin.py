"""``conflictbench new-plugin``: the plugin it writes has the target layout, is clean to ruff, passes its own tests
(its client and its real server half talking on 127.0.0.1, for each protocol); its server half, installed in a model
environment of its own, is started by its client through conflictbench-serve for a checkpoint (marked model_env,
each protocol); and, installed as a user installs it, it plays real LIBERO episodes with the stand-in backend's
actions (marked e2e)."""

from __future__ import annotations

import glob
import json
import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from conflictbench.cli import main
from conflictbench.cli.new_plugin import PROTOCOLS, in_checkout
from conflictbench.store import EpisodeStore

REPO = Path(__file__).resolve().parents[1]
#: A name no plugin has, README's tutorial's (``mymodel``) included: a reader who followed it has that one installed.
NAME = "np_probe"
BIN = Path(sys.executable).parent
TREE = {
    "README.md",
    "pyproject.toml",
    "server/pyproject.toml",
    "conflictbench_{name}/__init__.py",
    "conflictbench_{name}/protocol.py",
    "conflictbench_{name}/processing.py",
    "conflictbench_{name}/checkpoints.py",
    "conflictbench_{name}/client.py",
    "conflictbench_{name}/server.py",
    "conflictbench_{name}/backend.py",
    "tests/conftest.py",
    "tests/test_{name}_protocol.py",
    "tests/test_{name}_client.py",
}


def new_plugin(*args: str) -> int:
    return main(["new-plugin", *args])


def generated(tmp_path: Path, name: str, protocol: str) -> Path:
    assert new_plugin(name, "--protocol", protocol, "--dir", str(tmp_path)) == 0
    return tmp_path / name


@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
def test_it_writes_both_halves_in_the_target_layout_each_with_one_entry_point(tmp_path, protocol, capsys):
    plugin = generated(tmp_path, NAME, protocol)
    files = {str(path.relative_to(plugin)) for path in plugin.rglob("*") if path.is_file()}
    assert files == {path.format(name=NAME) for path in TREE}
    assert sorted(capsys.readouterr().out.split()) == sorted(str(plugin / f) for f in files)  # what it wrote, said
    client = tomllib.loads((plugin / "pyproject.toml").read_text())["project"]
    server = tomllib.loads((plugin / "server" / "pyproject.toml").read_text())["project"]
    assert client["entry-points"] == {"conflictbench": {NAME: f"conflictbench_{NAME}.client"}}
    assert server["entry-points"] == {"conflictbench_serving": {NAME: f"conflictbench_{NAME}.server:SERVED"}}
    assert "scripts" not in client and "scripts" not in server
    assert not any("conflictbench>" in r or "conflictbench[" in r for r in server["dependencies"])  # never the client's
    for path in plugin.rglob("*.py"):
        compile(path.read_text(), str(path), "exec")


def test_the_generated_python_is_clean_to_the_projects_ruff_for_every_protocol_and_a_long_name(tmp_path):
    for protocol in PROTOCOLS:
        generated(tmp_path, f"{protocol}_plugin", protocol)
        generated(tmp_path, f"name_of_twenty_{protocol}"[:20], protocol)  # the longest name a plugin may have
    config = ["--config", str(REPO / "pyproject.toml")]
    lint = subprocess.run([BIN / "ruff", "check", *config, tmp_path], capture_output=True, text=True)
    assert lint.returncode == 0, lint.stdout
    form = subprocess.run([BIN / "ruff", "format", "--check", *config, tmp_path], capture_output=True, text=True)
    assert form.returncode == 0, form.stdout


@pytest.mark.parametrize(
    "args, words",
    [
        (["My-Model", "--protocol", "openpi"], "'My-Model' cannot name a plugin"),
        (["class", "--protocol", "openpi"], "'class' cannot name a plugin"),
        (["a" * 21, "--protocol", "openpi"], "cannot name a plugin"),
        (["zz_", "--protocol", "rest"], "'zz_' cannot name a plugin"),  # its distribution, conflictbench-zz-: no
        (["noop", "--protocol", "rest"], "already registers the policy 'noop'"),
        ([NAME, "--protocol", "grpc"], "invalid choice: 'grpc'"),
        ([NAME], "--protocol"),
    ],
)
def test_a_name_a_plugin_cannot_have_is_one_line_and_exit_code_2(tmp_path, capsys, args, words):
    assert new_plugin(*args, "--dir", str(tmp_path)) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not any(tmp_path.iterdir())


def test_a_folder_that_is_not_empty_is_refused_an_empty_one_filled(tmp_path, capsys):
    (tmp_path / NAME).mkdir()
    (tmp_path / NAME / "notes.txt").write_text("mine")
    assert new_plugin(NAME, "--protocol", "openpi", "--dir", str(tmp_path)) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / NAME} exists and is not empty" in err and err.count("\n") == 1
    assert [p.name for p in (tmp_path / NAME).iterdir()] == ["notes.txt"]
    (tmp_path / "other").mkdir()
    assert new_plugin("other", "--protocol", "openpi", "--dir", str(tmp_path)) == 0
    assert (tmp_path / "other" / "conflictbench_other" / "backend.py").is_file()


def test_a_folder_it_cannot_write_in_is_one_line_and_exit_code_2(tmp_path, capsys):
    (tmp_path / "a_file").write_text("not a folder")
    assert new_plugin("x", "--protocol", "rest", "--dir", str(tmp_path / "a_file")) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith(f"conflictbench: error: new-plugin: cannot write {tmp_path / 'a_file' / 'x'}: ")
        and err.count("\n") == 1
    )


def test_in_the_checkouts_plugins_the_readme_says_set_up_and_the_next_step_is_readmes_table(tmp_path, capsys):
    """README's table lists the checkout's plugins/ (a test keeps it current): a plugin written there is told to add
    its row; elsewhere its README's steps start from its own folder, naming no path of the checkout."""
    assert in_checkout(REPO / "plugins" / NAME) and not in_checkout(tmp_path / "plugins" / NAME)
    plugin = generated(tmp_path, NAME, "rest")
    assert "scripts/readme_plugins.py" not in capsys.readouterr().err
    readme = (plugin / "README.md").read_text()
    assert "From this folder" in readme and "./plugins/" not in readme and "setup.sh" not in readme


@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
def test_the_generated_tests_pass_its_client_and_real_server_half_talking_on_loopback(tmp_path, protocol):
    """The plugin's own tests as generated, importing it from its folder: among them, its client against its server
    half started on 127.0.0.1 (no mocks), and the client's encode and decode."""
    plugin = generated(tmp_path, f"my_{protocol}", protocol)
    env = {**os.environ, "PYTHONPATH": str(plugin)}
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:randomly", "tests"],
        cwd=plugin, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert re.search(r"\b8 passed\b", done.stdout), done.stdout[-1000:]


def test_the_rest_server_half_refuses_a_json_numpy_array_it_cannot_read_in_one_line(tmp_path):
    """A ``__numpy__`` object without its dtype, or with one numpy does not know: an invalid request (400), not a
    server error (500, a traceback)."""
    plugin = generated(tmp_path, "np_rest", "rest")
    probe = (
        "import sys\nfrom conflictbench_serving import rest\nfrom conflictbench_np_rest.server import request_row\n"
        "for body in sys.argv[1:]:\n    try:\n        request_row(body.encode())\n"
        "    except rest.InvalidRequest as error:\n        print(error)\n"
    )
    bodies = [
        '{"image": {"__numpy__": "AAAA", "shape": [3]}}',
        '{"image": {"__numpy__": "AAAA", "dtype": "<zz", "shape": [1]}}',
    ]
    env = {**os.environ, "PYTHONPATH": str(plugin)}
    done = subprocess.run([sys.executable, "-c", probe, *bodies], capture_output=True, text=True, env=env)
    assert done.returncode == 0 and done.stdout.splitlines() == [
        "a json-numpy array that cannot be read (a json-numpy array without its 'dtype')",
        "a json-numpy array that cannot be read (not a dtype: '<zz' (data type '<zz' not understood))",
    ], done.stdout + done.stderr


# ---- installed as a user would, and played --------------------------------------------------------------------


def model_python() -> str:
    """The model environments' interpreter as scripts/setup.sh picks it (a Python 3.12, pyenv's too), else this one."""
    pyenv = shutil.which("pyenv")
    root = subprocess.run([pyenv, "root"], capture_output=True, text=True).stdout.strip() if pyenv else ""
    found = [shutil.which("python3.12"), *sorted(glob.glob(f"{root}/versions/3.12*/bin/python3.12") if root else [])]
    for candidate in filter(None, found):  # a pyenv shim exists even where its version is not selected: ask it
        probe = [candidate, "-c", "import sys; sys.exit(sys.version_info[:2] != (3, 12))"]
        if subprocess.run(probe, capture_output=True).returncode == 0:
            return candidate
    return sys.executable


def uv(*args: object) -> None:
    done = subprocess.run([BIN / "uv", "--color", "never", *map(str, args)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]


#: The client's lifecycle for a checkpoint, in this Python with the plugin importable from its folder: load (the
#: model environment's Python named), start (conflictbench-serve there, ready by the protocol's own check), act, close.
LIFECYCLE = """
import sys
from pathlib import Path

import numpy as np

from conflictbench import Observation, sampling_seed
from PACKAGE import client
from PACKAGE.backend import standin_chunk
from PACKAGE.checkpoints import POLICY, fingerprint
from PACKAGE.protocol import NOISE_SEED_LIMIT

checkpoint, python = Path(sys.argv[1]), sys.argv[2]
config = next(v for k, v in vars(client).items() if k.endswith("Config") and k != "HostedConfig")
policy = client.load(POLICY, config(checkpoint=str(checkpoint), python=python, startup_timeout_s=120.0))
policy.start()
try:
    obs = Observation(
        step=3, instruction="pick up the bowl", eef_pos=np.zeros(3), eef_quat=np.array([1.0, 0, 0, 0]),
        gripper_qpos=np.zeros(2), state=np.arange(8.0) / 10, agentview_image=np.zeros((256, 256, 3), np.uint8),
        wrist_image=None, stream=0, episode_id="e0",
    )
    np.testing.assert_array_equal(policy.act(obs), standin_chunk(obs.state, sampling_seed(obs) % NOISE_SEED_LIMIT, 1.0))
    assert policy.identity["checkpoint"] == fingerprint(checkpoint), policy.identity
    print("served", policy.metadata["policy_type"], flush=True)
finally:
    policy.close()
"""


@pytest.mark.model_env
@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
def test_its_client_starts_its_server_half_in_a_model_environment_for_a_checkpoint(tmp_path, protocol):
    """The path a run with ``model.checkpoint=`` takes, without a simulator: the server half installed alone in a
    model environment (conflictbench-serving with the protocol's extra, the plugin's server distribution, its entry
    point; no conflictbench), started there by ``conflictbench-serve`` for the client, which answers the stand-in's
    chunk."""
    name = f"np_{protocol}"
    plugin = generated(tmp_path, name, protocol)
    model = tmp_path / "model-env"
    uv("venv", "-q", "--python", model_python(), model)
    uv("pip", "install", "-q", "--python", model / "bin" / "python", REPO / "serving", plugin / "server")
    checkpoint = tmp_path / "standin"
    checkpoint.mkdir()
    (checkpoint / "config.json").write_text(json.dumps({"type": name}))
    env = {**os.environ, "PYTHONPATH": str(plugin)}
    script = LIFECYCLE.replace("PACKAGE", f"conflictbench_{name}")
    done = subprocess.run(
        [sys.executable, "-c", script, checkpoint, model / "bin" / "python"],
        capture_output=True, text=True, timeout=240, env=env, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0 and done.stdout == f"served {name}\n", done.stdout[-2000:] + done.stderr[-3000:]


@pytest.mark.sim
@pytest.mark.e2e
def test_a_generated_plugin_installed_as_a_user_would_plays_libero_episodes_with_the_stand_ins_actions(tmp_path):
    name = "standin_vla"
    plugin = generated(tmp_path / "plugins", name, "openpi")
    # The client half beside conflictbench (and its simulator), the server half in a model environment of its own.
    client, model = tmp_path / "client-env", tmp_path / "model-env"
    uv("venv", "-q", "--python", sys.executable, client)
    uv("pip", "install", "-q", "--python", client / "bin" / "python", "-e", f"{REPO}[sim]", REPO / "serving", plugin)
    uv("venv", "-q", "--python", model_python(), model)
    uv("pip", "install", "-q", "--python", model / "bin" / "python", REPO / "serving", plugin / "server")
    # The stand-in's checkpoint, made by the README's own command.
    [make] = [line for line in (plugin / "README.md").read_text().splitlines() if line.startswith("mkdir -p standin")]
    subprocess.run(["bash", "-c", make.split("  #")[0]], cwd=tmp_path, check=True)
    store = tmp_path / "results"
    run = [
        client / "bin" / "conflictbench", f"model={name}", f"model.checkpoint={tmp_path / 'standin'}",
        f"model.python={model / 'bin' / 'python'}", "suite=physical", "level=L1", "run.cases_per_cell=1",
        "run.libero_suites=[libero_spatial]", "run.max_steps=12", "run.progress=false", "run.report=false",
        f"run.out={store}",
    ]  # fmt: skip
    env = {**os.environ, "MUJOCO_GL": "egl"}
    done = subprocess.run(run, capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    closing = r"\b2 played, 0 already stored, \d+ played by another job, 0 with errors"
    assert re.search(closing, done.stderr), done.stderr[-3000:]

    sys.path.insert(0, str(plugin))
    try:
        from conflictbench_standin_vla.backend import CHUNK, TURN, standin_chunk
    finally:
        sys.path.remove(str(plugin))
    records = list(EpisodeStore(store).records())
    assert len(records) == 2 and {r.case_id is None for r in records} == {True, False}
    for record in records:
        assert record.error is None and record.steps == 12 and record.plugin_version == "0.1.0"
        assert "sha256:" in record.policy_identity and record.model_stack != ("unreported",)
        raw = record.raw_actions
        # Each chunk pulls the end effector from where it was at the step that asked for it. The store's path is the
        # simulator's end-effector site, the policy's state robosuite's observation of it: they differ by < 0.1 mm.
        for step in range(record.steps):
            asked = step - step % CHUNK
            state = np.concatenate([record.eef_pos[asked], np.zeros(5)])
            np.testing.assert_allclose(raw[step, :3], standin_chunk(state, 0, gain=1.0)[0, :3], rtol=0, atol=2e-4)
        assert np.all(raw[:, 6] == -1.0) and np.all(np.abs(raw[:, 3:6]) <= TURN)
        assert len({tuple(raw[s, 3:6]) for s in range(0, record.steps, CHUNK)}) == record.steps // CHUNK  # per step
    assert json.loads(records[0].policy_identity)["checkpoint"] == json.loads(records[1].policy_identity)["checkpoint"]
