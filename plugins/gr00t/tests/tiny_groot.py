"""Tiny random-weight LeRobot GR00T N1.7 checkpoint, built offline (model environment only).

Runs only inside ``.venv/models/gr00t`` (``lerobot[groot]==0.6.1``, transformers 5.5.4).  LeRobot
0.6.1 has a single GR00T version, N1.7 (``configuration_groot.py:30,56``; N1.5 is rejected).
File:line references below are in ``site-packages/lerobot/policies/groot``.

How a LeRobot GR00T checkpoint loads, and how this module makes that work offline:

* ``GrootPolicy.__init__`` always rebuilds the native model with
  ``GR00TN17.from_pretrained(config.base_model_path)`` (``modeling_groot.py:88-118``) before the
  checkpoint's ``model.safetensors`` overwrites it; ``base_model_path`` defaults to the hub id
  ``nvidia/GR00T-N1.7-3B`` (``configuration_groot.py:44,382``).  We keep that id, as checkpoints
  fine-tuned from the hub base do, and cache a *tiny* base model under it.
* The backbone width 2048 is hard-coded in ``_cosmos_reason2_qwen3_vl_config()``
  (``groot_n1_7.py:751-803``, ``hidden_size`` at 768), used whenever the base config's
  ``model_name`` is exactly ``nvidia/Cosmos-Reason2-2B`` (``groot_n1_7.py:353,748``); any other
  name goes through ``AutoConfig.from_pretrained``.  So the tiny base names the cache-only repo
  ``BACKBONE_ID`` (a small ``Qwen3VLConfig``; this logs one harmless "Unrecognized GR00T N1.7
  backbone model name" warning, ``groot_n1_7.py:810``) and shrinks ``backbone_embedding_dim``
  (default 2048, ``groot_n1_7.py:83``) and the DiT to match.
* The preprocessor's VLM step loads its processor from the hard-coded ``nvidia/Cosmos-Reason2-2B``
  (``processor_groot.py:1259,1369-1381``); transformers 5 ``AutoTokenizer`` also reads that repo's
  ``config.json``.  We cache there a character-level WordLevel tokenizer with the Qwen special
  tokens, Qwen3-VL-style image/video processors (patch 16, merge 2) and the tiny config.

So a loading process must get ``offline_env(hf_home)`` *before* it imports huggingface_hub,
transformers or lerobot (this module imports none of them at top level).

Facts found:

* Sampling noise: one ``torch.randn((B, action_horizon, max_action_dim))`` from the global
  generator in ``GR00TN17ActionHead.get_action_with_features`` (``groot_n1_7.py:657``); nothing
  else is random at inference.  No ``noise=`` can be passed (``predict_action_chunk`` only takes
  the RTC kwargs ``inference_delay``/``prev_chunk_left_over``, ``modeling_groot.py:474-502``).
  ``torch.manual_seed(s)`` before ``predict_action_chunk`` gives bitwise-equal chunks.  A row
  depends on the rest of the batch: it gets slice ``i`` of the batch-wide draw, and prompts are
  left-padded to the batch's longest (``processor_groot.py:1380,2191``; ~1e-5 differences).
* Preprocessor (``processor_groot.py:1254-1264``): rename (empty map) -> add batch dim ->
  ``GrootN17PackInputsStep`` (cameras ``observation.images.*`` in sorted key order, 1563-1598,
  stacked to video (B,T,V,H,W,C) uint8, floats in [0, 1] truncated to uint8 at 1347; ``task``
  lower-cased and stripped to alnum/space/_; ``observation.state`` min-max normalized to [-1, 1]
  with clipping, 1811-1824, zero-padded to 132; ``embodiment_id`` 10 = ``new_embodiment``) ->
  ``GrootN17VLMEncodeStep`` (square resize 256, centre crop 230, resize 256, Qwen3-VL chat prompt,
  tokenise) -> device.  Postprocessor (1300-1325): ``GrootActionUnpackUnnormalizeStep`` (slice to
  7-D, clamp to [-1, 1], invert min-max) -> cpu.  The min/max come from the ``dataset_stats``
  given at build time (here +-1, so env action = clamped model action) and are stored in the
  processor safetensors; ``normalization_mapping`` is IDENTITY and unused
  (``configuration_groot.py:258-269``).  ``predict_action_chunk`` returns normalized
  (B, min(action_horizon, chunk_size, n_action_steps) = 40, 7) (``modeling_groot.py:504-510``).
"""

