"""LeRobot checkpoints as every model plugin's server loads them.

A LeRobot checkpoint is a folder with ``config.json`` (its ``type``), ``model.safetensors`` and the processor
pipelines (``policy_preprocessor.json``, ``policy_postprocessor.json`` and their state files: the normalization
statistics), as ``save_pretrained`` writes them. :func:`check_checkpoint` checks one without torch (the client
does, before starting a server); :func:`load_policy` loads it with its processors (torch and LeRobot imported
only there).
"""

from __future__ import annotations

import contextlib
import io
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .checkpoints import CheckpointError, fingerprint

WEIGHTS_FILE = "model.safetensors"
PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")
#: Lines LeRobot's ``from_pretrained`` prints, instead of raising, when the weights did not load.
_WEIGHT_FAILURES = ("Could not load state dict", "Returning model without loading pretrained weights")


def checkpoint_type(folder: Path, not_lerobot_hint: str = "") -> str:
    """The ``type`` in the folder's ``config.json``; :class:`CheckpointError` if there is none to read
    (``not_lerobot_hint`` is added where the folder has no ``config.json``: what else it may be)."""
    folder = Path(folder).expanduser()
    if not folder.is_dir():
        raise CheckpointError(f"no checkpoint folder at {folder}")
    config = folder / "config.json"
    try:
        kind = json.loads(config.read_text()).get("type")
    except FileNotFoundError:
        raise CheckpointError(f"{folder} is not a LeRobot checkpoint (no config.json){not_lerobot_hint}") from None
    except (OSError, ValueError, AttributeError) as exc:
        raise CheckpointError(f"cannot read {config}: {exc}") from None
    return kind or "untyped"


def check_checkpoint(
    folder: Path, types: Iterable[str], files: Iterable[str] = (WEIGHTS_FILE, *PROCESSOR_FILES), hint: str = ""
) -> Path:
    """The folder, checked to hold a LeRobot checkpoint of one of ``types`` with ``files``."""
    folder = Path(folder).expanduser()
    kind, types = checkpoint_type(folder, hint), tuple(types)
    if kind not in types:
        raise CheckpointError(f"{folder} holds a {kind} policy, not a {' or '.join(types)} one")
    for name in files:
        if not (folder / name).is_file():
            raise CheckpointError(f"{folder} has no {name}")
    return folder


def checkpoint_fingerprint(folder: Path) -> str:
    """A digest of what decides the actions: config, weights, processor files (statistics), by content."""
    folder = Path(folder).expanduser()
    return fingerprint([folder / "config.json", folder / WEIGHTS_FILE, *sorted(folder.glob("policy_*processor*"))])


def camera_order(names: list[str]) -> list[str]:
    """A checkpoint's two camera inputs as (agentview, wrist): the one named like a wrist camera (``wrist`` in
    its name, or LeRobot's LIBERO ``...image2``) takes the wrist image; with no such name, the config's order."""
    wrist = [n for n in names if "wrist" in n.lower()] or [n for n in names if n.endswith("image2")]
    if len(wrist) != 1:
        return list(names)
    return [next(n for n in names if n != wrist[0]), wrist[0]]


def refuse_unloaded_weights(printed: str, folder: Path, policy_type: str) -> None:
    """:class:`CheckpointError` where ``printed`` (what loading ``folder`` wrote to stdout) says its weights did not
    load: LeRobot prints that and goes on with random weights instead of raising."""
    failure = next((line for line in printed.splitlines() if any(m in line for m in _WEIGHT_FAILURES)), None)
    if failure is not None:
        raise CheckpointError(f"{folder / WEIGHTS_FILE} does not fit the {policy_type} model: {failure}")


def load_policy(folder: Path, policy_type: str, device: str) -> tuple[Any, Any, Any]:
    """(policy, preprocessor, postprocessor) of the checkpoint, on ``device``, in eval mode; CheckpointError
    where LeRobot cannot load it (LeRobot prints some failures instead of raising: those count too)."""
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    config = PreTrainedConfig.from_pretrained(str(folder))
    config.device = device
    log = io.StringIO()
    try:
        with contextlib.redirect_stdout(log):  # LeRobot prints banners, and prints (not raises) load failures
            policy = get_policy_class(policy_type).from_pretrained(str(folder), config=config)
    except OSError as error:  # a base model or processor it names is not in the Hugging Face cache
        raise CheckpointError(f"cannot load {folder}: {str(error).splitlines()[0]}") from None
    refuse_unloaded_weights(log.getvalue(), folder, policy_type)
    policy.to(device)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(
        policy.config,
        pretrained_path=str(folder),
        preprocessor_overrides={"device_processor": {"device": device}},
    )
    return policy, preprocessor, postprocessor
