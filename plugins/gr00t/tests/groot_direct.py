"""The in-process side of the served-vs-direct comparison (model environment only).

    python groot_direct.py CHECKPOINT REQUESTS.npz OUT.npz

For each request (the ``get_action`` observations our client sent, saved as ``obs<i>/<key>`` arrays with
``texts``, ``seeds`` and ``states``, the episode's own 8-D LIBERO state) writes ``lerobot`` (LeRobot's own
sampling and postprocessing of that row alone, on a batch built here from the camera arrays and the episode's
state under LeRobot's LIBERO names: ``torch.manual_seed(seed)``, then the preprocessor, ``predict_action_chunk``
untouched and the postprocessor), ``backend`` (our backend's chunk for the row as the server received it) and
``in_company_x`` (its ``action.x`` in a call beside a row with a much longer prompt).
"""

from __future__ import annotations

import json
import sys

import numpy as np
import torch

from conflictbench_gr00t.backend import load_backend
from conflictbench_gr00t.protocol import STATE_KEYS, VIDEO_KEYS
from conflictbench_gr00t.server import Row


def main(checkpoint: str, requests_path: str, out: str) -> None:
    torch.set_num_threads(1)
    backend = load_backend(checkpoint)
    data = np.load(requests_path)
    texts, seeds = json.loads(str(data["texts"])), data["seeds"]
    lerobot, ours, in_company = [], [], []
    for i, text in enumerate(texts):
        observation = {key: data[f"obs{i}/{key}"] for key in (*VIDEO_KEYS, *STATE_KEYS)}
        row = Row(observation, text, int(seeds[i]))
        batch = {
            "observation.images.image": torch.from_numpy(observation[VIDEO_KEYS[0]][:, 0]).permute(0, 3, 1, 2),
            "observation.images.image2": torch.from_numpy(observation[VIDEO_KEYS[1]][:, 0]).permute(0, 3, 1, 2),
            "observation.state": torch.from_numpy(data["states"][i : i + 1].astype(np.float32)),
            "task": [text],
        }
        torch.manual_seed(row.seed)
        with torch.inference_mode():
            chunk = backend._postprocessor(backend._policy.predict_action_chunk(backend._preprocessor(batch)))
        lerobot.append(chunk.to(torch.float32).numpy()[0])
        ours.append(backend.env_chunk(row))
        other = Row(observation, "a much longer instruction than the first " * 3, 12345)
        in_company.append(backend.infer_batch([row, other])[0])  # NVIDIA's reply keys, gripper in [0, 1]
    np.savez(out, lerobot=np.stack(lerobot), backend=np.stack(ours),
             in_company_x=np.stack([chunk["action.x"][:, 0] for chunk in in_company]))  # fmt: skip


if __name__ == "__main__":
    main(*sys.argv[1:4])
