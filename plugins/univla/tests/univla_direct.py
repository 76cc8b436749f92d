"""The stand-in UniVLA checkpoint called directly, as UniVLA's evaluation calls it (model environment).

    python univla_direct.py CHECKPOINT REQUESTS.npz OUT.npz

For each request (image, prompt, seed, key): ``torch.manual_seed(seed)``, ``predict_latent_action`` with UniVLA's
sampling arguments on the processor's bfloat16 inputs, the action decoder in float32; the latent token ids and
the chunk. Loads the stand-in checkout by file itself, not through the plugin's backend.
"""

import importlib.util
import json
import sys
import types
from pathlib import Path

import numpy as np
import torch
from PIL import Image

CODE = Path(__file__).resolve().parent / "standin_univla_code"


def module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    loaded = importlib.util.module_from_spec(spec)
    sys.modules[name] = loaded
    spec.loader.exec_module(loaded)
    return loaded


def main(checkpoint: str, requests: str, out: str) -> None:
    from conflictbench_univla.backend import decoder_head  # UniVLA's ActionDecoderHead (its script defines it)

    package = types.ModuleType("direct_hf")
    package.__path__ = [str(CODE / "prismatic/extern/hf")]
    sys.modules["direct_hf"] = package
    module("direct_hf.configuration_prismatic", CODE / "prismatic/extern/hf/configuration_prismatic.py")
    modeling = module("direct_hf.modeling_prismatic", CODE / "prismatic/extern/hf/modeling_prismatic.py")
    processing = module("direct_hf.processing_prismatic", CODE / "prismatic/extern/hf/processing_prismatic.py")
    utils = module("direct_utils", CODE / "prismatic/models/policy/transformer_utils.py")
    vla = modeling.OpenVLAForActionPrediction.from_pretrained(checkpoint, torch_dtype=torch.bfloat16).eval()
    vla.norm_stats = json.loads((Path(checkpoint) / "dataset_statistics.json").read_text())
    decoder = decoder_head(utils.MAPBlock, 12)
    decoder.load_state_dict(torch.load(Path(checkpoint) / "action_decoder.pt"))
    processor = processing.PrismaticProcessor()
    data = np.load(requests)
    tokens, chunks = [], []
    for image, prompt, seed, key in zip(data["images"], json.loads(str(data["prompts"])), data["seeds"], data["keys"]):
        inputs = processor(prompt, Image.fromarray(image).convert("RGB")).to("cpu", dtype=torch.bfloat16)
        torch.manual_seed(int(seed))
        with torch.inference_mode():
            latent, visual, ids = vla.predict_latent_action(**inputs, unnorm_key=str(key), do_sample=True,
                                                            temperature=0.75, top_p=0.9)  # fmt: skip
            chunk = decoder(latent.to(torch.float), visual.to(torch.float)).reshape(-1, 12, 7)[0]
        tokens.append(ids[0].tolist())
        chunks.append(np.array(chunk.tolist()))
    np.savez(out, tokens=np.array(tokens), chunks=np.array(chunks))


if __name__ == "__main__":
    main(*sys.argv[1:4])
