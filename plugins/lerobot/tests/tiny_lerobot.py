"""Tiny random-weight LeRobot checkpoints of several policy types, built offline (model environment only).

    .venv/models/lerobot/bin/python plugins/lerobot/tests/tiny_lerobot.py --type smolvla --out DIR \\
        [--hub-cache CACHE] [--seed 0] [--check]
    .venv/models/lerobot/bin/python plugins/lerobot/tests/tiny_lerobot.py --type act pi05 xvla --out ROOT

writes in DIR (with several types, one process builds them all, each in ROOT/TYPE) what LeRobot 0.6.1's
``save_pretrained`` writes for a trained policy (``policy.save_pretrained``, then the two processor pipelines'
``save_pretrained``): ``config.json`` (with ``"type"``), ``model.safetensors``, ``policy_preprocessor.json`` /
``policy_postprocessor.json`` and their ``*.safetensors`` statistics. The same command writes the same bytes
(every draw is seeded by ``--seed``), so pinned actions recorded with one build hold for the next.

Inputs and outputs are those of a LeRobot LIBERO checkpoint (trained on LeRobot's 256-px LIBERO datasets):
``observation.images.image`` (agentview) and ``observation.images.image2`` (wrist), VISUAL ``(3, 256, 256)``;
``observation.state`` ``(8,)``; ``action`` ``(7,)`` -- except X-VLA, whose LIBERO checkpoints keep its 20-D
``ee6d`` action space (``action (20,)``: LeRobot's X-VLA environment post-processor,
``policies/xvla/processor_xvla.py:450-505``, turns the first 10 of those into LIBERO's 7; its environment
preprocessor builds a 20-D state, eef position and 6-D rotation, which the model pads to 32). X-VLA's saved
preprocessor leaves out the two image steps 0.6.1's factory adds (see ``build_checkpoint``). Every type accepts
the 360-px renders ``lerobot-eval`` gives it (``--check`` runs them): ACT's ResNet and X-VLA's DaViT take any
size, Diffusion resizes (``resize_shape``), SmolVLA and pi0.5 resize with padding, Multi-task DiT crops.
Normalization statistics are seeded random, LIBERO-like and far from identity, so a missing or doubled
normalization shows in the actions.

Types (``TYPES``): ``act`` and ``diffusion`` (ResNet-18 without ImageNet weights: ``pretrained_backbone_weights``
None), ``smolvla``, ``pi05``, ``xvla`` and ``multi_task_dit``. Small widths, short chunks and few denoising steps
keep a chunk's ``select_action`` well under a second on one CPU thread (``--check`` times it). The transformer
types' weights are redrawn at unit gain (``reinitialize_at_unit_gain``) so that their inputs move the actions.

Names a type loads from the hub are written, tiny, as Hugging Face hub-cache entries under ``--hub-cache``
(default: the checkpoint's own, ``DIR/hub``, so the folder survives a copy), and the checkpoint's config keeps
the real names: it loads with ``HF_HUB_OFFLINE=1`` and ``HF_HUB_CACHE`` naming that folder (set before Python
starts):

- ``smolvla``: ``HuggingFaceTB/SmolVLM2-500M-Video-Instruct`` -- a SmolVLM (2-layer Llama of width 64, a 1-layer
  SigLIP of width 32 at SmolVLM2's 512-px input, patch 16, pixel-shuffle 4: 64 tokens an image, as the real one),
  config and seeded weights, and its processor (tokenizer with SmolVLM's image special tokens, image and video
  processors). The checkpoint's ``load_vlm_weights`` is false: the VLM is built from the config in float32 and
  its weights come from ``model.safetensors``. (A checkpoint with it true first loads the hub VLM in bfloat16,
  ``smolvlm_with_expert.py:91-96``, and keeps those parameters in bfloat16 after ``from_pretrained``: measured
  with this stand-in, 60 of 72 parameter tensors. Its weights are in the stand-in for that case.);
- ``pi05``: ``google/paligemma-3b-pt-224`` -- a byte-level BPE tokenizer of
  ``tiny_patches/sitecustomize.TINY_VOCAB`` tokens. pi0.5's model sizes are fixed in LeRobot's code, so a process
  that builds or loads this checkpoint needs ``tiny_patches`` on ``PYTHONPATH`` (see that module; this script adds
  it itself);
- ``xvla``: ``facebook/bart-large`` -- a byte-level BPE tokenizer; the Florence-2 config is the checkpoint's own
  ``florence_config`` (a 4-stage DaViT of width 16-32 and a 1-layer BART of width 32), nothing is downloaded;
- ``multi_task_dit``: ``openai/clip-vit-base-patch16`` -- a tiny CLIP (both towers of width 32, one layer,
  224-px images of patch 32) with weights, and its tokenizer.

``--check`` then loads the folder as the plugin's server does and as ``lerobot-eval`` plays LIBERO (LeRobot
0.6.1, ``scripts/lerobot_eval.py: rollout``): ``PreTrainedConfig.from_pretrained``, the policy class's
``from_pretrained``, ``make_pre_post_processors(..., preprocessor_overrides={"device_processor": cpu})``,
``make_env_pre_post_processors(LiberoEnv(), cfg)``; then, on LIBERO-shaped raw observations (360-px uint8
images as robosuite renders them, float64 robot state, batch of one), ``preprocess_observation``, the task, the
environment preprocessor, the preprocessor, ``select_action``, the postprocessor and the environment
postprocessor, for more steps than a chunk. It prints one JSON line: timings, the first actions, and how far
the action moves when an image is flipped, the state changes or the task text changes (all with the same seed):
a processing bug upstream of the model must move the action. With several types and no ``--hub-cache``, each
is loaded from its own hub cache in turn.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
PATCHES = HERE / "tiny_patches"
TYPES = ("act", "diffusion", "smolvla", "pi05", "xvla", "multi_task_dit")
IMAGE_KEYS = ("observation.images.image", "observation.images.image2")  # agentview, wrist: LeRobot's LIBERO names
DATASET_IMAGE_SHAPE = (3, 256, 256)  # LeRobot's LIBERO datasets
RENDER_SIZE = 360  # what lerobot-eval's LiberoEnv config renders (envs/configs.py:333-334)
STATE_DIM, ACTION_DIM = 8, 7
XVLA_ACTION_DIM = 20  # X-VLA's ee6d action space (policies/xvla/action_hub.py:113-117)

SMOLVLM = "HuggingFaceTB/SmolVLM2-500M-Video-Instruct"
PALIGEMMA = "google/paligemma-3b-pt-224"
BART = "facebook/bart-large"
CLIP = "openai/clip-vit-base-patch16"

#: Per type: LeRobot config fields of the tiny checkpoint (chunk length, queue, sizes, denoising steps). Each
#: executes fewer actions than it predicts (``n_action_steps < chunk``), so the queue's slice is exercised.
OPTIONS: dict[str, dict] = {
    "act": dict(
        chunk_size=20, n_action_steps=10, pretrained_backbone_weights=None, dim_model=64, n_heads=4,
        dim_feedforward=128, n_encoder_layers=1, n_decoder_layers=1, n_vae_encoder_layers=1, latent_dim=8,
    ),
    "diffusion": dict(
        n_obs_steps=2, horizon=16, n_action_steps=8, pretrained_backbone_weights=None, use_group_norm=True,
        resize_shape=(96, 96), crop_ratio=0.9, spatial_softmax_num_keypoints=8, down_dims=(32, 64),
        kernel_size=3, n_groups=4, diffusion_step_embed_dim=32, num_inference_steps=4,
    ),
    "smolvla": dict(
        vlm_model_name=SMOLVLM, load_vlm_weights=False, chunk_size=10, n_action_steps=5, num_steps=3,
        num_vlm_layers=2, num_expert_layers=-1, self_attn_every_n_layers=2, expert_width_multiplier=0.75,
    ),
    "pi05": dict(chunk_size=10, n_action_steps=5, num_inference_steps=3, dtype="float32"),
    "xvla": dict(
        tokenizer_name=BART, action_mode="ee6d", chunk_size=8, n_action_steps=4, num_denoising_steps=3,
        hidden_size=32, depth=1, num_heads=2, len_soft_prompts=4, dim_time=16, max_len_seq=512,
        tokenizer_max_length=32, dtype="float32",
    ),
    "multi_task_dit": dict(
        vision_encoder_name=CLIP, text_encoder_name=CLIP, n_obs_steps=2, horizon=16, n_action_steps=8,
        hidden_dim=32, num_layers=1, num_heads=2, timestep_embed_dim=32, num_inference_steps=4,
        image_crop_shape=(224, 224), dropout=0.0,
    ),
}  # fmt: skip

#: LIBERO instructions and the prompt words of pi0.5 (``Task: ..., State: ...;\nAction: ``): the tokenizers'
#: merges are learnt from these, so typical task text takes few tokens (any text still encodes: byte level).
CORPUS = """
put the black bowl on the plate pick up the alphabet soup and place it in the basket
open the middle drawer of the cabinet put the bowl on the stove turn on the stove
put the wine bottle on top of the cabinet open the top drawer and put the bowl inside
push the plate to the front of the stove put the cream cheese in the bowl
pick up the ketchup and place it in the basket pick up the tomato sauce and place it in the basket
put both the alphabet soup and the tomato sauce in the basket put both moka pots on the stove
put the yellow and white mug in the microwave and close it turn on the stove and put the moka pot on it
put the white mug on the left plate and put the yellow and white mug on the right plate
pick up the book and place it in the back compartment of the caddy
put the black bowl in the bottom drawer of the cabinet and close it
pick up the black bowl between the plate and the ramekin and place it on the plate
pick up the black bowl next to the cookie box and place it on the plate
Task: State: Action: ; , . : \n
"""


# ---------------------------------------------------------------------------------------------------------------
# Hub-cache stand-ins


def write_hub_entry(hub_cache: Path, repo_id: str, save) -> Path:
    """Lay out what ``save(folder)`` writes as the cached snapshot of hub model ``repo_id``.

    The snapshot's name is a digest of its files, so the same stand-in always lands in the same place, and a
    second builder writing the same entry at the same time finds it already there.
    """
    repo_dir = hub_cache / ("models--" + repo_id.replace("/", "--"))
    repo_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix="staging-", dir=repo_dir))
    save(staging)
    digest = hashlib.sha1()
    for path in sorted(p for p in staging.rglob("*") if p.is_file()):
        digest.update(str(path.relative_to(staging)).encode() + b"\0" + path.read_bytes() + b"\0")
    revision = digest.hexdigest()
    snapshot = repo_dir / "snapshots" / revision
    snapshot.parent.mkdir(exist_ok=True)
    try:
        staging.rename(snapshot)
    except OSError:  # already there, with the same content
        shutil.rmtree(staging)
    (repo_dir / "refs").mkdir(exist_ok=True)
    (repo_dir / "refs" / "main").write_text(revision)
    return snapshot


def bpe_tokenizer(vocab_size: int, special_tokens: list[str], corpus: str = CORPUS):
    """A byte-level BPE (``tokenizers``) with ``special_tokens`` first, trained on ``corpus`` (deterministic)."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers

    tokenizer = Tokenizer(models.BPE())
    tokenizer.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    tokenizer.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=vocab_size,
        special_tokens=special_tokens,
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        show_progress=False,
    )
    tokenizer.train_from_iterator([corpus] * 4, trainer=trainer)
    return tokenizer


