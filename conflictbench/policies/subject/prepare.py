"""Recorded demonstrations -> the frame arrays the training environment writes as a LeRobot dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .features import Entities, Vocabulary, arm_numbers, entity_numbers, name_text

TEXT_TOKENS = 32
"""Instruction words kept (the longest base instruction has 19)."""
ENTITY_TOKENS = 32
"""Entities kept per scene (the largest LIBERO scene has 27)."""


def load_demonstrations(folder: Path) -> list[dict]:
    episodes = []
    for path in sorted(Path(folder).glob("*.npz")):
        with np.load(path, allow_pickle=False) as f:
            episodes.append({k: f[k] for k in f.files})
    return episodes


def vocabulary_for(episodes: list[dict], instructions: list[str]) -> Vocabulary:
    """Every word of the base tasks' instructions and of the entities' names."""
    names = [name_text(str(n)) for e in episodes for key in ("objects", "regions", "joints") for n in e[key]]
    return Vocabulary.build([*instructions, *names])


def prepare(episodes: list[dict], vocabulary: Vocabulary) -> dict[str, np.ndarray]:
    """One row per recorded step: the model's inputs, the expert's action, the episode it belongs to."""
    columns: dict[str, list[np.ndarray]] = {k: [] for k in ("text", "names", "kinds", "entities", "arm", "action")}
    episode_index, task = [], []
    for i, e in enumerate(episodes):
        entities = Entities(*(tuple(str(n) for n in e[key]) for key in ("objects", "regions", "joints")))
        if len(entities) > ENTITY_TOKENS:
            raise ValueError(f"{len(entities)} entities in one scene; the subject takes at most {ENTITY_TOKENS}")
        frames = len(e["label"])
        text = np.zeros(TEXT_TOKENS, dtype=np.int64)
        ids = vocabulary.ids(str(e["instruction"]))[:TEXT_TOKENS]
        text[: len(ids)] = ids
        name_ids = entities.name_ids(vocabulary)
        names = np.zeros((ENTITY_TOKENS, name_ids.shape[1]), dtype=np.int64)
        names[: len(entities)] = name_ids
        kinds = np.zeros(ENTITY_TOKENS, dtype=np.int64)
        kinds[: len(entities)] = entities.kinds()
        numbers = entity_numbers(e["object_poses"], e["region_positions"], e["joint_positions"], e["eef_pos"])
        padded = np.zeros((frames, ENTITY_TOKENS, numbers.shape[-1]), dtype=np.float32)
        padded[:, : len(entities)] = numbers
        columns["text"].append(np.broadcast_to(text, (frames, TEXT_TOKENS)))
        columns["names"].append(np.broadcast_to(names, (frames, *names.shape)))
        columns["kinds"].append(np.broadcast_to(kinds, (frames, ENTITY_TOKENS)))
        columns["entities"].append(padded)
        columns["arm"].append(arm_numbers(e["eef_pos"], e["eef_quat"], e["gripper_qpos"]))
        columns["action"].append(e["label"].astype(np.float32))
        episode_index.append(np.full(frames, i, dtype=np.int64))
        task.extend([str(e["instruction"])] * frames)
    out = {k: np.concatenate(v) for k, v in columns.items()}
    out["episode_index"] = np.concatenate(episode_index)
    out["task"] = np.array(task)
    return out


def write_prepared(demonstrations: Path, out: Path, instructions: list[str]) -> Path:
    """``out/prepared.npz``: the frames and the vocabulary their word ids index; returns its path."""
    episodes = load_demonstrations(demonstrations)
    if not episodes:
        raise ValueError(f"no demonstrations under {demonstrations}")
    vocabulary = vocabulary_for(episodes, instructions)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "prepared.npz"
    np.savez(path, **prepare(episodes, vocabulary), vocabulary=np.array(vocabulary.words))
    return path
