"""Tiny random-weight LeRobot checkpoints of every tested policy type, built once per test session.

``tiny_lerobot_checkpoints`` (session) maps each type of ``TINY_TYPES`` to its checkpoint folder, all built by
``tiny_lerobot.py`` in one model-environment process (about 20 s here). Each folder carries the hub-cache stand-ins
its type loads by name in ``<folder>/hub`` (``tiny_lerobot.hub_cache``). ``tiny_lerobot_env`` (session) maps each
type to the variables a model-environment process (our server, a direct LeRobot call) needs to load that
checkpoint, on top of ``os.environ``: offline, ``HF_HUB_CACHE`` naming that hub cache, one CPU thread, the bfloat16
guard, and ``tiny_patches`` plus this folder on ``PYTHONPATH`` (pi0.5's tiny sizes are a patch applied at import:
``tiny_patches/sitecustomize.py``). ``LEROBOT.env(checkpoint)`` gives the same with ``os.environ`` included, and
``LEROBOT.use(monkeypatch, checkpoint)`` sets it on this process, so a server it starts inherits it. Both
fixtures skip where ``.venv/models/lerobot`` is missing (``scripts/setup.sh --models lerobot``).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from pathlib import Path

import pytest

from conflictbench.testing import BASE_ENV, ModelEnvironment

TESTS = Path(__file__).resolve().parent
BUILDER = TESTS / "tiny_lerobot.py"
PATCHES = TESTS / "tiny_patches"
#: The policy types this plugin is tested with (tiny_lerobot.TYPES).
TINY_TYPES = ("act", "diffusion", "smolvla", "pi05", "xvla", "multi_task_dit")
#: One process builds them all; importing torch and LeRobot is most of it.
BUILD_TIMEOUT_S = 600


def hub_cache(checkpoint: Path) -> Path:
    """The hub cache a tiny checkpoint carries (tiny_lerobot.hub_cache, restated: this module runs outside the
    model environment and cannot import the builder)."""
    return Path(checkpoint) / "hub"


def model_process_env(checkpoint: Path | None) -> dict[str, str]:
    """What a model-environment process loading ``checkpoint`` needs beyond ``BASE_ENV``."""
    env = {"PYTHONPATH": os.pathsep.join([str(PATCHES), str(TESTS)])}
    if checkpoint is not None:
        env["HF_HUB_CACHE"] = str(hub_cache(checkpoint))
    return env


LEROBOT = ModelEnvironment("lerobot", TESTS, extra=model_process_env)
if LEROBOT.missing and (TESTS.parents[2] / ".venv" / "models" / "lerobot" / "bin" / "python").exists():
    # Tests run by another environment's Python (CI's 3.12 pass, .venv312) use the checkout's model environment.
    LEROBOT.python = TESTS.parents[2] / ".venv" / "models" / "lerobot" / "bin" / "python"
model_env_missing, MODEL_ENV_REASON, needs_model_env = LEROBOT.missing, LEROBOT.reason, LEROBOT.needs

#: What the last session's build said, per type (its seconds, its digest), for reports.
build_report: dict[str, dict] = {}


def parse_lines(output: str) -> dict[str, dict]:
    """The builder's JSON lines (one a type), by type; LeRobot's and transformers' chatter is skipped."""
    found = {}
    for line in output.splitlines():
        if line.startswith("{"):
            entry = json.loads(line)
            found[entry["type"]] = entry
    return found


@pytest.fixture(scope="session")
def tiny_lerobot_checkpoints(tmp_path_factory) -> dict[str, Path]:
    if model_env_missing:
        pytest.skip(MODEL_ENV_REASON)
    root = tmp_path_factory.mktemp("tiny-lerobot")
    start = time.perf_counter()
    done = LEROBOT.run([str(BUILDER), "--type", *TINY_TYPES, "--out", str(root)], timeout=BUILD_TIMEOUT_S)
    build_report.update(parse_lines(done.stdout))
    build_report["all"] = {"seconds": time.perf_counter() - start}
    folders = {policy_type: root / policy_type for policy_type in TINY_TYPES}
    missing = [policy_type for policy_type, folder in folders.items() if not (folder / "config.json").is_file()]
    if missing:
        pytest.fail(f"tiny_lerobot.py built no checkpoint of {missing}:\n{done.stdout[-3000:]}", pytrace=False)
    return folders


@pytest.fixture(scope="session")
def tiny_lerobot_env(tiny_lerobot_checkpoints) -> dict[str, Mapping[str, str]]:
    return {
        policy_type: {**BASE_ENV, **model_process_env(folder)}
        for policy_type, folder in tiny_lerobot_checkpoints.items()
    }