def save_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")


def smolvlm_stand_in(folder: Path) -> None:
    """SmolVLM2's config and processor, tiny: what SmolVLA's ``AutoConfig`` / ``AutoProcessor`` /
    ``AutoTokenizer`` read (``policies/smolvla/smolvlm_with_expert.py:97-101``, ``processor_smolvla.py``)."""
    import torch
    from transformers import (
        PreTrainedTokenizerFast,
        SmolVLMConfig,
        SmolVLMForConditionalGeneration,
        SmolVLMImageProcessor,
        SmolVLMProcessor,
        SmolVLMVideoProcessor,
    )

    image_tokens = {
        "fake_image_token": "<fake_token_around_image>",
        "image_token": "<image>",
        "global_image_token": "<global-img>",
        "end_of_utterance_token": "<end_of_utterance>",
    }
    specials = ["<|endoftext|>", "<|im_start|>", "<unk>", *image_tokens.values()]
    core = bpe_tokenizer(600, specials)
    tokenizer = PreTrainedTokenizerFast(
        tokenizer_object=core, bos_token="<|im_start|>", eos_token="<end_of_utterance>", pad_token="<|endoftext|>",
        unk_token="<unk>", extra_special_tokens=image_tokens, model_max_length=8192,
    )  # fmt: skip
    image_processor = SmolVLMImageProcessor(
        do_resize=True, size={"longest_edge": 512}, do_image_splitting=False, max_image_size={"longest_edge": 512}
    )
    processor = SmolVLMProcessor(
        image_processor=image_processor, tokenizer=tokenizer, video_processor=SmolVLMVideoProcessor(), image_seq_len=64
    )
    processor.save_pretrained(folder)
    config = SmolVLMConfig(
        text_config=dict(
            model_type="llama", vocab_size=len(tokenizer), hidden_size=64, intermediate_size=128, num_hidden_layers=2,
            num_attention_heads=4, num_key_value_heads=2, head_dim=16, max_position_embeddings=2048,
            pad_token_id=tokenizer.pad_token_id,
        ),
        vision_config=dict(
            hidden_size=32, intermediate_size=64, num_hidden_layers=1, num_attention_heads=2, image_size=512,
            patch_size=16,
        ),
        scale_factor=4, image_token_id=tokenizer.convert_tokens_to_ids("<image>"), pad_token_id=tokenizer.pad_token_id,
    )  # fmt: skip
    config.save_pretrained(folder)
    # Weights too, as the hub has them, for a config with ``load_vlm_weights`` true (which loads them in bfloat16,
    # smolvlm_with_expert.py:91-96, then overwrites them from model.safetensors).
    torch.manual_seed(0)
    SmolVLMForConditionalGeneration(config).save_pretrained(folder)


