"""A tiny random-weight LeRobot ``vla_jepa`` checkpoint, built offline (model environment only).

``build_tiny_checkpoint(folder)`` writes what ``policy.save_pretrained`` and the processor pipelines'
``save_pretrained`` write for a real checkpoint (``config.json`` with ``"type": "vla_jepa"``,
``model.safetensors``, ``policy_preprocessor.json`` / ``policy_postprocessor.json`` and their
``*.safetensors`` statistics), around a minuscule Qwen3-VL backbone (1 text layer, 1 vision block, hidden 32,
a character-level tokenizer) and the ``DiT-test`` action head, with the world model off.

The backbone. LeRobot rebuilds the policy by loading ``config.qwen_model_name`` with
``Qwen3VLForConditionalGeneration.from_pretrained`` / ``AutoProcessor.from_pretrained``
(``lerobot/policies/vla_jepa/qwen_interface.py``) and only then overwrites its weights from
``model.safetensors``; the name is stored in ``config.json`` as given. A real checkpoint names a hub id
(``Qwen/Qwen3-VL-2B-Instruct``); so does this one (``HUB_ID``), and the backbone lies in a hub cache inside the
checkpoint, ``folder/hub`` (``hub_cache(folder)``). So the folder survives a copy or a move: load it with
``HF_HUB_CACHE=<folder>/hub HF_HUB_OFFLINE=1`` in the environment (set before Python starts), exactly as a
real checkpoint loads from a cache, or, without that environment, set
``config.qwen_model_name = str(backbone_dir(folder))`` between ``PreTrainedConfig.from_pretrained`` and the
policy's ``from_pretrained``. (An absolute path in ``config.json`` would break on a move; a relative one is
resolved against the working directory, not the checkpoint.)

Facts about LeRobot 0.6.1's ``vla_jepa`` (read in its source, checked with this checkpoint on CPU):

- Chunk length is ``chunk_size``: ``predict_action_chunk`` returns ``(B, chunk_size, action_dim)`` float32;
  ``n_action_steps <= chunk_size`` only limits ``select_action``'s queue. The backbone's tokenizer gets
  ``4 * chunk_size`` ``<|action_i|>`` tokens and ``<|embodied_action|>`` (``qwen_interface.py``).
- Normalization: VISUAL identity, STATE mean/std, ACTION min/max. Preprocessor: rename, add batch dim, device,
  normalize. A batch holds ``observation.images.image`` (agentview) and ``observation.images.image2`` (wrist,
  LeRobot's LIBERO names) as float CHW in [0, 1] (``(3, H, W)`` or ``(B, 3, H, W)``; the Qwen processor runs
  with ``do_rescale=False``), ``observation.state`` (8) and ``"task"`` (a string or a list of strings).
- Postprocessor: clip to [-1, 1], gripper (dim 6) snapped to {0, 1} at 0.5, min/max un-normalize, gripper
  ``1 - 2 (g > 0.5)``, to CPU. The normalized chunk (upstream's ``normalized_actions``, not clipped) is
  ``predict_action_chunk``'s own output; ``postprocessor(chunk)`` gives the executed actions.
- Images: Qwen3-VL's processor (patch 16, merge 2, at least 65536 pixels, as Qwen/Qwen3-VL-2B-Instruct) turns
  224 x 224 into 256 x 256, 64 visual tokens an image (``resize_images_to`` is unset).
- Sampling: the one draw is ``torch.randn(B, chunk_size, action_dim)`` in ``VLAJEPAActionHead.predict_action``;
  ``predict_action_chunk``'s ``noise=`` is ignored. ``torch.manual_seed(s)`` before a call repeats it bitwise;
  a row's result depends on the batch size (its noise is a slice of that one draw), not on the other rows.
- On CPU too the backbone runs under bfloat16 autocast (``is_amp_available("cpu")`` is true), so a CPU process
  needs ``ONEDNN_MAX_CPU_ISA=AVX512_CORE_BF16`` where bfloat16 matmuls otherwise crash.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.factory import make_pre_post_processors
from lerobot.policies.vla_jepa.configuration_vla_jepa import VLAJEPAConfig
from lerobot.policies.vla_jepa.modeling_vla_jepa import VLAJEPAPolicy
from tokenizers import Regex, Tokenizer, decoders, models, pre_tokenizers
from transformers import (
    PreTrainedTokenizerFast,
    Qwen2VLImageProcessor,
    Qwen3VLConfig,
    Qwen3VLForConditionalGeneration,
    Qwen3VLProcessor,
    Qwen3VLVideoProcessor,
)

HUB_ID = "conflictbench/tiny-qwen3-vl"
#: The snapshot name of the backbone in the checkpoint's hub cache (any 40 hex digits do).
REVISION = "0" * 40
IMAGE_KEYS = ("observation.images.image", "observation.images.image2")
STATE_DIM, ACTION_DIM, IMAGE_SIZE = 8, 7, 224
SPECIAL_TOKENS = [
    "<|endoftext|>", "<|im_start|>", "<|im_end|>", "<|vision_start|>", "<|vision_end|>",
    "<|image_pad|>", "<|video_pad|>", "<unk>",
]  # fmt: skip
#: A chat template of our own, in Qwen's layout: one user turn, images as vision-start/pad/end, then text.
CHAT_TEMPLATE = (
    "{% for message in messages %}<|im_start|>{{ message['role'] }}\n"
    "{% if message['content'] is string %}{{ message['content'] }}{% else %}{% for item in message['content'] %}"
    "{% if item['type'] == 'image' %}<|vision_start|><|image_pad|><|vision_end|>"
    "{% elif item['type'] == 'text' %}{{ item['text'] }}{% endif %}{% endfor %}{% endif %}<|im_end|>\n"
    "{% endfor %}{% if add_generation_prompt %}<|im_start|>assistant\n{% endif %}"
)
#: LIBERO-like statistics: actions within about ±0.9 (translation) / ±0.3 (rotation), the gripper -1..1.
ACTION_MIN = [-0.9, -0.8, -0.9, -0.3, -0.25, -0.35, -1.0]
ACTION_MAX = [0.9, 0.85, 0.9, 0.3, 0.3, 0.35, 1.0]
STATE_MEAN = [-0.05, 0.03, 0.9, 3.0, -0.1, -0.05, 0.03, -0.03]
STATE_STD = [0.1, 0.15, 0.1, 0.3, 0.4, 0.3, 0.01, 0.01]


def hub_cache(folder: Path) -> Path:
    """The hub cache inside a checkpoint folder: what ``HF_HUB_CACHE`` must name to load it."""
    return Path(folder) / "hub"


def backbone_dir(folder: Path) -> Path:
    """The backbone's snapshot folder (a plain ``from_pretrained`` folder) inside a checkpoint."""
    return hub_cache(folder) / f"models--{HUB_ID.replace('/', '--')}" / "snapshots" / REVISION


