"""What UniVLA's LIBERO evaluation does around the model, step by step (pinned by ``tests/test_univla_processing.py``).

The facts, from OpenDriveLab/UniVLA ``experiments/robot/libero/run_libero_eval.py`` and ``experiments/robot/
openvla_utils.py`` (``docs/upstream/openvla_oft_univla.md``, section 5, has the lines):

- **image**: the agentview camera only, as OpenVLA's client prepares it (upright, JPEG round trip, Lanczos to 224,
  centre crop of 0.9 of the area): ``conflictbench.hosting.openvla_family``;
- **prompt**: OpenVLA's, and from an episode's second query on, ``History action`` and the previous query's four
  latent action tokens, concatenated (``<ACT_3><ACT_12><ACT_0><ACT_7>``; token id ``32001 + k`` is ``<ACT_k>``):
  ``In: What action should the robot take to {task lower-cased}? History action {tokens}\\nOut:``;
- **latent tokens**: sampled with temperature 0.75 and top-p 0.9 (upstream seeds once per run, so a query's
  sample depends on every query before it; ours seeds each from the episode and step);
- **action decoder**: a chunk of ``window`` (12) normalized actions per query; the last ``window`` chunks are
  ensembled, the newest weighted ``exp(0)``, the one before ``exp(-0.1)``, ... (:class:`TemporalEnsemble`), in
  normalized space, then q01/q99 un-normalization where the mask keeps; one action per environment step;
- **gripper** as OpenVLA's; **steps** 240 / 300 / 320 / 550; the history and the window reset with each episode.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

UNIVLA_MAX_STEPS = {"libero_spatial": 240, "libero_object": 300, "libero_goal": 320, "libero_10": 550}
LATENT_TOKEN_OFFSET = 32001
LATENT_CODES = 32  # <ACT_0> .. <ACT_31>, the list upstream's loop de-tokenizes with
LATENT_TOKENS = 4
WINDOW = 12
BALANCING_FACTOR = 0.1


def unreadable_tokens(token_ids: Sequence[int]) -> list[int]:
    """The ids that are no ``<ACT_k>`` (``32001 + k``, k < 32): upstream's loop looks each up in its list of 32
    (``run_libero_eval.py:231, 322``), an IndexError past ``<ACT_31>`` (``predict_latent_action`` keeps only ids
    above 32000)."""
    return [int(token) for token in token_ids if not 0 <= int(token) - LATENT_TOKEN_OFFSET < LATENT_CODES]


def history_text(token_ids: Sequence[int]) -> str:
    """The prompt's history for the latent tokens a query generated: ``<ACT_k>`` for id ``32001 + k``, joined."""
    return "".join(f"<ACT_{int(token) - LATENT_TOKEN_OFFSET}>" for token in token_ids)


V01_SYSTEM_PROMPT = (
    "A chat between a curious user and an artificial intelligence assistant. "
    "The assistant gives helpful, detailed, and polite answers to the user's questions."
)


def prompt(instruction: str, history: str, v01: bool = False) -> str:
    """UniVLA's prompt: OpenVLA's, with the previous query's latent tokens once there are any (that form also for a
    checkpoint whose path says ``openvla-v01``, which otherwise gets OpenVLA v0.1's template, as upstream's)."""
    task = instruction.lower()
    if history:
        return f"In: What action should the robot take to {task}? History action {history}\nOut:"
    if v01:
        return f"{V01_SYSTEM_PROMPT} USER: What action should the robot take to {task}? ASSISTANT:"
    return f"In: What action should the robot take to {task}?\nOut:"


class TemporalEnsemble:
    """UniVLA's ``ActionDecoder`` window: each query's chunk of ``window`` actions, aged one row per query; the
    action executed is the weighted mean of what each stored chunk planned for now (newest weighted most)."""

    def __init__(self, window: int = WINDOW):
        self.window = window
        self.valid = np.flip(np.triu(np.ones((window, window), dtype=bool)), axis=1)  # row i plans window - i steps
        self.weights = np.array([np.exp(-1 * BALANCING_FACTOR * i) for i in range(window)])[:, None]
        self.reset()

    def reset(self) -> None:
        self.buffer = np.zeros((self.window, self.window, 7))
        self.mask = np.zeros((self.window, self.window), dtype=bool)

    def add(self, chunk: np.ndarray) -> np.ndarray:
        """Store a new (window, 7) normalized chunk and return the ensembled normalized action (7,)."""
        chunk = np.asarray(chunk, dtype=np.float64)
        if chunk.shape != (self.window, 7):
            raise ValueError(f"expected a chunk of shape ({self.window}, 7), got {chunk.shape}")
        self.buffer[1:] = self.buffer[:-1].copy()  # older chunks move one row down ...
        self.mask[1:] = self.mask[:-1].copy()
        self.buffer[:, :-1] = self.buffer[:, 1:].copy()  # ... and one step on
        self.mask[:, :-1] = self.mask[:, 1:].copy()
        self.mask = self.mask * self.valid
        self.buffer[0], self.mask[0] = chunk, True
        now = self.mask[:, 0:1]
        return np.sum(self.buffer[:, 0, :] * now * self.weights, axis=0) / np.sum(now * self.weights)
