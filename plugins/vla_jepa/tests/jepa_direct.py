"""The in-process side of the served-vs-direct comparison (model environment only).

    python jepa_direct.py CHECKPOINT REQUESTS.npz MAX_BATCH OUT.npz

For each request row (``images``, ``wrist_images``, ``states``, ``seeds``, and ``instructions`` as JSON) writes:
``lerobot_alone``, LeRobot's own sampling for that row alone (``torch.manual_seed(seed)``, then
``predict_action_chunk`` untouched, on a batch built here under LeRobot's LIBERO camera names); ``backend_alone``,
our backend's chunk for the row alone; ``backend_served``, our backend's chunk in a call of the server's fixed
shape (the row padded with copies); ``backend_in_company``, the row's chunk in a call beside a row with a much
longer instruction; ``executed``, LeRobot's postprocessor applied to the served chunk (the actions LeRobot itself
would execute).
"""

from __future__ import annotations

import json
import sys

import numpy as np
import torch

from conflictbench_vla_jepa.backend import load_backend
from conflictbench_vla_jepa.protocol import Row


def main(checkpoint: str, requests_path: str, max_batch: int, out: str) -> None:
    torch.set_num_threads(1)
    backend = load_backend(checkpoint)
    data = np.load(requests_path)
    instructions = json.loads(str(data["instructions"]))
    rows = [
        Row(
            data["images"][i],
            data["wrist_images"][i],
            data["states"][i].astype(np.float32),
            instructions[i],
            int(data["seeds"][i]),
        )  # fmt: skip
        for i in range(len(instructions))
    ]
    from lerobot.policies.factory import make_pre_post_processors

    _, postprocessor = make_pre_post_processors(backend._policy.config, pretrained_path=checkpoint)
    results = {"lerobot_alone": [], "backend_alone": [], "backend_served": [], "backend_in_company": [], "executed": []}
    other = Row(rows[0].wrist_image, rows[0].image, rows[0].state[::-1].copy(), "a much longer instruction " * 4, 99)
    for row in rows:
        batch = {
            "observation.images.image": torch.from_numpy(row.image).permute(2, 0, 1)[None].float() / 255.0,
            "observation.images.image2": torch.from_numpy(row.wrist_image).permute(2, 0, 1)[None].float() / 255.0,
            "observation.state": torch.from_numpy(row.state)[None],
            "task": [row.instruction],
        }
        torch.manual_seed(row.seed)
        with torch.inference_mode():
            results["lerobot_alone"].append(
                backend._policy.predict_action_chunk(backend._preprocessor(batch)).numpy()[0]
            )
        results["backend_alone"].append(backend.infer_batch([row])[0])
        served = backend.infer_batch([row] * max_batch)[0]
        results["backend_in_company"].append(backend.infer_batch([row, other])[0])
        results["backend_served"].append(served)
        results["executed"].append(postprocessor(torch.from_numpy(served)[None]).numpy()[0])
    np.savez(out, **{name: np.stack(values) for name, values in results.items()})


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4])
