"""Stand-in for UniVLA's ``processing_prismatic.py``: ``<ACT_k>`` as token 32001 + k, other bytes as ids."""

import re

import numpy as np
import torch
from PIL import Image
from transformers import BatchFeature


class PrismaticImageProcessor:
    pass


class PrismaticProcessor:
    @classmethod
    def from_pretrained(cls, folder, **kwargs):
        return cls()

    def __call__(self, text, images, return_tensors="pt"):
        ids = [1]
        for piece in re.split(r"(<ACT_\d+>)", text):
            found = re.fullmatch(r"<ACT_(\d+)>", piece)
            ids += [32001 + int(found[1])] if found else [3 + byte for byte in piece.encode()]
        image = images.convert("RGB").resize((224, 224), Image.BICUBIC)
        pixels = torch.from_numpy(np.asarray(image, dtype=np.float32) / 127.5 - 1.0).permute(2, 0, 1)[None]
        mask = torch.ones(1, len(ids), dtype=torch.long)
        return BatchFeature({"input_ids": torch.tensor([ids]), "attention_mask": mask, "pixel_values": pixels})