def size_patch():
    """``tiny_patches/sitecustomize.py`` loaded as a module (it installs pi0.5's size patch once per process)."""
    import importlib.util

    name = "conflictbench_lerobot_tiny_sizes"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, PATCHES / "sitecustomize.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def paligemma_stand_in(folder: Path) -> None:
    """PaliGemma's tokenizer, tiny: what pi0.5's processor loads by name (``policies/pi05/processor_pi05.py:141``)."""
    from tokenizers import processors

    TINY_VOCAB = size_patch().TINY_VOCAB  # noqa: N806

    numbers = " ".join(str(number) for number in range(256))  # pi0.5 writes the state as bin numbers
    core = bpe_tokenizer(TINY_VOCAB, ["<pad>", "<eos>", "<bos>", "<unk>"], CORPUS + numbers + "\n")
    if core.get_vocab_size() > TINY_VOCAB:
        raise RuntimeError(f"the tiny PaliGemma tokenizer has {core.get_vocab_size()} tokens, over {TINY_VOCAB}")
    bos = core.token_to_id("<bos>")
    core.post_processor = processors.TemplateProcessing(
        single="<bos> $A", pair="<bos> $A $B", special_tokens=[("<bos>", bos)]
    )
    (folder / "tokenizer.json").write_text(core.to_str())
    save_json(
        folder / "tokenizer_config.json",
        dict(tokenizer_class="PreTrainedTokenizerFast", bos_token="<bos>", eos_token="<eos>", pad_token="<pad>",
             unk_token="<unk>", padding_side="right", model_max_length=1_000_000),
    )  # fmt: skip
    save_json(folder / "config.json", {})  # transformers looks for a model config beside a tokenizer


