"""The subject's network in NumPy: what runs in the benchmark, with no deep-learning library in the process.

A small transformer encoder over one token per instruction word, one per scene entity and one for the arm;
the arm token's output is read out as a chunk of actions. ``train_torch.py`` defines the same network in
PyTorch (a test holds the two to the same outputs) and writes the weights this module reads.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

TEXT, ARM = 0, 4
"""Token types; entities use their kind (1 object, 2 region, 3 joint)."""


@dataclass(frozen=True)
class Inputs:
    """One batch: B episodes' current frames, padded (word id 0 and kind 0 are padding)."""

    text: np.ndarray  # (B, T) int
    names: np.ndarray  # (B, E, W) int
    kinds: np.ndarray  # (B, E) int
    entities: np.ndarray  # (B, E, ENTITY_NUMBERS) float
    arm: np.ndarray  # (B, ARM_NUMBERS) float


def _layer_norm(x: np.ndarray, gain: np.ndarray, bias: np.ndarray) -> np.ndarray:
    mean = x.mean(-1, keepdims=True)
    var = ((x - mean) ** 2).mean(-1, keepdims=True)
    return (x - mean) / np.sqrt(var + 1e-5) * gain + bias


def _gelu(x: np.ndarray) -> np.ndarray:  # the tanh approximation, as in train_torch.py
    return 0.5 * x * (1.0 + np.tanh(0.7978845608028654 * (x + 0.044715 * x**3)))