from __future__ import annotations

import hashlib
import string
import tempfile
from pathlib import Path

BASE_MODEL_ID = "nvidia/GR00T-N1.7-3B"  # GrootConfig default base_model_path
PROCESSOR_ID = "nvidia/Cosmos-Reason2-2B"  # hard-coded in GrootN17VLMEncodeStep
BACKBONE_ID = "conflictbench/tiny-random-qwen3-vl"  # cache-only; any name but PROCESSOR_ID
CAMERA_KEYS = ("observation.images.image", "observation.images.image2")  # LIBERO agentview, wrist
STATE_DIM, ACTION_DIM, IMAGE_SIZE = 8, 7, 256
SPECIAL_TOKENS = (
    "<|endoftext|>",
    "<|im_start|>",
    "<|im_end|>",
    "<|vision_start|>",
    "<|vision_end|>",
    "<|image_pad|>",
    "<|video_pad|>",
)
# Minimal Qwen-style chat template: one user turn of images (placeholders) followed by text.
CHAT_TEMPLATE = (
    "{% for message in messages %}<|im_start|>{{ message['role'] }}\n"
    "{% for item in message['content'] %}"
    "{% if item['type'] == 'image' %}<|vision_start|><|image_pad|><|vision_end|>"
    "{% elif item['type'] == 'text' %}{{ item['text'] }}{% endif %}"
    "{% endfor %}<|im_end|>\n{% endfor %}"
)


def offline_env(hf_home: Path) -> dict[str, str]:
    """Environment variables a fresh loading process needs (set before any HF import)."""
    return {
        "HF_HOME": str(hf_home),
        "HF_HUB_OFFLINE": "1",
        "TRANSFORMERS_OFFLINE": "1",
        "ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16",
    }


def hub_snapshot(hf_home: Path, repo_id: str) -> Path:
    """Create ``$HF_HOME/hub/models--org--name/snapshots/<hash>`` with ``refs/main``; return it."""
    repo_dir = Path(hf_home) / "hub" / ("models--" + repo_id.replace("/", "--"))
    revision = hashlib.sha1(repo_id.encode()).hexdigest()
    (repo_dir / "refs").mkdir(parents=True, exist_ok=True)
    (repo_dir / "refs" / "main").write_text(revision)
    snapshot = repo_dir / "snapshots" / revision
    snapshot.mkdir(parents=True, exist_ok=True)
    return snapshot


def _save_processor(directory: Path):
    """Save a tiny Qwen3VLProcessor (character tokenizer + Qwen3-VL image/video processors)."""
    from tokenizers import AddedToken, Regex, Tokenizer, decoders, models, pre_tokenizers
    from transformers import (
        PreTrainedTokenizerFast,
        Qwen2VLImageProcessor,
        Qwen3VLProcessor,
        Qwen3VLVideoProcessor,
    )

    vocab = {token: i for i, token in enumerate(["<unk>", *string.printable])}
    backend = Tokenizer(models.WordLevel(vocab=vocab, unk_token="<unk>"))
    backend.pre_tokenizer = pre_tokenizers.Split(Regex(r"[\s\S]"), behavior="isolated")
    backend.decoder = decoders.Fuse()
    backend.add_special_tokens([AddedToken(t, special=True, normalized=False) for t in SPECIAL_TOKENS])
    tokenizer = PreTrainedTokenizerFast(
        tokenizer_object=backend, unk_token="<unk>", pad_token="<|endoftext|>", eos_token="<|im_end|>"
    )
    tokenizer.chat_template = CHAT_TEMPLATE
    vision = {"patch_size": 16, "merge_size": 2, "temporal_patch_size": 2}
    norm = {"image_mean": [0.5] * 3, "image_std": [0.5] * 3}
    processor = Qwen3VLProcessor(
        image_processor=Qwen2VLImageProcessor(
            **vision, **norm, size={"shortest_edge": 64 * 64, "longest_edge": 512 * 512}
        ),
        tokenizer=tokenizer,
        video_processor=Qwen3VLVideoProcessor(**vision, **norm),
        chat_template=CHAT_TEMPLATE,
    )
    processor.save_pretrained(directory)
    tokenizer.save_pretrained(directory)  # keeps the chat template on the tokenizer, too
    return tokenizer


