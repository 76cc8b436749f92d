"""A LeRobot pi0 / pi0.5 / pi0-FAST checkpoint as a batch function of openpi observations (model env only).

The server side of openpi's split: openpi's LIBERO client has already rotated both images by 180 degrees and
letterboxed them to 224 x 224, and built the 8-D state and the prompt; the server's policy transforms
normalize the inputs, run the model and un-normalize the actions. Here LeRobot does those last steps with
what the checkpoint itself saved: the policy class of its config type (``from_pretrained``) and its
pre/post-processor pipelines (``make_pre_post_processors(config, pretrained_path=...)``: tokenizer,
normalization statistics, un-normalization).

Observations enter as LeRobot's environment path makes them (``lerobot.envs.utils.preprocess_observation``):
HWC uint8 images become CHW float32 in [0, 1]; of the checkpoint's two camera inputs the one named like a
wrist camera (``wrist`` in its name, or LeRobot's LIBERO ``observation.images.image2``) gets the wrist image
and the other the agentview image (with no such name, the config's order), and ``task`` is the list of
prompts. The model's own letterbox to its ``image_resolution`` is then an exact no-op at 224.

Sampling depends on the request, never on the call order or batch company: pi0 and pi0.5 get their
flow-matching noise from a ``torch.Generator`` seeded with the request's ``NOISE_SEED`` (seed 0 when the
request has none), drawn as one standard-normal (chunk_size, max_action_dim) float32 array per request on the
CPU; pi0-FAST decodes greedily (batched as is) unless its temperature is above 0, when each request runs alone
inside ``torch.random.fork_rng`` seeded the same way. Seeds are taken modulo 2**64.

Imports torch and LeRobot only inside :func:`load_backend`, so the pure checks below can run anywhere.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from conflictbench_serving.checkpoints import reduce_seed
from conflictbench_serving.lerobot import camera_order, load_policy
from conflictbench_serving.seeding import row_noise

from .checkpoints import POLICY_TYPES, CheckpointError, checkpoint_type, fingerprint
from .protocol import IMAGE, NOISE_SEED, PROMPT, STATE, STATE_SIZE, WRIST_IMAGE, validate_request

__all__ = [
    "POLICY_TYPES",
    "CheckpointError",
    "PiBackend",
    "camera_order",
    "checkpoint_type",
    "load_backend",
    "noise_for_seed",
]

#: The processor pipelines LeRobot saves beside the weights; without them there are no normalization stats.
PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")


def request_seed(request: dict) -> int:
    """The request's noise seed (``NOISE_SEED``, default 0), reduced to torch's seed range."""
    return reduce_seed(request.get(NOISE_SEED))


def noise_for_seed(seed: int, chunk_size: int, max_action_dim: int):
    """The flow-matching noise of one request: standard normal, from a CPU generator seeded with ``seed``."""
    return row_noise(seed, (chunk_size, max_action_dim))


def image_feature_names(config_features: dict[str, Any]) -> list[str]:
    """The checkpoint's camera inputs in its order (LeRobot's padding cameras ``empty_camera_*`` left out)."""
    names = []
    for name, feature in config_features.items():
        kind = feature["type"] if isinstance(feature, dict) else feature.type.value
        if str(kind).endswith("VISUAL") and "empty_camera" not in name:
            names.append(name)
    return names


def _check_inputs(folder: Path) -> None:
    """Two cameras and an 8-D state, read from config.json (CheckpointError naming what it has otherwise)."""
    config = json.loads((folder / "config.json").read_text())
    features = config.get("input_features") or {}
    cameras = image_feature_names(features)
    if len(cameras) != 2:
        raise CheckpointError(
            f"{folder} takes {len(cameras)} camera image(s) ({', '.join(cameras) or 'none'}); "
            "openpi's LIBERO client sends 2 (agentview, wrist)"
        )
    state = features.get("observation.state")
    state_shape = list(state.get("shape", [])) if isinstance(state, dict) else None
    if state_shape != [STATE_SIZE]:
        raise CheckpointError(
            f"{folder} takes a state of shape {state_shape}; openpi's LIBERO client sends {STATE_SIZE} numbers"
        )
    for name in PROCESSOR_FILES:
        if not (folder / name).is_file():
            raise CheckpointError(f"{folder} has no {name} (LeRobot >= 0.4 saves its normalization stats there)")


class PiBackend:
    """One loaded checkpoint: :meth:`infer_batch` runs one forward pass for any number of requests."""

    def __init__(self, checkpoint: Path, policy, preprocessor, postprocessor, device: str) -> None:
        import lerobot

        config = policy.config
        self.policy_type: str = config.type
        self.action_dim: int = int(config.output_features["action"].shape[0])
        self.chunk_length: int = int(config.n_action_steps)
        self.image_keys: list[str] = camera_order(image_feature_names(config.input_features))
        self.metadata: dict = {
            "policy_type": self.policy_type,
            "checkpoint": str(checkpoint),
            "checkpoint_fingerprint": fingerprint(checkpoint),
            "action_dim": self.action_dim,
            "action_horizon": self.chunk_length,
            "image_keys": list(self.image_keys),
            "lerobot_version": str(lerobot.__version__),
        }
        self._policy = policy
        self._preprocessor = preprocessor
        self._postprocessor = postprocessor
        self._device = device
        self._samples_tokens = self.policy_type == "pi0_fast" and float(config.temperature) > 0

    def infer_batch(self, requests: list[dict]) -> list[np.ndarray]:
        """Actions for each request: float32 (chunk_length, action_dim), in env units.

        Each request is an unpacked openpi observation: IMAGE and WRIST_IMAGE (uint8 224 x 224 x 3, already
        rotated and letterboxed by the client), STATE (8,), PROMPT (str) and optionally NOISE_SEED (int;
        0 when absent). A request's actions do not depend on the other requests of the batch.
        """
        import torch

        if not requests:
            return []
        for request in requests:
            validate_request(request)
        with torch.inference_mode():
            if self._samples_tokens:  # token sampling draws from torch's global RNG: one seeded run each
                # (post-processed one by one too: a relative-actions step remembers the last state it saw)
                actions = torch.cat([self._postprocessor(self._sample_alone(request)) for request in requests])
            else:
                actions = self._postprocessor(self._predict(requests))
        actions = actions[:, : self.chunk_length].to("cpu", torch.float32).numpy()
        return [np.array(chunk) for chunk in actions]

    def _observation_batch(self, requests: list[dict]) -> dict:
        """LeRobot's batch for these requests, through the checkpoint's own preprocessor."""
        import torch

        def images(key: str):
            stacked = torch.from_numpy(np.stack([np.asarray(request[key]) for request in requests]))
            return stacked.permute(0, 3, 1, 2).contiguous().to(torch.float32) / 255.0

        states = np.stack([np.asarray(request[STATE], dtype=np.float32) for request in requests])
        batch = {
            self.image_keys[0]: images(IMAGE),
            self.image_keys[1]: images(WRIST_IMAGE),
            "observation.state": torch.from_numpy(states),
            "task": [request[PROMPT] for request in requests],
        }
        return self._preprocessor(batch)

    def _predict(self, requests: list[dict]):
        import torch

        batch = self._observation_batch(requests)
        if self.policy_type == "pi0_fast":
            return self._policy.predict_action_chunk(batch)
        config = self._policy.config
        noise = torch.stack(
            [noise_for_seed(request_seed(r), config.chunk_size, config.max_action_dim) for r in requests]
        )
        return self._policy.predict_action_chunk(batch, noise=noise.to(self._device))

    def _sample_alone(self, request: dict):
        import torch

        devices = [torch.device(self._device).index or 0] if self._device.startswith("cuda") else []
        with torch.random.fork_rng(devices=devices):
            torch.manual_seed(request_seed(request))
            return self._predict([request])


def load_backend(checkpoint: Path, device: str = "cpu") -> PiBackend:
    """Load a LeRobot pi checkpoint folder with its saved processors; CheckpointError if it is not usable."""
    folder = Path(checkpoint).expanduser()
    policy_type = checkpoint_type(folder)
    _check_inputs(folder)

    policy, preprocessor, postprocessor = load_policy(folder, policy_type, device)
    return PiBackend(folder, policy, preprocessor, postprocessor, device)
