"""Build a tiny random-weight UniVLA checkpoint for the stand-in checkout (run with the univla model environment).

    python tiny_univla.py DIR

The folder is shaped as UniVLA's LIBERO checkpoints: the VLA in Hugging Face format (``config.json`` of type
``openvla``, ``model.safetensors``, ``preprocessor_config.json``, ``dataset_statistics.json`` per suite, the gripper
masked out) and ``action_decoder.pt``, the state dict of UniVLA's ``ActionDecoderHead`` (window 12) built with the
stand-in's ``MAPBlock``. Seeded: the same folder every time.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

CODE = Path(__file__).resolve().parent / "standin_univla_code"
ACTION = {"q01": [-0.6, -0.7, -0.8, -0.1, -0.2, -0.3, 0.0], "q99": [0.7, 0.6, 0.9, 0.12, 0.2, 0.3, 1.0],
          "mask": [True] * 6 + [False]}  # fmt: skip
SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
STATISTICS = {s: {"action": {**ACTION, "q01": [v - 0.02 * i for v in ACTION["q01"]]}} for i, s in enumerate(SUITES)}


def build(folder: Path) -> Path:
    import torch

    from conflictbench_univla.backend import decoder_head, load_code

    folder.mkdir(parents=True, exist_ok=True)
    classes = load_code(CODE)
    torch.manual_seed(0)
    vla = classes["OpenVLAForActionPrediction"](classes["OpenVLAConfig"](norm_stats={"unused": {}}))
    with torch.no_grad():
        for module in vla.modules():
            if isinstance(module, (torch.nn.Linear, torch.nn.Embedding)):
                module.weight.normal_(0.0, 0.5)
    vla.save_pretrained(folder)
    (folder / "preprocessor_config.json").write_text(json.dumps({"image_size": 224}))
    (folder / "dataset_statistics.json").write_text(json.dumps(STATISTICS))
    decoder = decoder_head(classes["MAPBlock"], window=12)
    with torch.no_grad():
        for parameter in decoder.parameters():
            parameter.normal_(0.0, 0.05)
    torch.save(decoder.state_dict(), folder / "action_decoder.pt")
    return folder


if __name__ == "__main__":
    print(build(Path(sys.argv[1])))