def _backbone_config(tokenizer):
    from transformers import Qwen3VLConfig

    ids = {t: tokenizer.convert_tokens_to_ids(t) for t in SPECIAL_TOKENS}
    return Qwen3VLConfig(
        image_token_id=ids["<|image_pad|>"],
        video_token_id=ids["<|video_pad|>"],
        vision_start_token_id=ids["<|vision_start|>"],
        vision_end_token_id=ids["<|vision_end|>"],
        tie_word_embeddings=True,
        text_config={
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": 2,
            "num_attention_heads": 2,
            "num_key_value_heads": 1,
            "head_dim": 16,
            "vocab_size": len(tokenizer),
            "max_position_embeddings": 4096,
            "bos_token_id": ids["<|endoftext|>"],
            "eos_token_id": ids["<|im_end|>"],
            "rope_parameters": {
                "rope_type": "default",
                "rope_theta": 5000000.0,
                "mrope_section": [4, 2, 2],  # sums to head_dim / 2
                "mrope_interleaved": True,
            },
            "tie_word_embeddings": True,
        },
        vision_config={
            "depth": 2,
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_heads": 2,
            "out_hidden_size": 32,
            "patch_size": 16,
            "spatial_merge_size": 2,
            "temporal_patch_size": 2,
            "num_position_embeddings": 64,
            "deepstack_visual_indexes": [1],
        },
    )


def _base_config(model_name: str):
    from lerobot.policies.groot.groot_n1_7 import GR00TN17Config

    return GR00TN17Config(
        model_name=model_name,
        select_layer=2,  # = text num_hidden_layers (layers above it are dropped)
        backbone_embedding_dim=32,  # = text hidden_size (default 2048)
        hidden_size=32,
        input_embedding_dim=32,
        diffusion_model_cfg={
            "positional_embeddings": None,
            "num_layers": 4,  # blocks: text cross-attn, self, image cross-attn, self
            "num_attention_heads": 2,
            "attention_head_dim": 16,  # 2 * 16 = input_embedding_dim
            "norm_type": "ada_norm",
            "dropout": 0.2,
            "final_dropout": True,
            "output_dim": 32,  # = hidden_size
            "interleave_self_attention": True,
        },
        vl_self_attention_cfg={
            "positional_embeddings": None,
            "num_layers": 1,
            "num_attention_heads": 2,
            "attention_head_dim": 16,  # 2 * 16 = backbone_embedding_dim
            "dropout": 0.2,
            "final_dropout": True,
        },
        max_num_embodiments=32,
    )


def libero_features():
    from lerobot.configs import FeatureType, PolicyFeature

    inputs = {k: PolicyFeature(FeatureType.VISUAL, (3, IMAGE_SIZE, IMAGE_SIZE)) for k in CAMERA_KEYS}
    inputs["observation.state"] = PolicyFeature(FeatureType.STATE, (STATE_DIM,))
    return inputs, {"action": PolicyFeature(FeatureType.ACTION, (ACTION_DIM,))}


#: LIBERO-like min/max (so un-normalization visibly moves the actions): translation about ±0.9, rotation
#: about ±0.3, the gripper -1 (open) .. +1 (closed); the state: position, axis-angle, two gripper joints.
ACTION_MIN = [-0.9, -0.85, -0.9, -0.3, -0.25, -0.35, -1.0]
ACTION_MAX = [0.9, 0.8, 0.9, 0.3, 0.3, 0.35, 1.0]
STATE_MIN = [-0.4, -0.3, 0.8, 2.0, -1.5, -1.0, 0.0, -0.05]
STATE_MAX = [0.3, 0.4, 1.4, 3.5, 1.5, 1.0, 0.05, 0.0]


