"""Build a tiny random-weight stand-in OpenVLA checkpoint (run with the openvla model environment's python).

    python tiny_openvla.py DIR

The folder is shaped as an OpenVLA checkpoint in Hugging Face format: ``config.json`` whose ``auto_map`` names the
model code beside it (``standin_code/``, copied in), the processor's ``preprocessor_config.json`` (its own
``auto_map``), ``model.safetensors``, and ``dataset_statistics.json`` with LIBERO-like statistics per suite (the
gripper masked out). Seeded: the same folder every time.
"""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

CODE = Path(__file__).resolve().parent / "standin_code"
ACTION = {"q01": [-0.6, -0.7, -0.8, -0.1, -0.2, -0.3, 0.0], "q99": [0.7, 0.6, 0.9, 0.12, 0.2, 0.3, 1.0],
          "mask": [True] * 6 + [False]}  # fmt: skip
SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
STATISTICS = {s: {"action": {**ACTION, "q01": [v - 0.02 * i for v in ACTION["q01"]]}} for i, s in enumerate(SUITES)}


def build(folder: Path) -> Path:
    import torch

    folder.mkdir(parents=True, exist_ok=True)
    for source in CODE.glob("*.py"):
        shutil.copy(source, folder / source.name)
    sys.path.insert(0, str(CODE.parent))  # the code's relative imports need it as a package, as HF loads it
    from standin_code.configuration_standin import StandInVlaConfig
    from standin_code.modeling_standin import StandInVla

    torch.manual_seed(0)
    config = StandInVlaConfig(norm_stats={"bridge_orig": STATISTICS["libero_goal"]})
    config.auto_map = {"AutoConfig": "configuration_standin.StandInVlaConfig",
                       "AutoModelForVision2Seq": "modeling_standin.StandInVla"}  # fmt: skip
    model = StandInVla(config)
    with torch.no_grad():  # weights large enough that bfloat16 (deploy.py's dtype) keeps inputs apart
        for module in model.modules():
            if isinstance(module, (torch.nn.Linear, torch.nn.Embedding)):
                module.weight.normal_(0.0, 0.5)
    model.save_pretrained(folder)
    (folder / "preprocessor_config.json").write_text(
        json.dumps({"image_size": 224, "auto_map": {"AutoProcessor": "processing_standin.StandInProcessor"}})
    )
    (folder / "dataset_statistics.json").write_text(json.dumps(STATISTICS))
    return folder


if __name__ == "__main__":
    print(build(Path(sys.argv[1])))