def bart_tokenizer():
    from tokenizers import processors

    core = bpe_tokenizer(500, ["<s>", "<pad>", "</s>", "<unk>", "<mask>"])
    core.post_processor = processors.TemplateProcessing(
        single="<s> $A </s>", pair="<s> $A </s> </s> $B </s>",
        special_tokens=[("<s>", core.token_to_id("<s>")), ("</s>", core.token_to_id("</s>"))],
    )  # fmt: skip
    return core


def bart_stand_in(folder: Path) -> None:
    """BART's tokenizer, tiny: what X-VLA's processor loads by ``tokenizer_name``."""
    core = bart_tokenizer()
    (folder / "tokenizer.json").write_text(core.to_str())
    save_json(
        folder / "tokenizer_config.json",
        dict(tokenizer_class="PreTrainedTokenizerFast", bos_token="<s>", eos_token="</s>", pad_token="<pad>",
             unk_token="<unk>", mask_token="<mask>", padding_side="right", model_max_length=1024),
    )  # fmt: skip
    save_json(folder / "config.json", {})


def xvla_florence_config() -> dict:
    """A tiny Florence-2 (``XVLAConfig.florence_config``): DaViT 16-16-32-32 wide, one block a stage; 1-layer BART."""
    vocab = bart_tokenizer().get_vocab_size()
    return {
        "vision_config": {
            "depths": [1, 1, 1, 1], "embed_dim": [16, 16, 32, 32], "num_heads": [1, 1, 2, 2],
            "num_groups": [1, 1, 2, 2], "window_size": 4, "projection_dim": 32, "max_position_embeddings": 64,
        },
        "text_config": {
            "model_type": "bart", "vocab_size": vocab + 1, "d_model": 32, "encoder_layers": 1, "decoder_layers": 1,
            "encoder_attention_heads": 2, "decoder_attention_heads": 2, "encoder_ffn_dim": 64,
            "decoder_ffn_dim": 64, "max_position_embeddings": 256,
        },
        "image_token_id": vocab, "bos_token_id": 0, "pad_token_id": 1, "eos_token_id": 2,
    }  # fmt: skip


