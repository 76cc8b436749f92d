"""The stand-in OpenVLA checkpoint's config (its own code, loaded with ``trust_remote_code`` as a real one's is)."""

from transformers import PretrainedConfig


class StandInVlaConfig(PretrainedConfig):
    model_type = "standin_openvla"

    def __init__(self, vocab_size=32064, pad_to_multiple_of=64, hidden_size=16, n_action_bins=256,
                 norm_stats=None, **kwargs):  # fmt: skip
        self.vocab_size, self.pad_to_multiple_of, self.hidden_size = vocab_size, pad_to_multiple_of, hidden_size
        self.n_action_bins, self.norm_stats = n_action_bins, norm_stats or {}
        super().__init__(**kwargs)
