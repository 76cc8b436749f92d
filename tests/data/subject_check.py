"""Run by the subject's training environment's Python (tests/test_subject_training.py): read a dataset that
``train-subject`` wrote with LeRobot's own reader, and run its weights through the PyTorch network and the
NumPy one the benchmark uses. Prints one JSON object."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import torch


def load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


package, root, weights = (Path(a) for a in sys.argv[1:4])
trainer = load("train_torch", package / "train_torch.py")
numpy_model = load("subject_model", package / "model.py")

from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402

dataset = LeRobotDataset(trainer.REPO_ID, root=root)
frames, vocabulary = trainer.read_dataset(root)
stored = np.load(weights)
network = trainer.SubjectNetwork(len(vocabulary), frames["entities"].shape[-1], frames["arm"].shape[-1], trainer.CONFIG)
network.load_state_dict({k: torch.tensor(stored[k]) for k in network.state_dict()})
inputs = [frames[k] for k in ("text", "names", "kinds", "entities", "arm")]
with torch.no_grad():
    raw = network(*inputs).numpy()
expected = numpy_model.decode(raw, trainer.CONFIG["chunk"], trainer.CONFIG["bins"])
ours, _ = numpy_model.SubjectNetwork.load(weights)
got = ours(numpy_model.Inputs(*(x.numpy() for x in inputs)))
print(
    json.dumps(
        {
            "episodes": dataset.meta.total_episodes,
            "frames": dataset.meta.total_frames,
            "tasks": sorted(dataset.meta.tasks.index),
            "first_task": dataset[0]["task"],
            "largest_difference": float(np.abs(got - expected).max()),
            "decided_close": int((expected[..., 6] > 0).sum()),
        }
    )
)
