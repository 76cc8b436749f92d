"""Stand-in for UniVLA's ``configuration_prismatic.py``: the config type its evaluation registers as ``openvla``."""

from transformers import PretrainedConfig


class OpenVLAConfig(PretrainedConfig):
    model_type = "openvla"

    def __init__(self, hidden_size=16, norm_stats=None, **kwargs):
        self.hidden_size, self.norm_stats = hidden_size, norm_stats or {}
        super().__init__(**kwargs)
