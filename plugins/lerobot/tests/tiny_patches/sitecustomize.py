"""Shrinks LeRobot 0.6.1's pi0.5 model to a tiny size, for the lerobot plugin's offline tests only.

LeRobot fixes pi0.5's sizes in code: ``get_gemma_config`` in ``lerobot.policies.pi05.modeling_pi05`` (lines
158-179) knows only Gemma 300M and 2B, and ``PaliGemmaWithExpertModel.__init__`` (lines 187-238) builds a
So400m SigLIP and a 257,152-token vocabulary whatever the config says. A tiny random-weight pi0.5 checkpoint
(``tiny_lerobot.py --type pi05``) can therefore only be built, and loaded again, by a process that makes the
same substitution when that module is imported: this module does it, in every process that has this folder on
``PYTHONPATH`` (Python's ``site`` imports ``sitecustomize`` at start-up). ``lerobot_fixtures.tiny_lerobot_env``
puts it there for the processes the tests start; the plugin's server has no test hook of its own.

Nothing is imported at start-up: a finder waits for ``lerobot.policies.pi05.modeling_pi05`` and patches the
module right after it executes, before any caller can use it. What it changes:

- ``get_gemma_config``: the VLM (``gemma_2b``) becomes width 64 and the action expert (``gemma_300m``) width 32,
  both two layers of 8 heads of width 8 (``TINY_GEMMA``);
- ``PaliGemmaWithExpertModel``: the SigLIP tower becomes ``TINY_SIGLIP`` (patch 16: 196 tokens per 224-px image,
  the real count) projected to the VLM width, and the vocabulary of both models ``TINY_VOCAB`` tokens, the size
  of the tiny PaliGemma tokenizer ``tiny_lerobot.py`` writes into the hub cache.

No other type needs a patch: their sizes are config fields, stored in the checkpoint's ``config.json`` or in the
stand-in configs of its hub cache.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys

#: Tokens of the tiny PaliGemma tokenizer, and so rows of the tiny models' embeddings.
TINY_VOCAB = 1024
#: (width, depth, mlp_dim, num_heads, num_kv_heads, head_dim) per Gemma variant: 8 heads, as LeRobot's joint
#: attention hard-codes them (``modeling_pi05.py:121``).
TINY_GEMMA = {"gemma_2b": (64, 2, 128, 8, 1, 8), "gemma_300m": (32, 2, 64, 8, 1, 8)}
TINY_SIGLIP = {"hidden_size": 32, "intermediate_size": 64, "num_hidden_layers": 1, "num_attention_heads": 2,
               "patch_size": 16}  # fmt: skip
PATCHED_MODULE = "lerobot.policies.pi05.modeling_pi05"


def _shrink(module) -> None:
    gemma_config = module.GemmaConfig

    def tiny_gemma_config(variant: str):
        if variant not in TINY_GEMMA:
            raise ValueError(f"Unknown variant: {variant}")
        return gemma_config(*TINY_GEMMA[variant])

    module.get_gemma_config = tiny_gemma_config

    class TinyPaliGemma(module.PaliGemmaForConditionalGenerationWithPiGemma):
        def __init__(self, config):
            vision = config.vision_config
            for name, value in TINY_SIGLIP.items():
                setattr(vision, name, value)
            width = config.text_config.hidden_size
            vision.projection_dim = config.projection_dim = width
            config.text_config.num_image_tokens = (vision.image_size // vision.patch_size) ** 2
            config.text_config.vocab_size = config._vocab_size = TINY_VOCAB  # noqa: SLF001 - LeRobot sets it too
            config.image_token_index = TINY_VOCAB - 1  # unused: pi0.5 embeds the images itself
            super().__init__(config)

    class TinyExpert(module.PiGemmaForCausalLM):
        def __init__(self, config, **kwargs):
            config.vocab_size = TINY_VOCAB
            super().__init__(config, **kwargs)

    module.PaliGemmaForConditionalGenerationWithPiGemma = TinyPaliGemma
    module.PiGemmaForCausalLM = TinyExpert


class _ShrinkAfterExec(importlib.abc.Loader):
    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        self._loader.exec_module(module)
        _shrink(module)


class _Pi05Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path, target=None):
        if fullname != PATCHED_MODULE:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _ShrinkAfterExec(spec.loader)
        return spec


if not any(type(finder).__name__ == "_Pi05Finder" for finder in sys.meta_path):
    sys.meta_path.insert(0, _Pi05Finder())
