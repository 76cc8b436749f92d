"""The stand-in checkpoint called directly, as OpenVLA's README and deploy.py call a checkpoint (model environment).

    python openvla_direct.py CHECKPOINT REQUESTS.npz OUT.npz

For each request (image, instruction, unnorm_key): ``predict_action`` of the checkpoint's own code on its processor's
inputs in bfloat16, and the action tokens it generated. Independent of the plugin's backend.
"""

import json
import sys

import numpy as np
import torch
from PIL import Image
from transformers import AutoModelForVision2Seq, AutoProcessor


def main(checkpoint: str, requests: str, out: str) -> None:
    processor = AutoProcessor.from_pretrained(checkpoint, trust_remote_code=True)
    model = AutoModelForVision2Seq.from_pretrained(checkpoint, trust_remote_code=True, torch_dtype=torch.bfloat16)
    with open(f"{checkpoint}/dataset_statistics.json") as handle:
        model.norm_stats = json.load(handle)
    data = np.load(requests)
    actions, tokens = [], []
    for image, instruction, key in zip(data["images"], json.loads(str(data["instructions"])), data["keys"]):
        prompt = f"In: What action should the robot take to {instruction.lower()}?\nOut:"
        inputs = processor(prompt, Image.fromarray(image).convert("RGB")).to("cpu", dtype=torch.bfloat16)
        with torch.inference_mode():
            actions.append(model.predict_action(**inputs, unnorm_key=str(key), do_sample=False))
            tokens.append(model.action_tokens(inputs["input_ids"], inputs["pixel_values"]))
    np.savez(out, actions=np.array(actions), tokens=np.array(tokens))


if __name__ == "__main__":
    main(*sys.argv[1:4])
