"""Offline stand-in for the FAST action tokenizer (hub ``lerobot/fast-action-tokenizer``), tests only.

LeRobot's pi0-FAST loads its action tokenizer from the hub with ``AutoProcessor.from_pretrained(name,
trust_remote_code=True)`` and, when decoding, uses exactly three things of it: ``bpe_tokenizer.decode(ids)``
(a string whose characters' code points, offset by ``min_token``, are the quantized DCT coefficients),
``min_token`` and ``scale``. ``tests/tiny/build.py`` copies this file into a hub-cache entry of that name,
with a ``processor_config.json`` whose ``auto_map`` points here.

A random-weight model emits arbitrary token ids, which the real BPE decodes to nothing usable (LeRobot then
falls back to all-zero actions). This stand-in decodes every id, so any token sequence gives valid
coefficients and actions that follow the model's tokens: different images, states or prompts give
different actions, as the tests require. Encoding (used only in training) is not provided.
"""

from __future__ import annotations

#: Number of distinct coefficient values; an id maps to ``id mod ALPHABET``.
ALPHABET = 64


class _ModuloDecoder:
    """Plays the role of FAST's byte-pair tokenizer: one character per action-token id."""

    def decode(self, ids) -> str:
        return "".join(chr(int(token_id) % ALPHABET) for token_id in ids)


class FastActionStandIn:
    """Decoding side of FAST: coefficients in [-ALPHABET/2, ALPHABET/2) divided by ``scale``."""

    def __init__(self) -> None:
        self.bpe_tokenizer = _ModuloDecoder()
        self.min_token = -(ALPHABET // 2)
        self.scale = 10.0

    @classmethod
    def from_pretrained(cls, *args, **kwargs) -> FastActionStandIn:
        return cls()

    @classmethod
    def register_for_auto_class(cls, auto_class="AutoProcessor") -> None:
        """transformers calls this on every remote-code class it loads; nothing to record here."""

    def __call__(self, *args, **kwargs):
        raise NotImplementedError("the FAST stand-in only decodes (tests never train)")