def clip_stand_in(folder: Path) -> None:
    """CLIP, tiny, with weights and tokenizer: what Multi-task DiT's encoders and processor load by name."""
    import torch
    from transformers import CLIPConfig, CLIPModel, PreTrainedTokenizerFast

    core = bpe_tokenizer(500, ["<|startoftext|>", "<|endoftext|>"])
    tokenizer = PreTrainedTokenizerFast(
        tokenizer_object=core, bos_token="<|startoftext|>", eos_token="<|endoftext|>", pad_token="<|endoftext|>",
        unk_token="<|endoftext|>", model_max_length=77,
    )  # fmt: skip
    tokenizer.save_pretrained(folder)
    torch.manual_seed(0)
    config = CLIPConfig(
        text_config=dict(
            vocab_size=len(tokenizer), hidden_size=32, intermediate_size=64, num_hidden_layers=1,
            num_attention_heads=2, max_position_embeddings=77, projection_dim=32,
            eos_token_id=tokenizer.eos_token_id, bos_token_id=tokenizer.bos_token_id,
            pad_token_id=tokenizer.pad_token_id,
        ),
        vision_config=dict(
            hidden_size=32, intermediate_size=64, num_hidden_layers=1, num_attention_heads=2, image_size=224,
            patch_size=32, projection_dim=32,
        ),
        projection_dim=32,
    )  # fmt: skip
    CLIPModel(config).save_pretrained(folder)


STAND_INS = {
    "smolvla": [(SMOLVLM, smolvlm_stand_in)],
    "pi05": [(PALIGEMMA, paligemma_stand_in)],
    "xvla": [(BART, bart_stand_in)],
    "multi_task_dit": [(CLIP, clip_stand_in)],
}


# ---------------------------------------------------------------------------------------------------------------
# The checkpoint


def libero_like_stats(seed: int, action_dim: int) -> dict[str, dict[str, list]]:
    """Normalization statistics shaped like LeRobot's LIBERO datasets', perturbed by ``seed``: every statistic a
    type may use (mean/std, min/max, quantiles), for the state, the action and each camera."""
    import numpy as np

    rng = np.random.default_rng(seed)
    state_mean = np.array([-0.05, 0.03, 1.0, 3.0, -0.1, 0.0, 0.03, -0.03])
    state_std = np.array([0.1, 0.15, 0.1, 0.3, 0.4, 0.3, 0.01, 0.01])
    action_mean = np.array([0.06, 0.09, -0.1, 0.0, 0.005, -0.005, -0.1])
    action_std = np.array([0.3, 0.35, 0.45, 0.04, 0.06, 0.08, 0.99])
    if action_dim > ACTION_DIM:
        action_mean = np.resize(action_mean, action_dim)
        action_std = np.resize(action_std, action_dim)

    def stats(mean, std, shape=None):
        mean = mean + rng.normal(0.0, 0.2, mean.shape) * std
        std = std * rng.uniform(0.7, 1.4, std.shape)
        entry = {
            "mean": mean, "std": std, "min": mean - 3 * std, "max": mean + 3 * std, "q01": mean - 2.3 * std,
            "q99": mean + 2.3 * std, "q10": mean - 1.3 * std, "q90": mean + 1.3 * std,
        }  # fmt: skip
        return {name: (value.reshape(shape) if shape else value).tolist() for name, value in entry.items()}

    result = {"observation.state": stats(state_mean, state_std), "action": stats(action_mean, action_std)}
    for key in IMAGE_KEYS:
        image = stats(np.array([0.45, 0.42, 0.38]), np.array([0.25, 0.24, 0.26]), (3, 1, 1))
        image["min"], image["max"] = [[[0.0]]] * 3, [[[1.0]]] * 3
        result[key] = image
    return result


