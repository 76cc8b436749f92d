"""Stand-in for UniVLA's ``modeling_prismatic.py``: a tiny random-weight model with its ``predict_latent_action``.

What the server relies on, kept: the arguments (``unnorm_key``, ``do_sample``, ``temperature``, ``top_p``), sampling
from torch's global generator, and the results: the four latent tokens' hidden states (1, 4, 4096), the image
patches' (1, 256, 4096) and the token ids (1, 4), each ``32001 + k`` for ``<ACT_k>``, k < 16.
"""

import torch
from transformers import PreTrainedModel

from .configuration_prismatic import OpenVLAConfig

LATENT_OFFSET, CODEBOOK = 32001, 16


class OpenVLAForActionPrediction(PreTrainedModel):
    config_class = OpenVLAConfig

    def __init__(self, config):
        super().__init__(config)
        width = config.hidden_size
        self.embed = torch.nn.Embedding(32064, width)
        self.image = torch.nn.Linear(3 * 14 * 14, width)
        self.head = torch.nn.Linear(width, CODEBOOK)
        self.lift = torch.nn.Linear(width, 4096)
        self.norm_stats = config.norm_stats

    def predict_latent_action(self, input_ids=None, unnorm_key=None, attention_mask=None, pixel_values=None,
                              do_sample=False, temperature=1.0, top_p=1.0, **kwargs):  # fmt: skip
        assert unnorm_key in self.norm_stats, f"no statistics {unnorm_key!r}"
        patches = torch.nn.functional.unfold(pixel_values.to(self.image.weight.dtype), 14, stride=14)  # (1, 588, 256)
        visual = torch.tanh(self.image(patches.transpose(1, 2)))  # (1, 256, width)
        context = self.embed(input_ids).mean(dim=1) + visual.mean(dim=1)
        tokens, states = [], []
        for _ in range(4):
            probs = torch.softmax(self.head(torch.tanh(context)).float() / temperature, dim=-1)
            if do_sample:
                ordered, index = probs.sort(dim=-1, descending=True)
                keep = ordered.cumsum(dim=-1) - ordered < top_p  # the smallest set reaching top_p
                ordered = ordered * keep
                token = index.gather(-1, torch.multinomial(ordered / ordered.sum(), 1))
            else:
                token = probs.argmax(dim=-1, keepdim=True)
            token = token + LATENT_OFFSET
            tokens.append(token)
            context = context + self.embed(token[:, 0])
            states.append(self.lift(torch.tanh(context)))
        return torch.stack(states, dim=1), self.lift(visual), torch.cat(tokens, dim=1)
