"""The backend's episode bookkeeping, exercised on a real checkpoint (model environment; run by test_lerobot_backend).

    .venv/models/lerobot/bin/python plugins/lerobot/tests/backend_checks.py CHECKPOINT

prints one JSON object of what was observed: whether two episodes interleaved step by step get the actions each gets
alone, whether a step sent again gets the same answer, what an out-of-order step says, whether the step seed alone
decides a sampled action, and on which steps the policy refilled its queue with and without ``n_action_steps``.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import torch

from conflictbench_lerobot.backend import load_backend
from conflictbench_lerobot.protocol import CAMERAS, DEFAULT_CAMERA_NAMES, request

STEPS = 8


def step_request(episode: str, step: int, seed: int, n_action_steps: int = 0, salt: int = 0) -> dict:
    rng = np.random.default_rng([step, salt])
    state = {"robot_state/eef/pos": rng.normal(size=3), "robot_state/eef/quat": rng.normal(size=4),
             "robot_state/eef/mat": rng.normal(size=(3, 3)), "robot_state/gripper/qpos": rng.normal(size=2),
             "robot_state/gripper/qvel": rng.normal(size=2), "robot_state/joints/pos": rng.normal(size=7),
             "robot_state/joints/vel": rng.normal(size=7)}  # fmt: skip
    images = tuple(rng.integers(0, 256, (96, 96, 3), dtype=np.uint8) for _ in CAMERAS)
    return request(images, state, "put the bowl on the plate", episode=episode, step=step, seed=seed,
                   camera_names=DEFAULT_CAMERA_NAMES, rename_map={}, n_action_steps=n_action_steps)  # fmt: skip


def main() -> None:
    torch.set_num_threads(1)
    backend = load_backend(sys.argv[1], "cpu")
    act = lambda r: backend.infer_batch([r])[0]  # noqa: E731

    alone = {name: [act(step_request(name, t, 1000 * salt + t, salt=salt)) for t in range(STEPS)]
             for salt, name in ((1, "alone-a"), (2, "alone-b"))}  # fmt: skip
    together = {"a": [], "b": []}
    for t in range(STEPS):
        together["a"].append(act(step_request("together-a", t, 1000 + t, salt=1)))
        together["b"].append(act(step_request("together-b", t, 2000 + t, salt=2)))
    interleaved_same = all(
        np.array_equal(x, y) for key, name in (("a", "alone-a"), ("b", "alone-b"))
        for x, y in zip(together[key], alone[name])
    )  # fmt: skip

    again_request = step_request("again", 0, 5)
    first, again = act(again_request), act(again_request)
    try:
        act(step_request("again", 3, 8))
        out_of_order = ""
    except ValueError as error:
        out_of_order = str(error)

    seeded = [act(step_request(f"seed-{i}", 0, seed)) for i, seed in enumerate((11, 11, 12))]

    def refills(n_action_steps: int) -> list[int]:
        name, found = f"refill-{n_action_steps}", []
        for t in range(STEPS):
            act(step_request(name, t, t, n_action_steps))
            state = backend.episodes[name].policy.__dict__
            queue = state.get("_action_queue", (state.get("_queues") or {}).get("action"))
            found.append(len(queue))
        return found

    lengths, lengths_n2 = refills(0), refills(2)
    try:
        act(step_request("third", 0, 1, n_action_steps=3))
        third = ""
    except ValueError as error:
        third = str(error)

    print(json.dumps({
        "interleaved_same": interleaved_same,
        "again_same": bool(np.array_equal(first, again)),
        "out_of_order": out_of_order,
        "same_seed_same": bool(np.array_equal(seeded[0], seeded[1])),
        "other_seed_differs": not np.array_equal(seeded[0], seeded[2]),
        "queue_lengths": lengths,
        "queue_lengths_n2": lengths_n2,
        "third_n_action_steps": third,
        "dtype": str(first.dtype), "shape": list(first.shape),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