def _tokenizer() -> PreTrainedTokenizerFast:
    """One token a character (printable ASCII and newline), plus Qwen's chat and vision special tokens."""
    chars = [chr(code) for code in range(32, 127)] + ["\n"]
    vocab = {token: index for index, token in enumerate(SPECIAL_TOKENS + chars)}
    core = Tokenizer(models.WordLevel(vocab, unk_token="<unk>"))
    core.pre_tokenizer = pre_tokenizers.Split(Regex(r"[\s\S]"), behavior="isolated")
    core.decoder = decoders.Fuse()
    core.add_special_tokens(SPECIAL_TOKENS)
    return PreTrainedTokenizerFast(
        tokenizer_object=core, unk_token="<unk>", pad_token="<|endoftext|>", eos_token="<|im_end|>"
    )


def _build_backbone(target: Path, extra_tokens: int) -> None:
    """Save a tiny Qwen3-VL model and its processor to ``target``."""
    tokenizer = _tokenizer()
    ids = {token: tokenizer.convert_tokens_to_ids(token) for token in SPECIAL_TOKENS}
    text = dict(
        vocab_size=len(tokenizer) + extra_tokens, hidden_size=32, intermediate_size=64, num_hidden_layers=1,
        num_attention_heads=2, num_key_value_heads=1, head_dim=16, max_position_embeddings=4096,
        rope_parameters={"rope_type": "default", "rope_theta": 5e6, "mrope_section": [4, 2, 2],
                         "mrope_interleaved": True},
        pad_token_id=ids["<|endoftext|>"], eos_token_id=ids["<|im_end|>"],
    )  # fmt: skip
    vision = dict(
        depth=1, hidden_size=32, intermediate_size=64, num_heads=2, patch_size=16, spatial_merge_size=2,
        temporal_patch_size=2, out_hidden_size=32, num_position_embeddings=256, deepstack_visual_indexes=[0],
    )  # fmt: skip
    config = Qwen3VLConfig(
        text_config=text, vision_config=vision, image_token_id=ids["<|image_pad|>"],
        video_token_id=ids["<|video_pad|>"], vision_start_token_id=ids["<|vision_start|>"],
        vision_end_token_id=ids["<|vision_end|>"], tie_word_embeddings=False,
    )  # fmt: skip
    Qwen3VLForConditionalGeneration(config).to(torch.float32).save_pretrained(target)
    image_processor = Qwen2VLImageProcessor(
        size={"shortest_edge": 65536, "longest_edge": 16777216}, patch_size=16, temporal_patch_size=2,
        merge_size=2, image_mean=[0.5, 0.5, 0.5], image_std=[0.5, 0.5, 0.5],
    )  # fmt: skip
    video_processor = Qwen3VLVideoProcessor(patch_size=16, temporal_patch_size=2, merge_size=2)
    processor = Qwen3VLProcessor(
        image_processor=image_processor, tokenizer=tokenizer, video_processor=video_processor,
        chat_template=CHAT_TEMPLATE,
    )  # fmt: skip
    processor.save_pretrained(target)