def reinitialize_at_unit_gain(module) -> None:
    """Linear, convolution and embedding weights of std 1/sqrt(fan_in) (embeddings 1/sqrt(width)), biases 0.

    The transformers' own init (std 0.02, for full-size models) leaves a model this narrow nearly blind to its
    inputs; at unit gain an image, the state or the prompt visibly moves the actions, as in a trained model.
    """
    import torch
    from torch import nn

    with torch.no_grad():
        for child in module.modules():
            if isinstance(child, (nn.Linear, nn.Conv1d, nn.Conv2d)):
                child.weight.normal_(0.0, child.weight[0].numel() ** -0.5)
                if child.bias is not None:
                    child.bias.zero_()
            elif isinstance(child, nn.Embedding):
                child.weight.normal_(0.0, child.embedding_dim**-0.5)


def build_checkpoint(policy_type: str, out: Path, seed: int) -> None:
    """Construct the tiny policy with LeRobot's own classes and save it as LeRobot saves a trained one."""
    import torch
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    action_dim = XVLA_ACTION_DIM if policy_type == "xvla" else ACTION_DIM
    options = dict(OPTIONS[policy_type])
    if policy_type == "xvla":
        options["florence_config"] = xvla_florence_config()
    image = PolicyFeature(type=FeatureType.VISUAL, shape=DATASET_IMAGE_SHAPE)
    config = PreTrainedConfig.get_choice_class(policy_type)(
        input_features={
            IMAGE_KEYS[0]: image,
            IMAGE_KEYS[1]: image,
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,))},
        device="cpu",
        push_to_hub=False,
        **options,
    )
    torch.manual_seed(seed)
    policy = get_policy_class(policy_type)(config)
    if policy_type in ("smolvla", "pi05", "xvla", "multi_task_dit"):
        reinitialize_at_unit_gain(policy)
    policy.save_pretrained(out)
    stats = {
        key: {name: torch.tensor(values, dtype=torch.float32) for name, values in entry.items()}
        for key, entry in libero_like_stats(seed, action_dim).items()
    }
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=stats)
    if policy_type == "xvla":
        # As LeRobot's LIBERO X-VLA checkpoints: no image steps in the policy's own pipeline, where LeRobot's X-VLA
        # environment preprocessor already scales and ImageNet-normalizes (processor_xvla.py:515-527). The steps
        # 0.6.1's factory adds (processor_xvla.py:59-71) would then refuse the normalized images
        # (``xvla_image_to_float``: "values outside [0, 255]"; measured), so lerobot-eval could not play it.
        from lerobot.policies.xvla.processor_xvla import (
            XVLAImageNetNormalizeProcessorStep,
            XVLAImageToFloatProcessorStep,
        )

        image_steps = (XVLAImageToFloatProcessorStep, XVLAImageNetNormalizeProcessorStep)
        preprocessor.steps[:] = [step for step in preprocessor.steps if not isinstance(step, image_steps)]
    preprocessor.save_pretrained(out)
    postprocessor.save_pretrained(out)


# ---------------------------------------------------------------------------------------------------------------
# The check: loaded and played as lerobot-eval plays LIBERO


