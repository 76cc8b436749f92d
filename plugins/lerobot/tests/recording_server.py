"""Our LeRobot server, recording what LeRobot's ``select_action`` receives and answers at every step (tests only).

Run with the model environment's Python:

    .venv/models/lerobot/bin/python plugins/lerobot/tests/recording_server.py CHECKPOINT OUT_DIR

It loads the checkpoint with the plugin's own backend and serves it with the plugin's own server on a free port of
127.0.0.1 (no token), writing ``HOST PORT`` to ``OUT_DIR/address`` once it listens. Each step of each episode is
written to ``OUT_DIR/<episode>/<step>.npz`` as it is answered: ``policy_in/<key>`` (every tensor of the batch
``select_action`` received, as numpy), ``task``, ``policy_out`` (what it returned), ``action`` (the reply) and
``seed``. The oracle test compares these with what LeRobot's own rollout recorded (``oracle/lerobot_rollout.py``).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import torch

from conflictbench_lerobot import backend as lerobot_backend
from conflictbench_lerobot.protocol import EPISODE, NOISE_SEED, STEP
from conflictbench_lerobot.server import serve


def as_numpy(value):
    return value.detach().to("cpu").numpy() if isinstance(value, torch.Tensor) else np.asarray(value)


class RecordingBackend(lerobot_backend.LeRobotBackend):
    """The plugin's backend; every step's policy input and output written where the test reads them."""

    def __init__(self, folder: Path, out: Path) -> None:
        super().__init__(folder, lerobot_backend.check_folder(folder), "cpu")
        self.out = out
        self.current: dict = {}

    def fresh_policy(self, n_action_steps: int):
        shell = super().fresh_policy(n_action_steps)
        select_action = shell.select_action

        def recording_select_action(batch, *args, **kwargs):
            self.current["policy_in"] = {k: as_numpy(v) for k, v in batch.items() if isinstance(v, torch.Tensor)}
            self.current["task"] = list(batch.get("task", []))
            answer = select_action(batch, *args, **kwargs)
            self.current["policy_out"] = as_numpy(answer)
            return answer

        shell.__dict__["select_action"] = recording_select_action
        return shell

    def step(self, request: dict) -> np.ndarray:
        self.current = {}
        action = super().step(request)
        folder = self.out / re.sub(r"[^A-Za-z0-9_.-]", "_", str(request[EPISODE]))
        folder.mkdir(parents=True, exist_ok=True)
        arrays = {f"policy_in/{k}": v for k, v in self.current["policy_in"].items()}
        arrays.update(
            task=np.array(self.current["task"]),
            policy_out=self.current["policy_out"],
            action=action,
            seed=np.int64(int(request[NOISE_SEED]) % 2**63),
        )
        np.savez(folder / f"{int(request[STEP])}.npz", **arrays)
        return action


def main() -> None:
    torch.set_num_threads(1)
    checkpoint, out = Path(sys.argv[1]), Path(sys.argv[2])
    backend = RecordingBackend(checkpoint, out)

    def ready(host: str, port: int) -> None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "address.tmp").write_text(f"{host} {port}\n")
        (out / "address.tmp").rename(out / "address")

    serve(backend, "127.0.0.1", 0, on_ready=ready)


if __name__ == "__main__":
    main()
