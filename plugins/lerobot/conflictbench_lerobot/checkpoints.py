"""What a LeRobot checkpoint folder must hold to be played on LIBERO, checked without torch (the client checks before
starting a server, the server before loading).

Any folder LeRobot's ``save_pretrained`` wrote: ``config.json`` (its ``type``), ``model.safetensors`` and the
processor pipelines. Its inputs must be ones LeRobot's LIBERO env gives, as ``lerobot-eval`` names them: the cameras
``observation.images.<name>`` for the names of ``camera_name_mapping`` (``image``, ``image2`` by default), after
``rename_map``. LeRobot's check (``validate_visual_features_consistency``) accepts either set of cameras holding the
other, and so does this one, after renaming (LeRobot skips its check when a ``rename_map`` is given; ours still holds
the renamed names to it: a run that renames a camera nobody takes is refused here). The state is what LeRobot's
LIBERO processors build: 8 values (end-effector position, axis-angle, gripper), or X-VLA's 20; the action has 7
values (LIBERO's arm and gripper), or X-VLA's 20.
"""

from __future__ import annotations

import json
from pathlib import Path

from conflictbench_serving import lerobot
from conflictbench_serving.checkpoints import CheckpointError

__all__ = [
    "KNOWN_TYPES",
    "SUPPORTED_TYPES",
    "CheckpointError",
    "check_checkpoint",
    "check_folder",
    "checkpoint_inputs",
    "fingerprint",
]

#: Every policy type LeRobot 0.6.1 registers (``lerobot/policies/``), and whether this plugin is tested with it.
SUPPORTED_TYPES = ("act", "diffusion", "multi_task_dit", "pi05", "smolvla", "xvla")
KNOWN_TYPES = (
    *SUPPORTED_TYPES,
    *("eo1", "evo1", "fastwam", "gaussian_actor", "groot", "lingbot_va", "molmoact2"),
    *("pi0", "pi0_fast", "tdmpc", "vla_jepa", "vqbet", "wall_x"),
)
#: The state each type's LIBERO processors build (``LiberoProcessorStep``: 8; X-VLA's own build 20, which its model
#: pads to ``max_state_dim`` whatever its config's state feature says: not checked) and the action its
#: policy answers before the environment's post-processor (X-VLA's 20-D ``ee6d`` actions, which its LIBERO
#: post-processor turns into LIBERO's 7: ``policies/xvla/processor_xvla.py``).
STATE_SIZE: dict[str, int | None] = {"xvla": None}
DEFAULT_STATE_SIZE = 8
ACTION_SIZE = {"xvla": 20}
DEFAULT_ACTION_SIZE = 7


def _shape(features: dict, key: str) -> list[int] | None:
    feature = features.get(key)
    return None if not isinstance(feature, dict) else list(feature.get("shape") or [])


def checkpoint_inputs(folder: Path) -> tuple[str, dict, dict]:
    """The folder's policy type and its input and output features (``config.json``)."""
    kind = lerobot.checkpoint_type(folder)
    config = json.loads((folder / "config.json").read_text())
    return kind, dict(config.get("input_features") or {}), dict(config.get("output_features") or {})


def check_folder(folder: str | Path) -> str:
    """The policy type of a LeRobot checkpoint folder of a type LeRobot 0.6.1 has, with its weights; a one-line
    :class:`CheckpointError` otherwise."""
    folder = Path(folder).expanduser()
    kind = lerobot.checkpoint_type(folder)
    if kind not in KNOWN_TYPES:
        raise CheckpointError(f"{folder} holds a {kind} policy, a type LeRobot 0.6.1 does not have")
    if not (folder / lerobot.WEIGHTS_FILE).is_file():
        raise CheckpointError(f"{folder} has no {lerobot.WEIGHTS_FILE}")
    return kind


def check_checkpoint(folder: str | Path, camera_names: dict[str, str], rename_map: dict[str, str]) -> str:
    """The checkpoint's policy type, checked to take what LeRobot's LIBERO env gives (cameras named by
    ``camera_names`` and renamed by ``rename_map``, the state its processors build, 7 actions); a one-line
    :class:`CheckpointError` naming what it expected and what it found otherwise."""
    folder = Path(folder).expanduser()
    check_folder(folder)
    kind, inputs, outputs = checkpoint_inputs(folder)
    given = {rename_map.get(key, key) for key in (f"observation.images.{name}" for name in camera_names.values())}
    cameras = {key for key, feature in inputs.items() if isinstance(feature, dict) and feature.get("type") == "VISUAL"}
    if not cameras:
        raise CheckpointError(f"{folder} takes no camera image; LIBERO gives {', '.join(sorted(given))}")
    if not (cameras <= given or given <= cameras):
        raise CheckpointError(
            f"{folder} takes the cameras {', '.join(sorted(cameras))}; LIBERO gives {', '.join(sorted(given))} "
            "(model.camera_name_mapping and model.rename_map name them)"
        )
    state = _shape(inputs, "observation.state")
    wanted = STATE_SIZE.get(kind, DEFAULT_STATE_SIZE)
    if state is not None and wanted is not None and state != [wanted]:
        raise CheckpointError(
            f"{folder} takes a state of shape {state}; LeRobot's LIBERO processors give the {kind} policy [{wanted}]"
        )
    action, wanted = _shape(outputs, "action"), ACTION_SIZE.get(kind, DEFAULT_ACTION_SIZE)
    if action is not None and action != [wanted]:
        raise CheckpointError(
            f"{folder} answers actions of shape {action}; LeRobot's LIBERO post-processors take [{wanted}] of a "
            f"{kind} policy (LIBERO's arm: 7)"
        )
    return kind


def fingerprint(folder: str | Path) -> str:
    """A digest of what decides the actions: the config, the weights and the processor files, by content."""
    return lerobot.checkpoint_fingerprint(Path(folder))