def libero_stats():
    import torch

    return {
        "observation.state": {"min": torch.tensor(STATE_MIN), "max": torch.tensor(STATE_MAX)},
        "action": {"min": torch.tensor(ACTION_MIN), "max": torch.tensor(ACTION_MAX)},
    }


def build_tiny_checkpoint(folder: Path, seed: int = 0, hf_home: Path | None = None) -> Path:
    """Write a tiny LeRobot ``groot`` checkpoint to ``folder`` and its hub-cache entries to ``hf_home``.

    ``hf_home`` defaults to ``folder / "hf_home"``; loaders must run with ``offline_env(hf_home)``.
    Returns ``folder``.  Needs no network and no HF_HOME in the building process.
    """
    import torch
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors
    from lerobot.policies.groot.configuration_groot import GrootConfig
    from lerobot.policies.groot.groot_n1_7 import GR00TN17

    folder = Path(folder)
    hf_home = Path(hf_home) if hf_home is not None else folder / "hf_home"
    torch.manual_seed(seed)

    processor_dir = hub_snapshot(hf_home, PROCESSOR_ID)
    tokenizer = _save_processor(processor_dir)
    backbone_dir = hub_snapshot(hf_home, BACKBONE_ID)
    for directory in (processor_dir, backbone_dir):  # AutoTokenizer reads config.json, too
        _backbone_config(tokenizer).save_pretrained(directory)

    # Build the native model from the local backbone folder, then store it as the cached base
    # model, naming the backbone by its (cache-resolved) hub id.
    base = GR00TN17(_base_config(str(backbone_dir)), load_backbone_weights=False)
    base.config.model_name = BACKBONE_ID
    base.save_pretrained(hub_snapshot(hf_home, BASE_MODEL_ID))

    # The policy constructor reloads the base model by path; give it a local copy whose
    # model_name is a local path too, so this process needs no HF_HOME.
    inputs, outputs = libero_features()
    with tempfile.TemporaryDirectory() as local_base:
        base.config.model_name = str(backbone_dir)
        base.save_pretrained(local_base)
        config = GrootConfig(base_model_path=local_base, input_features=inputs, output_features=outputs, device="cpu")
        policy = get_policy_class("groot")(config)
    policy.config.base_model_path = BASE_MODEL_ID  # as in checkpoints fine-tuned from the hub base
    preprocessor, postprocessor = make_pre_post_processors(policy.config, dataset_stats=libero_stats())
    policy.save_pretrained(folder)
    preprocessor.save_pretrained(folder)
    postprocessor.save_pretrained(folder)
    return folder


def libero_batch(batch_size: int = 2, seed: int = 0, tasks: list[str] | None = None) -> dict:
    """A LIBERO-like raw observation batch: two 256x256 cameras in [0, 1], 8-D state, task text."""
    import torch

    g = torch.Generator().manual_seed(seed)
    batch = {k: torch.rand(batch_size, 3, IMAGE_SIZE, IMAGE_SIZE, generator=g) for k in CAMERA_KEYS}
    batch["observation.state"] = torch.rand(batch_size, STATE_DIM, generator=g) * 2 - 1
    batch["task"] = tasks or [f"put the bowl on plate {i}" for i in range(batch_size)]
    return batch


def load_tiny_checkpoint(folder: Path):
    """Load ``(policy, preprocessor, postprocessor)`` exactly as for a real checkpoint."""
    from lerobot.configs import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    config = PreTrainedConfig.from_pretrained(folder)
    policy = get_policy_class(config.type).from_pretrained(folder, config=config)
    preprocessor, postprocessor = make_pre_post_processors(policy.config, pretrained_path=str(folder))
    return policy, preprocessor, postprocessor


if __name__ == "__main__":  # python tiny_groot.py FOLDER [HF_HOME]: build, print the folder
    import sys

    print(build_tiny_checkpoint(Path(sys.argv[1]), hf_home=Path(sys.argv[2]) if len(sys.argv) > 2 else None))