def raw_libero_observation(rng, size: int) -> dict:
    """One LIBERO observation as ``LiberoEnv._format_raw_obs`` gives it, batched by the vector env (batch of one):
    uint8 HWC images as robosuite renders them, float64 robot state (``envs/libero.py:287-337``)."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    quat = Rotation.from_rotvec([np.pi, 0.0, 0.0]) * Rotation.from_rotvec(rng.normal(0.0, 0.2, 3))
    gripper = rng.uniform(0.0, 0.04)

    def batch(value):
        return np.asarray(value, dtype=np.float64)[None]

    return {
        "pixels": {name: rng.integers(0, 256, (1, size, size, 3), dtype=np.uint8) for name in ("image", "image2")},
        "robot_state": {
            "eef": {
                "pos": batch([-0.2, 0.0, 1.1] + rng.normal(0.0, 0.05, 3)),
                "quat": batch(quat.as_quat()),  # x, y, z, w (robosuite's order)
                "mat": batch(quat.as_matrix()),
            },
            "gripper": {"qpos": batch([gripper, -gripper]), "qvel": batch(rng.normal(0.0, 0.01, 2))},
            "joints": {"pos": batch(rng.normal(0.0, 0.5, 7)), "vel": batch(rng.normal(0.0, 0.05, 7))},
        },
    }


def check_checkpoint(folder: Path, size: int = RENDER_SIZE, seed: int = 0) -> dict:
    """Load ``folder`` as the server does and play LIBERO-shaped observations as ``lerobot-eval``'s rollout does."""
    import copy

    import numpy as np
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.configs import LiberoEnv
    from lerobot.envs.factory import make_env_pre_post_processors
    from lerobot.envs.utils import preprocess_observation
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    start = time.perf_counter()
    config = PreTrainedConfig.from_pretrained(folder)
    policy = get_policy_class(config.type).from_pretrained(folder, config=config)
    policy.eval()
    preprocessor, postprocessor = make_pre_post_processors(
        config, pretrained_path=str(folder), preprocessor_overrides={"device_processor": {"device": "cpu"}}
    )
    env_preprocessor, env_postprocessor = make_env_pre_post_processors(LiberoEnv(), config)
    load_s = time.perf_counter() - start

    def act(raw: dict, task: str) -> tuple[np.ndarray, float]:
        begin = time.perf_counter()
        observation = preprocess_observation(copy.deepcopy(raw))
        observation["task"] = [task]
        observation = preprocessor(env_preprocessor(observation))
        with torch.inference_mode():
            action = policy.select_action(observation)
        action = env_postprocessor({"action": postprocessor(action)})["action"]
        action = action.to("cpu").numpy()
        return action, time.perf_counter() - begin

    rng = np.random.default_rng(seed)
    task = "put the black bowl in the bottom drawer of the cabinet and close it"
    observations = [raw_libero_observation(rng, size) for _ in range(config.n_action_steps + 1)]
    torch.manual_seed(seed)
    policy.reset()
    actions, seconds = [], []
    for raw in observations:  # a whole chunk from the queue, then the next chunk
        action, took = act(raw, task)
        if action.shape != (1, ACTION_DIM) or not np.isfinite(action).all():
            raise RuntimeError(f"{config.type}: action {action!r} is not one finite {ACTION_DIM}-D row")
        actions.append(action[0])
        seconds.append(took)

    def first_action(raw: dict, text: str) -> np.ndarray:
        torch.manual_seed(seed)
        policy.reset()
        return act(raw, text)[0][0]

    base = observations[0]
    flipped = copy.deepcopy(base)
    flipped["pixels"]["image"] = flipped["pixels"]["image"][:, ::-1, ::-1].copy()
    wrist = copy.deepcopy(base)
    wrist["pixels"]["image2"] = wrist["pixels"]["image2"][:, ::-1].copy()
    moved = copy.deepcopy(base)
    moved["robot_state"]["eef"]["pos"] = moved["robot_state"]["eef"]["pos"] + 0.05
    moved["robot_state"]["gripper"]["qpos"] = moved["robot_state"]["gripper"]["qpos"] * 0.5
    reference = first_action(base, task)
    if not np.array_equal(reference, actions[0]):
        raise RuntimeError(f"{config.type}: the same seed and observation gave another action")

    def moves(action: np.ndarray) -> float:
        return float(np.abs(action - reference).max())

    return {
        "type": config.type,
        "render": size,
        "load_s": round(load_s, 3),
        "first_step_s": round(seconds[0], 3),
        "queued_step_s": round(float(np.median(seconds[1:-1])), 4),
        "refill_step_s": round(seconds[-1], 3),
        "n_action_steps": config.n_action_steps,
        "actions": [[float(x) for x in row] for row in actions[:2]],
        "moved_by": {
            "agentview_flipped": moves(first_action(flipped, task)),
            "wrist_flipped": moves(first_action(wrist, task)),
            "state": moves(first_action(moved, task)),
            "task": moves(first_action(base, "open the top drawer and put the bowl inside")),
        },
    }


