"""A LeRobot GR00T N1.7 checkpoint as a function of request rows (model environment only).

The server side of NVIDIA's split: GR00T's LIBERO client has already turned both images upright (256 px, uint8),
split the state by name and put the text in a list; NVIDIA's server (its sim policy wrapper) runs the model's
processing and answers ``action.<name>`` in the environment's units with the gripper in [0, 1] (the client maps
it to LIBERO's sign). Here LeRobot runs it with what the checkpoint saved: ``from_pretrained`` of its config
type, its preprocessor (state min/max, the VLM's image and prompt processing) and postprocessor (action min/max
back to the dataset's units, which for LeRobot's LIBERO data are the environment's, gripper -1 open / +1 closed).

The row -> LeRobot batch mapping (LeRobot has no code for NVIDIA's keys; this is what its LIBERO path holds):
``video.image`` -> the agentview camera input and ``video.wrist_image`` -> the wrist one (a name with ``wrist``,
else LeRobot's LIBERO ``...image2``), both uint8 CHW; ``state.x ... state.yaw, state.gripper`` concatenated to
the 8-D ``observation.state`` (LeRobot's LIBERO state: position, axis-angle, two gripper joints); the text to
``task``. Back: the postprocessed chunk split into ``action.x ... action.yaw`` and ``action.gripper`` as
``(1 - g) / 2``, NVIDIA's [0, 1] convention (1 open), so the unchanged client recovers the sign LeRobot gave.

Reproducibility. LeRobot ignores any ``noise=``: the action head draws one ``torch.randn`` for the batch, which
conflictbench-serving's :func:`~conflictbench_serving.seeding.seeded_draw` answers with the row's own seeded
noise. And GR00T's processor left-pads every prompt of a batch to the longest, which moves a row's actions
(about 1e-5) with its company's text: so each distinct row runs as its own forward pass (rows of one call run
one after another; the copies that pad a call to its fixed shape are not run again).

Imports torch and LeRobot only inside :func:`load_backend`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from conflictbench_serving.lerobot import camera_order, load_policy
from conflictbench_serving.seeding import row_noise, seeded_draw

from .checkpoints import POLICY_TYPE, CheckpointError, check_checkpoint, fingerprint
from .protocol import ACTION_KEYS, STATE_KEYS, VIDEO_KEYS
from .server import Row


def nvidia_actions(chunk: np.ndarray) -> dict[str, np.ndarray]:
    """A postprocessed (T, 7) chunk in env units as NVIDIA's reply keys, (T, 1) each, gripper in [0, 1]."""
    actions = {key: chunk[:, i : i + 1].astype(np.float32) for i, key in enumerate(ACTION_KEYS[:-1])}
    actions[ACTION_KEYS[-1]] = ((1.0 - chunk[:, 6:7]) / 2.0).astype(np.float32)
    return actions


class GrootBackend:
    """One loaded checkpoint: :meth:`infer_batch` answers each distinct row with its own forward pass."""

    def __init__(self, checkpoint: Path, policy, preprocessor, postprocessor, device: str) -> None:
        import lerobot
        from lerobot.policies.groot import groot_n1_7

        config = policy.config
        cameras = [n for n, f in config.input_features.items() if f.type.value.endswith("VISUAL")]
        if len(cameras) != 2:
            raise CheckpointError(f"{checkpoint} takes {len(cameras)} camera images; GR00T's LIBERO client sends 2")
        self.image_keys = camera_order(cameras)
        heads = [m for m in policy.modules() if isinstance(m, groot_n1_7.GR00TN17ActionHead)]
        if len(heads) != 1:
            raise CheckpointError(f"{checkpoint}: expected one GR00T N1.7 action head, found {len(heads)}")
        self.noise_shape = (int(heads[0].config.action_horizon), int(heads[0].action_dim))
        self.metadata: dict = {
            "policy_type": POLICY_TYPE,
            "checkpoint": str(checkpoint),
            "checkpoint_fingerprint": fingerprint(checkpoint),
            "image_keys": list(self.image_keys),
            "lerobot_version": str(lerobot.__version__),
        }
        self._policy, self._preprocessor, self._postprocessor = policy, preprocessor, postprocessor
        self._head_module = groot_n1_7

    def infer_batch(self, rows: list[Row]) -> list[dict[str, np.ndarray]]:
        answers: dict[int, dict[str, np.ndarray]] = {}
        for row in rows:
            if id(row) not in answers:
                answers[id(row)] = nvidia_actions(self.env_chunk(row))
        return [answers[id(row)] for row in rows]

    def env_chunk(self, row: Row) -> np.ndarray:
        """The postprocessed chunk (T, 7) for one row, in the dataset's (environment's) units."""
        import torch

        obs = row.observation
        image = lambda key: torch.from_numpy(np.ascontiguousarray(obs[key][:, 0])).permute(0, 3, 1, 2)  # noqa: E731
        state = np.concatenate([obs[key][:, 0] for key in STATE_KEYS], axis=-1).astype(np.float32)
        batch = {
            self.image_keys[0]: image(VIDEO_KEYS[0]),
            self.image_keys[1]: image(VIDEO_KEYS[1]),
            "observation.state": torch.from_numpy(state),
            "task": [row.instruction],
        }
        noise = row_noise(row.seed, self.noise_shape)[None]
        with torch.inference_mode(), seeded_draw(self._head_module, noise):
            normalized = self._policy.predict_action_chunk(self._preprocessor(batch))
            actions = self._postprocessor(normalized)
        return actions.to("cpu", torch.float32).numpy()[0]


def load_backend(checkpoint: Path, device: str = "cpu") -> GrootBackend:
    """Load a LeRobot GR00T checkpoint folder with its saved processors; CheckpointError if not usable."""
    folder = check_checkpoint(checkpoint)
    policy, preprocessor, postprocessor = load_policy(folder, POLICY_TYPE, device)
    return GrootBackend(folder, policy, preprocessor, postprocessor, device)