class SubjectNetwork:
    """Weights loaded from a ``.npz`` written by ``train_torch.py``."""

    def __init__(self, weights: dict[str, np.ndarray], config: dict):
        self.w = {k: np.asarray(v, dtype=np.float32) for k, v in weights.items()}
        self.config = config
        self.heads = int(config["heads"])
        self.layers = int(config["layers"])
        self.chunk = int(config["chunk"])
        self.bins = int(config["bins"])

    @classmethod
    def load(cls, path: str | Path) -> tuple[SubjectNetwork, tuple[str, ...]]:
        """The network and its vocabulary."""
        with np.load(path, allow_pickle=False) as f:
            config = json.loads(str(f["config"]))
            vocabulary = tuple(str(w) for w in f["vocabulary"])
            weights = {k: f[k] for k in f.files if k not in ("config", "vocabulary")}
        return cls(weights, config), vocabulary

    def _linear(self, x: np.ndarray, name: str) -> np.ndarray:
        return x @ self.w[f"{name}.weight"].T + self.w[f"{name}.bias"]

    def _mlp_in(self, x: np.ndarray, name: str) -> np.ndarray:
        return self._linear(_gelu(self._linear(x, f"{name}.0")), f"{name}.2")

    def tokens(self, inputs: Inputs) -> tuple[np.ndarray, np.ndarray]:
        """(B, 1 + E + T, d) token embeddings and (B, 1 + E + T) validity."""
        w = self.w
        words, types = w["word.weight"], w["kind.weight"]
        text = words[inputs.text] + w["position.weight"][: inputs.text.shape[1]] + types[TEXT]
        name_valid = (inputs.names != 0)[..., None]
        names = (words[inputs.names] * name_valid).sum(-2) / np.maximum(name_valid.sum(-2), 1)
        entities = (inputs.entities - w["entity_mean"]) / w["entity_std"]
        entity = names + types[inputs.kinds] + self._mlp_in(entities, "entity_in")
        arm = self._mlp_in((inputs.arm - w["arm_mean"]) / w["arm_std"], "arm_in") + types[ARM]
        x = np.concatenate([arm[:, None], entity, text], axis=1)
        valid = np.concatenate([np.ones((len(arm), 1), dtype=bool), inputs.kinds != 0, inputs.text != 0], axis=1)
        return x, valid

    def __call__(self, inputs: Inputs, gripper_lead: int = 0, draws: np.ndarray | None = None) -> np.ndarray:
        """(B, chunk, 7) actions: six arm values in [-1, 1] and the gripper (-1 open, +1 closed); see :func:`decode`."""
        x, valid = self.tokens(inputs)
        bias = np.where(valid, 0.0, -1e9).astype(np.float32)[:, None, None, :]
        b, n, d = x.shape
        h = self.heads
        for i in range(self.layers):
            p = f"layers.{i}"
            y = _layer_norm(x, self.w[f"{p}.norm1.weight"], self.w[f"{p}.norm1.bias"])
            qkv = self._linear(y, f"{p}.qkv").reshape(b, n, 3, h, d // h).transpose(2, 0, 3, 1, 4)
            scores = qkv[0] @ qkv[1].transpose(0, 1, 3, 2) / np.sqrt(d // h) + bias
            scores = np.exp(scores - scores.max(-1, keepdims=True))
            attended = (scores / scores.sum(-1, keepdims=True)) @ qkv[2]
            x = x + self._linear(attended.transpose(0, 2, 1, 3).reshape(b, n, d), f"{p}.out")
            y = _layer_norm(x, self.w[f"{p}.norm2.weight"], self.w[f"{p}.norm2.bias"])
            x = x + self._linear(_gelu(self._linear(y, f"{p}.ff1")), f"{p}.ff2")
        y = _layer_norm(x[:, 0], self.w["head_norm.weight"], self.w["head_norm.bias"])
        raw = self._linear(_gelu(self._linear(y, "head.0")), "head.2")
        return decode(raw, self.chunk, self.bins, gripper_lead, draws)


def decode(
    raw: np.ndarray, chunk: int, bins: int, gripper_lead: int = 0, draws: np.ndarray | None = None
) -> np.ndarray:
    """The head's output (B, chunk * (6 * bins + 1)) -> (B, chunk, 7) actions.

    Each arm value is a choice among ``bins`` values evenly spaced over [-1, 1] (a classification, not a
    regression: the expert grasps a bowl at one of several rim points, and the mean of those is the bowl's
    middle, where nothing can be grasped): the most likely bin, refined by the probability-weighted mean of it
    and its neighbours. ``gripper_lead``: action i takes the gripper command predicted for step i + lead (the
    chunk's last at most): switching a few steps before the expert did still grasps (the fingers take ~10
    steps to close), copying its exact moment makes a cloned policy hover short of it.

    ``draws`` (B, chunk), uniform in [0, 1): the gripper closes where its predicted probability of being
    closed exceeds the draw (a sample); None: where it exceeds one half. Sampled because, with noise on what
    it executes, the expert lets go when a tolerance or a timeout says so: over the plate the demonstrations
    hold on for a while, then let go, so every hovering state reads "closed" at ~70 % and a thresholded
    policy holds on forever, a sampled one lets go within a few steps.
    """
    b = len(raw)
    raw = raw.reshape(b, chunk, 6 * bins + 1)
    logits = raw[..., : 6 * bins].reshape(b, chunk, 6, bins)
    centers = np.linspace(-1.0, 1.0, bins)
    best = logits.argmax(-1)
    window = best[..., None] + np.arange(-1, 2)
    inside = (window >= 0) & (window < bins)  # at the first or last bin the window has two bins, not a repeat
    window = np.clip(window, 0, bins - 1)
    near = np.take_along_axis(logits, window, -1)
    weights = np.exp(near - near.max(-1, keepdims=True)) * inside
    arm = (weights * centers[window]).sum(-1) / weights.sum(-1)
    ahead = np.minimum(np.arange(chunk) + gripper_lead, chunk - 1)
    closed = raw[:, ahead, -1]  # the logit of "closed"; compared as logits: no overflow on a confident one
    if draws is None:
        threshold = np.zeros((b, chunk))
    else:
        draws = np.asarray(draws, dtype=np.float64).reshape(b, chunk)
        with np.errstate(divide="ignore"):  # a draw of 0 is -inf: closed whatever the logit
            threshold = np.log(draws) - np.log1p(-draws)
    gripper = np.where(closed > threshold, 1.0, -1.0)[..., None]
    return np.concatenate([arm, gripper], axis=-1)
