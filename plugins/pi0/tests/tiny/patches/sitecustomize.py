"""Shrinks LeRobot's pi0, pi0.5 and pi0-FAST models to tiny sizes, for offline tests only.

LeRobot 0.6.1 hard-codes the model sizes: ``get_gemma_config`` in each of
``lerobot.policies.{pi0,pi05,pi0_fast}.modeling_*`` knows only Gemma 300M and 2B, and the PaliGemma
configuration built there fixes a SigLIP So400m vision tower and a 257,152-token vocabulary. A tiny
random-weight checkpoint can only be built, and loaded again, by a process that makes the same
substitution at construction time. This module does it.

It is active only where ``tests/tiny/patches`` is on ``PYTHONPATH``: Python's ``site`` imports a
module named ``sitecustomize`` at start-up, so the test fixtures put this folder on the path of the
model-environment processes they start (build, server, direct call) and nowhere else. The production
backend (``conflictbench_pi0.backend``) has no test hooks at all.

What it changes, and only once the LeRobot modules are imported (nothing is imported here at start-up,
so a process that never loads a pi policy pays nothing):

- ``get_gemma_config``: the VLM ("gemma_2b") becomes width 64, the action expert ("gemma_300m")
  width 32; both 2 layers, 8 heads of width 8 (pi0 hard-codes 8 heads in its joint attention);
- the PaliGemma model: a 1-layer SigLIP of width 32 (patch 16, so 196 tokens per 224-px image),
  projected to the VLM width, and a vocabulary of ``TINY_VOCAB`` tokens, the size of the tiny tokenizer
  ``build.py`` writes (pi0-FAST maps action tokens from the end of the tokenizer's vocabulary, so the
  two must agree);
- the action expert's (unused) vocabulary: ``TINY_VOCAB`` as well, so its output head stays small.

pi0-FAST's decoding path needs no patch here: its FAST action-tokenizer stand-in
(``fast_standin.py`` in this folder, copied by ``build.py`` into the hub-cache entry LeRobot loads with
``trust_remote_code``) decodes any token sequence to valid DCT coefficients, so the random model's
tokens give varied actions rather than LeRobot's all-zero fallback.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys

#: Size of the tiny PaliGemma tokenizer's vocabulary, and so of the tiny models' embeddings.
TINY_VOCAB = 512
#: (width, depth, mlp_dim, num_heads, num_kv_heads, head_dim) per LeRobot Gemma variant name.
TINY_GEMMA = {
    "gemma_2b": (64, 2, 128, 8, 1, 8),
    "gemma_300m": (32, 2, 64, 8, 1, 8),
}
TINY_VISION = {
    "hidden_size": 32,
    "intermediate_size": 64,
    "num_hidden_layers": 1,
    "num_attention_heads": 2,
    "patch_size": 16,
}

_PATCHED_MODULES = (
    "lerobot.policies.pi0.modeling_pi0",
    "lerobot.policies.pi05.modeling_pi05",
    "lerobot.policies.pi0_fast.modeling_pi0_fast",
)


def _shrink(module) -> None:
    """Replace the size-fixing names of one LeRobot pi modeling module with tiny ones."""
    gemma_config_class = module.GemmaConfig

    def tiny_gemma_config(variant: str):
        if variant not in TINY_GEMMA:
            raise ValueError(f"Unknown variant: {variant}")
        width, depth, mlp_dim, heads, kv_heads, head_dim = TINY_GEMMA[variant]
        return gemma_config_class(width, depth, mlp_dim, heads, kv_heads, head_dim)

    module.get_gemma_config = tiny_gemma_config

    paligemma_class = module.PaliGemmaForConditionalGenerationWithPiGemma

    class TinyPaliGemma(paligemma_class):
        def __init__(self, config):
            for name, value in TINY_VISION.items():
                setattr(config.vision_config, name, value)
            config.vision_config.projection_dim = config.text_config.hidden_size
            config.projection_dim = config.text_config.hidden_size
            config.text_config.num_image_tokens = (
                config.vision_config.image_size // config.vision_config.patch_size
            ) ** 2
            config.text_config.vocab_size = TINY_VOCAB
            config._vocab_size = TINY_VOCAB  # noqa: SLF001 - LeRobot sets this private field too
            config.image_token_index = TINY_VOCAB - 1  # never used: pi models embed images directly
            super().__init__(config)

    module.PaliGemmaForConditionalGenerationWithPiGemma = TinyPaliGemma

    expert_class = getattr(module, "PiGemmaForCausalLM", None)
    if expert_class is not None:

        class TinyExpert(expert_class):
            def __init__(self, config, **kwargs):
                config.vocab_size = TINY_VOCAB
                super().__init__(config, **kwargs)

        module.PiGemmaForCausalLM = TinyExpert


class _ShrinkingLoader(importlib.abc.Loader):
    """Runs the real loader, then shrinks the module before anyone can use it."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        self._loader.exec_module(module)
        _shrink(module)


class _ShrinkingFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path, target=None):
        if fullname not in _PATCHED_MODULES:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is None or spec.loader is None:
            return spec
        spec.loader = _ShrinkingLoader(spec.loader)
        return spec


if not any(isinstance(finder, _ShrinkingFinder) for finder in sys.meta_path):
    sys.meta_path.insert(0, _ShrinkingFinder())
