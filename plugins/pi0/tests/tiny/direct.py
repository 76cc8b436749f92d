"""The direct call: a LeRobot pi checkpoint run the way LeRobot runs it, one request at a time, no server.

    .venv/models/pi0/bin/python plugins/pi0/tests/tiny/direct.py --checkpoint DIR --requests IN.msgpack \\
        --out OUT.npz

IN.msgpack is a list of openpi observations (packed with ``conflictbench_pi0.protocol``); OUT.npz holds
``actions`` (requests x n_action_steps x action_dim, float32, env units) and ``seconds`` (per request).
This is the independent counterpart the served path (``conflictbench_pi0.backend``) is compared with, so it
shares none of its code: the observation goes through LeRobot's own environment conversion
(``lerobot.envs.utils.preprocess_observation``: HWC uint8 -> CHW float in [0, 1], agent_pos -> state), then
the checkpoint's saved preprocessor, ``predict_action_chunk`` on a batch of one, and the saved postprocessor.
Sampling follows the backend's documented rule, written out again here: pi0/pi0.5 noise is
``torch.randn((chunk_size, max_action_dim))`` from a CPU ``torch.Generator`` seeded with the request's
``conflictbench/noise_seed`` (0 when absent) modulo 2**64; pi0-FAST with temperature > 0 seeds torch's global
RNG with it (inside ``fork_rng``) before the call.

Tiny test checkpoints also need ``tests/tiny/patches`` on ``PYTHONPATH`` (see ``patches/sitecustomize.py``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import msgpack
import numpy as np

# The wire keys, spelled out: this script must not depend on the plugin's code beyond the file format.
IMAGE, WRIST_IMAGE, STATE, PROMPT = "observation/image", "observation/wrist_image", "observation/state", "prompt"
NOISE_SEED = "conflictbench/noise_seed"
IMAGES_PREFIX = "observation.images."


def read_requests(path: Path) -> list[dict]:
    """openpi's msgpack-numpy frames: arrays are ``{__ndarray__, data, dtype, shape}`` maps."""

    def decode(obj):
        if b"__ndarray__" in obj:
            return np.frombuffer(obj[b"data"], dtype=np.dtype(obj[b"dtype"])).reshape(obj[b"shape"])
        if b"__npgeneric__" in obj:
            return np.dtype(obj[b"dtype"]).type(obj[b"data"])
        return obj

    return msgpack.unpackb(path.read_bytes(), object_hook=decode)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--requests", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)

    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.utils import preprocess_observation
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    torch.set_num_threads(1)
    config = PreTrainedConfig.from_pretrained(str(args.checkpoint))
    config.device = "cpu"
    policy = get_policy_class(config.type).from_pretrained(str(args.checkpoint), config=config)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(args.checkpoint))
    cameras = [name for name, feature in policy.config.image_features.items() if "empty_camera" not in name]
    sampled_tokens = config.type == "pi0_fast" and config.temperature > 0

    actions, seconds = [], []
    for request in read_requests(args.requests):
        start = time.perf_counter()
        pixels = {
            cameras[0].removeprefix(IMAGES_PREFIX): np.array(request[IMAGE])[None],
            cameras[1].removeprefix(IMAGES_PREFIX): np.array(request[WRIST_IMAGE])[None],
        }
        state = np.asarray(request[STATE], dtype=np.float32)[None]
        observation = preprocess_observation({"pixels": pixels, "agent_pos": state})
        batch = preprocessor({**observation, "task": request[PROMPT]})
        seed = int(request.get(NOISE_SEED, 0)) % 2**64
        with torch.random.fork_rng(devices=[]), torch.inference_mode():
            if config.type == "pi0_fast":
                if sampled_tokens:
                    torch.manual_seed(seed)
                chunk = policy.predict_action_chunk(batch)
            else:
                generator = torch.Generator().manual_seed(seed)
                noise = torch.randn((1, config.chunk_size, config.max_action_dim), generator=generator)
                chunk = policy.predict_action_chunk(batch, noise=noise)
            chunk = postprocessor(chunk)[:, : config.n_action_steps]
        actions.append(chunk[0].to(torch.float32).numpy())
        seconds.append(time.perf_counter() - start)
    np.savez(args.out, actions=np.stack(actions), seconds=np.array(seconds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
