"""Stand-in for UniVLA's ``transformer_utils.py``: ``MAPBlock``'s signature, a small pooling of its own inside."""

import torch


class MAPBlock(torch.nn.Module):
    def __init__(self, n_latents, vis_dim, embed_dim, n_heads, mlp_ratio=4.0, do_rms_norm=True, do_swish_glu=True):
        super().__init__()
        self.projection = torch.nn.Linear(vis_dim, embed_dim)
        self.latents = torch.nn.Parameter(torch.zeros(n_latents, embed_dim))

    def forward(self, x, mask=None, init_embed=None):
        pooled = self.projection(x).mean(dim=1) + self.latents[0]
        return torch.tanh(pooled + init_embed if init_embed is not None else pooled)
