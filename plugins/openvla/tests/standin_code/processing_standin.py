"""The stand-in checkpoint's processor: bytes of the prompt as token ids, the image as normalized pixels."""

import json
import os

import numpy as np
import torch
from PIL import Image
from transformers import BatchFeature

BOS = 1


class StandInProcessor:
    def __init__(self, image_size=224):
        self.image_size = image_size

    @classmethod
    def from_pretrained(cls, folder, **kwargs):
        with open(os.path.join(folder, "preprocessor_config.json")) as handle:
            return cls(json.load(handle)["image_size"])

    @classmethod
    def register_for_auto_class(cls, auto_class="AutoProcessor"):  # AutoProcessor calls it on remote code
        cls._auto_class = auto_class

    def __call__(self, text, images, return_tensors="pt"):
        ids = [BOS] + [3 + byte for byte in text.encode()]
        image = images.convert("RGB").resize((self.image_size, self.image_size), Image.BICUBIC)
        pixels = torch.from_numpy(np.asarray(image, dtype=np.float32) / 127.5 - 1.0).permute(2, 0, 1)[None]
        mask = torch.ones(1, len(ids), dtype=torch.long)
        return BatchFeature({"input_ids": torch.tensor([ids]), "attention_mask": mask, "pixel_values": pixels})