def _stats() -> dict[str, dict[str, torch.Tensor]]:
    def entry(low: list[float], high: list[float], mean: list[float], std: list[float]) -> dict:
        return {name: torch.tensor(values, dtype=torch.float32)
                for name, values in (("min", low), ("max", high), ("mean", mean), ("std", std))}  # fmt: skip

    action_mean = [(low + high) / 2 for low, high in zip(ACTION_MIN, ACTION_MAX, strict=True)]
    action_std = [(high - low) / 4 for low, high in zip(ACTION_MIN, ACTION_MAX, strict=True)]
    state_min = [m - 3 * s for m, s in zip(STATE_MEAN, STATE_STD, strict=True)]
    state_max = [m + 3 * s for m, s in zip(STATE_MEAN, STATE_STD, strict=True)]
    return {
        "action": entry(ACTION_MIN, ACTION_MAX, action_mean, action_std),
        "observation.state": entry(state_min, state_max, STATE_MEAN, STATE_STD),
    }


def build_tiny_checkpoint(folder: Path, chunk_length: int = 7, seed: int = 0) -> Path:
    """Write a tiny random ``vla_jepa`` checkpoint to ``folder`` (created) and return it.

    ``predict_action_chunk`` of the loaded policy returns ``(B, chunk_length, 7)``. Offline: nothing is
    downloaded. Load it with ``HF_HUB_CACHE=hub_cache(folder)`` and ``HF_HUB_OFFLINE=1`` (see the module).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    backbone = backbone_dir(folder)
    _build_backbone(backbone, extra_tokens=4 * chunk_length + 1)
    refs = backbone.parents[1] / "refs"
    refs.mkdir(parents=True, exist_ok=True)
    (refs / "main").write_text(REVISION)

    visual = PolicyFeature(type=FeatureType.VISUAL, shape=(3, IMAGE_SIZE, IMAGE_SIZE))
    config = VLAJEPAConfig(
        input_features={
            **{key: visual for key in IMAGE_KEYS},
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        chunk_size=chunk_length, n_action_steps=chunk_length, device="cpu",
        qwen_model_name=str(backbone),  # the hub id replaces it below, before saving
        enable_world_model=False, action_model_type="DiT-test", action_num_layers=1, action_hidden_size=32,
        num_embodied_action_tokens_per_instruction=4, num_inference_timesteps=2, torch_dtype="float32",
        push_to_hub=False,
    )  # fmt: skip
    policy = VLAJEPAPolicy(config)
    policy.config.qwen_model_name = HUB_ID
    policy.save_pretrained(folder)
    preprocessor, postprocessor = make_pre_post_processors(policy.config, dataset_stats=_stats())
    preprocessor.save_pretrained(folder)
    postprocessor.save_pretrained(folder)
    assert json.loads((folder / "config.json").read_text())["qwen_model_name"] == HUB_ID
    return folder


if __name__ == "__main__":
    print(build_tiny_checkpoint(Path(sys.argv[1])))