def digest(folder: Path) -> str:
    """One digest of every file under ``folder`` (names and bytes): equal across builds when deterministic."""
    sha = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        sha.update(str(path.relative_to(folder)).encode() + b"\0" + path.read_bytes())
    return sha.hexdigest()


def hub_cache(checkpoint: Path) -> Path:
    """The hub cache a checkpoint built without ``--hub-cache`` carries: what ``HF_HUB_CACHE`` must name to load it."""
    return Path(checkpoint) / "hub"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--type", choices=TYPES, nargs="+", required=True,
        help="a LeRobot policy type; or several, built in one process: then OUT is their parent, each in OUT/TYPE",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, required=True, help="the checkpoint folder to write")
    parser.add_argument(
        "--hub-cache", type=Path,
        help="the hub cache the stand-ins go into (default: each checkpoint's own, CHECKPOINT/hub)",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--check", action="store_true", help="then load and play it as lerobot-eval would")
    parser.add_argument("--no-build", action="store_true", help="only check existing folders (OUT as built)")
    parser.add_argument("--render", type=int, default=RENDER_SIZE, help="the image size the check renders")
    args = parser.parse_args(argv)

    types = list(dict.fromkeys(args.type))
    out = args.out.resolve()
    folders = {types[0]: out} if len(types) == 1 else {policy_type: out / policy_type for policy_type in types}
    if args.hub_cache:
        cache = args.hub_cache.resolve()
    elif len(types) == 1:
        cache = hub_cache(out)
    else:  # built together in one process, then each type's stand-ins copied into its checkpoint's own cache
        cache = out / "hub"
    # The hub client and transformers read these once, at import: set them before anything imports them.
    os.environ["HF_HUB_CACHE"] = str(cache)
    os.environ["HF_HUB_OFFLINE"] = "1"
    os.environ["TRANSFORMERS_OFFLINE"] = "1"
    os.environ.setdefault("ONEDNN_MAX_CPU_ISA", "AVX512_CORE_BF16")
    if "pi05" in types:
        if not args.no_build:
            size_patch()  # pi0.5's tiny sizes, before LeRobot is imported (a no-op where PYTHONPATH has it)
        elif not any(type(finder).__name__ == "_Pi05Finder" for finder in sys.meta_path):
            # Loading without it would build the full-size model (gigabytes) and then fail on the weights.
            parser.error(f"a tiny pi05 loads only with {PATCHES} on PYTHONPATH (see its sitecustomize.py)")
    import torch

    torch.set_num_threads(1)
    for policy_type, folder in folders.items():
        own_cache = hub_cache(folder) if len(types) > 1 and not args.hub_cache else cache
        summary: dict = {
            "type": policy_type,
            "out": str(folder),
            "hub_cache": str(own_cache) if STAND_INS.get(policy_type) else None,
        }
        if not args.no_build:
            start = time.perf_counter()
            folder.mkdir(parents=True, exist_ok=True)
            for repo_id, save in STAND_INS.get(policy_type, []):
                write_hub_entry(cache, repo_id, save)
                if own_cache != cache:
                    name = "models--" + repo_id.replace("/", "--")
                    shutil.copytree(cache / name, own_cache / name, dirs_exist_ok=True)
            build_checkpoint(policy_type, folder, args.seed)
            summary["build_s"] = round(time.perf_counter() - start, 2)
            summary["digest"] = digest(folder)
        if args.check:
            if own_cache != cache:
                # Each checkpoint loads from its own hub cache. The hub client reads HF_HUB_CACHE at import, but
                # it and transformers look up ``constants.HF_HUB_CACHE`` at each call (huggingface_hub
                # file_download.py, transformers utils/hub.py), so one process can switch between checkpoints.
                from huggingface_hub import constants

                constants.HF_HUB_CACHE = os.environ["HF_HUB_CACHE"] = str(own_cache)
            summary.update(check_checkpoint(folder, args.render, args.seed))
        print(json.dumps(summary), flush=True)
    if len(types) > 1 and not args.hub_cache and not args.no_build:
        shutil.rmtree(cache)  # each checkpoint has its own copy
    return 0


if __name__ == "__main__":
    sys.exit(main())
