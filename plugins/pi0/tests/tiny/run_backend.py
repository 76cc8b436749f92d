"""Runs ``conflictbench_pi0.backend`` on requests, batched and one by one, for the tests (model env only).

    .venv/models/pi0/bin/python plugins/pi0/tests/tiny/run_backend.py --requests IN.msgpack --out-dir D \\
        NAME=CHECKPOINT [NAME=CHECKPOINT ...]

For each checkpoint (one process for all of them: importing torch is most of the time), writes
``D/NAME.npz`` with ``batch`` (every request in one ``infer_batch`` call) and ``singles`` (one call each),
both requests x chunk_length x action_dim, and ``D/NAME.json`` with the backend's metadata, the call times
and the largest change LeRobot's own letterbox makes to a 224-px image at the model's resolution; or, when
``load_backend`` refuses the checkpoint, ``{"error": message}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def letterbox_change(resolution) -> float:
    """Largest change of LeRobot's ``resize_with_pad_torch`` to a random 224 x 224 image (0 = no-op)."""
    import torch
    from lerobot.policies.common.vla_utils import resize_with_pad_torch

    image = torch.rand((2, 224, 224, 3), generator=torch.Generator().manual_seed(0))
    resized = resize_with_pad_torch(image, *resolution)
    if resized.shape != image.shape:
        return float("inf")
    return float((resized - image).abs().max())


def run_one(checkpoint: Path, requests: list[dict], out_dir: Path, name: str) -> None:
    from conflictbench_pi0.backend import CheckpointError, load_backend

    try:
        start = time.perf_counter()
        backend = load_backend(checkpoint)
        load_seconds = time.perf_counter() - start
    except CheckpointError as error:
        (out_dir / f"{name}.json").write_text(json.dumps({"error": str(error)}))
        return
    backend.infer_batch(requests[:1])  # first call pays one-off costs; keep it out of the timings
    start = time.perf_counter()
    batch = backend.infer_batch(requests)
    batch_seconds = time.perf_counter() - start
    singles, single_seconds = [], []
    for request in requests:
        start = time.perf_counter()
        singles.append(backend.infer_batch([request])[0])
        single_seconds.append(time.perf_counter() - start)
    np.savez(out_dir / f"{name}.npz", batch=np.stack(batch), singles=np.stack(singles))
    config = backend._policy.config  # noqa: SLF001 - a test probe of the loaded model's settings
    report = {
        "metadata": backend.metadata,
        "load_seconds": load_seconds,
        "batch_seconds": batch_seconds,
        "single_seconds": single_seconds,
        "image_resolution": list(config.image_resolution),
        "letterbox_change": letterbox_change(config.image_resolution),
    }
    (out_dir / f"{name}.json").write_text(json.dumps(report))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=Path, required=True)
    parser.add_argument("--out-dir", type=Path, required=True)
    parser.add_argument("checkpoints", nargs="+", metavar="NAME=CHECKPOINT")
    args = parser.parse_args(argv)

    import torch

    from conflictbench_pi0.protocol import unpackb

    torch.set_num_threads(1)
    requests = unpackb(args.requests.read_bytes())
    for item in args.checkpoints:
        name, _, checkpoint = item.partition("=")
        run_one(Path(checkpoint), requests, args.out_dir, name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
