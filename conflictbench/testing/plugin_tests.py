"""Checks every served model plugin's tests make, written once (tests only: nothing at run time imports this).

- :func:`play_pinned_actions`: a policy started for a tiny checkpoint plays the actions pinned in its golden file
  (:func:`~conflictbench.testing.check_pinned_actions`), then its server is stopped, however the check ends;
- :func:`played_one_case`, :func:`played_records`: the records of the one-case selection played (against a stand-in
  server), checked to have run cleanly;
- :func:`check_served_identity`: what a policy started for a checkpoint counts in its episodes' identity;
- :func:`lerobot_folder`: a folder laid out as a LeRobot checkpoint (empty files), for the checks of a folder;
- :func:`lerobot_checkpoint_errors` and :func:`check_serve_refuses`: the folders a LeRobot plugin's server refuses
  in one line, and that check;
- :func:`server_in_thread`: a protocol server of conflictbench-serving on a free port, in a thread of the test;
- :func:`serve_command`: ``conflictbench-serve ARGV`` in this Python with the entry point the plugin's server half
  declares (``plugins/NAME/server/pyproject.toml``), as its model environment has it: the checks a folder passes
  before torch is imported can be tested in the simulator's environment, which holds the client half only.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import threading
import tomllib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .observations import check_pinned_actions


def play_pinned_actions(policy, golden: Path, fingerprint: str) -> None:
    """Start ``policy`` (its server for a checkpoint), check its actions against ``golden``, stop it."""
    try:
        policy.start()
        check_pinned_actions(policy, golden, fingerprint)
    finally:
        policy.close()


#: The files a LeRobot ``save_pretrained`` folder holds that the plugins' checks look for.
LEROBOT_FILES = ("model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json")


def lerobot_folder(folder: Path, kind: str | None, files: tuple[str, ...] = LEROBOT_FILES) -> Path:
    """``folder``, made, with ``config.json`` saying its policy ``type`` (none where ``kind`` is None) and ``files``
    (empty)."""
    folder.mkdir()
    if kind:
        (folder / "config.json").write_text(json.dumps({"type": kind}))
    for name in files:
        (folder / name).write_text("")
    return folder


def server_half_entry_points(server_pyproject: Path, site: Path) -> Path:
    """A folder for ``PYTHONPATH`` holding the metadata of the server half declared by ``server_pyproject``
    (its name, version and entry points; its package is the client's, importable already)."""
    project = tomllib.loads(server_pyproject.read_text())["project"]
    name = project["name"].replace("-", "_")
    info = site / f"{name}-{project['version']}.dist-info"
    info.mkdir(parents=True, exist_ok=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n")
    groups = project.get("entry-points", {})
    (info / "entry_points.txt").write_text(
        "".join(
            f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in entries.items()) for group, entries in groups.items()
        )
    )
    return site


def serve_command(plugin_root: Path, tmp_path: Path, *argv: str) -> subprocess.CompletedProcess:
    """``conflictbench-serve ARGV`` (``python -m conflictbench_serving``) in this Python, with the plugin's server
    half's entry point: its output captured, within two minutes."""
    site = server_half_entry_points(plugin_root / "server" / "pyproject.toml", tmp_path / "server-half")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    return subprocess.run(
        [sys.executable, "-m", "conflictbench_serving", *argv], capture_output=True, text=True, timeout=120, env=env
    )


def played_one_case(tmp_path: Path, started, run, steps: int) -> list:
    """The records of :data:`~conflictbench.testing.ONE_CASE` played by ``run(url)`` (a ``conflictbench`` command
    into ``tmp_path / "results"``) against ``started``, a stand-in server and its URL (stopped after): both
    episodes ran ``steps`` steps without an error. The reference episode first."""
    server, url = started
    try:
        out = run(url)
    finally:
        server.stop()
    return played_records(tmp_path, out, steps)


def played_records(tmp_path: Path, out: subprocess.CompletedProcess, steps: int) -> list:
    """The records of :data:`~conflictbench.testing.ONE_CASE` played by the finished command ``out`` into
    ``tmp_path / "results"``: both episodes ran ``steps`` steps without an error. The reference episode first."""
    from conflictbench.store import EpisodeStore

    from .runs import episode_counts

    assert out.returncode == 0, out.stderr[-3000:]
    assert episode_counts(out.stderr) == (2, 0, 0)
    records = sorted(EpisodeStore(tmp_path / "results").records(), key=lambda r: r.case_id is not None)
    assert len(records) == 2 and all(r.steps == steps and r.error is None for r in records)
    return records


def check_served_identity(policy, fingerprint: str, max_batch: int) -> None:
    """A policy started for a checkpoint on the CPU counts in its episodes' identity what its server reported: the
    checkpoint's fingerprint, the batch shape and the model stack (the device, torch among the packages)."""
    assert {k: v for k, v in policy.identity.items() if k != "model_stack"} == {
        "checkpoint": fingerprint,
        "max_batch": max_batch,
    }
    stack = policy.identity["model_stack"]
    assert stack["device"] == "cpu" and "torch" in stack["packages"]


def lerobot_checkpoint_errors(policy_type: str, other_type: str, no_config: str) -> list[tuple]:
    """``(make(tmp_path) -> folder, what the serve command says)`` for the folders a LeRobot plugin's server refuses
    before torch is imported: none, no ``config.json`` (``no_config``: the plugin's hint), another policy type,
    no processor files, and a good one where there is no torch (this Python: the simulator's)."""
    return [
        (lambda tmp: tmp / "nowhere", "no checkpoint folder at"),
        (lambda tmp: lerobot_folder(tmp / "c", None), no_config),
        (lambda tmp: lerobot_folder(tmp / "c", other_type), f"holds a {other_type} policy, not a {policy_type} one"),
        (lambda tmp: lerobot_folder(tmp / "c", policy_type, ("model.safetensors",)), "has no policy_preprocessor.json"),
        (lambda tmp: lerobot_folder(tmp / "c", policy_type), "run this with the model environment's python"),
    ]


def check_serve_refuses(plugin_root: Path, tmp_path: Path, policy: str, folder: Path, fragment: str) -> None:
    """``conflictbench-serve POLICY --checkpoint FOLDER`` (:func:`serve_command`) exits 2 with one line saying
    ``fragment``, and nothing on stdout."""
    done = serve_command(plugin_root, tmp_path, policy, "--checkpoint", str(folder))
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("conflictbench-serve: ") and fragment in done.stderr and done.stdout == ""


@contextmanager
def server_in_thread(make_server: Callable[[], Any]) -> Iterator[tuple[Any, int]]:
    """A protocol server of conflictbench-serving (``make_server()``: anything with ``run(host, port, stop,
    on_ready)``), built and run in its own event loop in a thread, on a free port of 127.0.0.1: ``(server, port)``;
    stopped after, and its thread gone."""
    bound, ready = {}, threading.Event()

    def main() -> None:
        async def go() -> None:
            bound["stop"], bound["loop"] = asyncio.Event(), asyncio.get_running_loop()
            server = bound["server"] = make_server()
            await server.run("127.0.0.1", 0, bound["stop"], lambda host, port: (bound.update(port=port), ready.set()))

        asyncio.run(go())

    thread = threading.Thread(target=main, daemon=True)
    thread.start()
    assert ready.wait(10)
    try:
        yield bound["server"], bound["port"]
    finally:
        bound["loop"].call_soon_threadsafe(bound["stop"].set)
        thread.join(10)
        assert not thread.is_alive()
