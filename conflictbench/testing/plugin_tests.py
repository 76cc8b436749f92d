"""Checks every served model plugin's tests make, written once (tests only: nothing at run time imports this).

- :func:`play_pinned_actions`: a policy started for a tiny checkpoint plays the actions pinned in its golden file
  (:func:`~conflictbench.testing.check_pinned_actions`), then its server is stopped, however the check ends;
- :func:`lerobot_folder`: a folder laid out as a LeRobot checkpoint (empty files), for the checks of a folder;
- :func:`serve_command`: ``conflictbench-serve ARGV`` in this Python with the entry point the plugin's server half
  declares (``plugins/NAME/server/pyproject.toml``), as its model environment has it: the checks a folder passes
  before torch is imported can be tested in the simulator's environment, which holds the client half only.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

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
