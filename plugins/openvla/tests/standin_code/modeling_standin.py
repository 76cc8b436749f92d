"""A stand-in for OpenVLA's ``modeling_prismatic.py``: a tiny random-weight model with OpenVLA's ``predict_action``.

OpenVLA's modeling code is in no installable package, so this checkpoint brings a small one of its own, loaded
the way a real checkpoint's is (``AutoModelForVision2Seq`` with ``trust_remote_code``). Its ``predict_action``
restates OpenVLA's steps: the empty token 29871 appended to the prompt, greedy decoding of 7 tokens, token ``id``
to bin ``vocab_size - id - 1`` clipped to [0, 254], the bin centre, q01/q99 un-normalization where the mask
keeps. Three liberties, because the weights are random: the image enters as one projected prefix embedding,
each next token is read from the last position plus the mean over the context (so the text and the image visibly
count), and decoding picks among the 256 action tokens only (a trained OpenVLA emits those of itself).
"""

import numpy as np
import torch
from transformers import LlamaConfig, LlamaForCausalLM, PreTrainedModel

from .configuration_standin import StandInVlaConfig

EMPTY_TOKEN = 29871


class StandInVla(PreTrainedModel):
    config_class = StandInVlaConfig

    def __init__(self, config):
        super().__init__(config)
        self.language_model = LlamaForCausalLM(LlamaConfig(
            vocab_size=config.vocab_size, hidden_size=config.hidden_size, intermediate_size=2 * config.hidden_size,
            num_hidden_layers=1, num_attention_heads=2, num_key_value_heads=2, max_position_embeddings=512,
        ))  # fmt: skip
        self.projector = torch.nn.Linear(3 * 8 * 8, config.hidden_size)
        self.norm_stats = config.norm_stats
        self.vocab_size = config.vocab_size - config.pad_to_multiple_of
        edges = np.linspace(-1, 1, config.n_action_bins)
        self.bin_centers = (edges[:-1] + edges[1:]) / 2.0

    def action_tokens(self, input_ids, pixel_values, n_tokens=7):
        if not torch.all(input_ids[:, -1] == EMPTY_TOKEN):
            input_ids = torch.cat([input_ids, torch.full_like(input_ids[:, :1], EMPTY_TOKEN)], dim=1)
        pooled = torch.nn.functional.adaptive_avg_pool2d(pixel_values, 8).flatten(1)
        prefix = self.projector(pooled.to(self.projector.weight.dtype))[:, None]
        embed = self.language_model.get_input_embeddings()
        first_action = self.vocab_size - self.config.n_action_bins + 1
        tokens = []
        for _ in range(n_tokens):
            sequence = torch.cat([prefix, embed(input_ids)], dim=1)
            hidden = self.language_model.model(inputs_embeds=sequence).last_hidden_state
            summary = hidden[:, -1] + 4 * hidden.mean(dim=1)  # the whole context, so text and image both count
            logits = self.language_model.lm_head(summary)[:, first_action : self.vocab_size]
            token = logits.float().argmax(dim=-1, keepdim=True) + first_action
            tokens.append(int(token))
            input_ids = torch.cat([input_ids, token], dim=1)
        return np.array(tokens)

    def predict_action(self, input_ids=None, attention_mask=None, pixel_values=None, unnorm_key=None, **kwargs):
        if unnorm_key is None:
            assert len(self.norm_stats) == 1, "several statistics: pass unnorm_key"
            unnorm_key = next(iter(self.norm_stats))
        stats = self.norm_stats[unnorm_key]["action"]
        tokens = self.action_tokens(input_ids, pixel_values, len(stats["q01"]))
        normalized = self.bin_centers[np.clip(self.vocab_size - tokens - 1, 0, self.bin_centers.shape[0] - 1)]
        low, high = np.array(stats["q01"]), np.array(stats["q99"])
        mask = np.array(stats.get("mask", np.ones_like(low, dtype=bool)))
        return np.where(mask, 0.5 * (normalized + 1) * (high - low) + low, normalized)
