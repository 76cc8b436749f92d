"""Builds a tiny random-weight LeRobot pi0 / pi0.5 / pi0-FAST checkpoint, fully offline.

    PYTHONPATH=plugins/pi0/tests/tiny/patches HF_HUB_OFFLINE=1 ONEDNN_MAX_CPU_ISA=AVX512_CORE_BF16 \\
        .venv/models/pi0/bin/python plugins/pi0/tests/tiny/build.py --policy pi05 --out DIR --hf-home HOME

Writes, in DIR, what LeRobot's ``save_pretrained`` writes for a trained policy: ``config.json``,
``model.safetensors`` and the pre/post-processor pipelines with their normalization statistics (a LIBERO-like
8-D state and 7-D action, random but fixed by ``--seed``). In HOME (to be used as ``HF_HOME`` with
``HF_HUB_OFFLINE=1``) it writes the hub-cache entries the policies ask for by name:
``google/paligemma-3b-pt-224`` (a tiny byte-level BPE tokenizer of ``TINY_VOCAB`` tokens) and, for pi0-FAST,
``lerobot/fast-action-tokenizer`` (``patches/fast_standin.py`` as its remote code).

Must run with ``tests/tiny/patches`` on ``PYTHONPATH`` (see ``patches/sitecustomize.py``): the model sizes are
shrunk there, and any process that loads the checkpoint needs the same patch.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
from pathlib import Path

PATCHES = Path(__file__).resolve().parent / "patches"
POLICY_TYPES = {"pi0": "pi0", "pi05": "pi05", "pi0-fast": "pi0_fast"}
TEXT_TOKENIZER = "google/paligemma-3b-pt-224"
FAST_TOKENIZER = "lerobot/fast-action-tokenizer"
IMAGE_KEYS = ("observation.images.image", "observation.images.image2")  # LeRobot's LIBERO names
STATE_DIM, ACTION_DIM = 8, 7
#: chunk_size, n_action_steps per policy type: openpi's LIBERO horizons (pi0 50, pi0.5 and FAST 10 replies).
CHUNKS = {"pi0": (50, 50), "pi05": (50, 10), "pi0_fast": (10, 10)}

# Words of LIBERO instructions and the pi0.5/FAST prompt templates: the tokenizer's merges come from these.
_CORPUS = """
put the black bowl on the plate pick up the alphabet soup and place it in the basket
open the middle drawer of the cabinet put the bowl on the stove turn on the stove
put the wine bottle on top of the cabinet open the top drawer and put the bowl inside
push the plate to the front of the stove put the cream cheese in the bowl
put the bowl on top of the cabinet pick up the ketchup and place it in the basket
pick up the tomato sauce and place it in the basket pick up the butter and place it in the basket
pick up the milk and place it in the basket pick up the orange juice and place it in the basket
pick up the salad dressing and place it in the basket pick up the bbq sauce and place it in the basket
pick up the chocolate pudding and place it in the basket pick up the cream cheese and place it in the basket
put both the alphabet soup and the tomato sauce in the basket put both moka pots on the stove
put the yellow and white mug in the microwave and close it turn on the stove and put the moka pot on it
put the white mug on the left plate and put the yellow and white mug on the right plate
pick up the book and place it in the back compartment of the caddy
put the black bowl in the bottom drawer of the cabinet and close it
pick up the black bowl between the plate and the ramekin and place it on the plate
pick up the black bowl next to the cookie box and place it on the plate
pick up the black bowl from table center and place it on the plate
pick up the black bowl on the wooden cabinet and place it on the plate
Task: State: Action: ; , . \n
"""


def _numbers() -> str:
    return " ".join(str(number) for number in range(256))


def build_text_tokenizer(vocab_size: int):
    """A byte-level BPE (any text encodes) with PaliGemma's special tokens and a leading <bos>."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers, processors, trainers

    tokenizer = Tokenizer(models.BPE())
    tokenizer.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    tokenizer.decoder = decoders.ByteLevel()
    trainer = trainers.BpeTrainer(
        vocab_size=vocab_size,
        special_tokens=["<pad>", "<eos>", "<bos>", "<unk>"],
        initial_alphabet=pre_tokenizers.ByteLevel.alphabet(),
        show_progress=False,
    )
    tokenizer.train_from_iterator([_CORPUS, _numbers()] * 4, trainer=trainer)
    if tokenizer.get_vocab_size() != vocab_size:
        raise RuntimeError(f"tiny tokenizer has {tokenizer.get_vocab_size()} tokens, not {vocab_size}")
    tokenizer.post_processor = processors.TemplateProcessing(
        single="<bos> $A", pair="<bos> $A $B", special_tokens=[("<bos>", tokenizer.token_to_id("<bos>"))]
    )
    return tokenizer


def write_hub_entry(hf_home: Path, repo_id: str, files: dict[str, str]) -> Path:
    """Lay ``files`` out as the cached snapshot of hub model ``repo_id`` (what offline loading reads)."""
    repo_dir = hf_home / "hub" / ("models--" + repo_id.replace("/", "--"))
    digest = hashlib.sha1()
    for name in sorted(files):
        digest.update(name.encode() + b"\0" + files[name].encode())
    revision = digest.hexdigest()
    snapshot = repo_dir / "snapshots" / revision
    if not snapshot.exists():  # named by its content: an existing one is already right
        staging = repo_dir / f"staging-{os.getpid()}"
        staging.mkdir(parents=True)
        for name, text in files.items():
            (staging / name).write_text(text)
        snapshot.parent.mkdir(exist_ok=True)
        try:
            staging.rename(snapshot)
        except OSError:  # another builder got there first, with the same content
            shutil.rmtree(staging)
    (repo_dir / "refs").mkdir(exist_ok=True)
    (repo_dir / "refs" / "main").write_text(revision)
    return snapshot


def write_hub_stand_ins(hf_home: Path, vocab_size: int) -> None:
    tokenizer = build_text_tokenizer(vocab_size)
    tokenizer_config = {
        "tokenizer_class": "PreTrainedTokenizerFast",
        "bos_token": "<bos>",
        "eos_token": "<eos>",
        "pad_token": "<pad>",
        "unk_token": "<unk>",
        "padding_side": "right",
        "model_max_length": 1_000_000,
    }
    write_hub_entry(
        hf_home,
        TEXT_TOKENIZER,
        {
            "tokenizer.json": tokenizer.to_str(),
            "tokenizer_config.json": json.dumps(tokenizer_config),
            "config.json": "{}",  # transformers 5 looks for a model config beside the tokenizer
        },
    )
    processor_config = {
        "processor_class": "FastActionStandIn",
        "auto_map": {"AutoProcessor": "fast_standin.FastActionStandIn"},
    }
    write_hub_entry(
        hf_home,
        FAST_TOKENIZER,
        {
            "fast_standin.py": (PATCHES / "fast_standin.py").read_text(),
            "processor_config.json": json.dumps(processor_config),
            "config.json": "{}",
        },
    )


def libero_like_stats(seed: int) -> dict[str, dict[str, list[float]]]:
    """Normalization statistics shaped like LIBERO's, perturbed by ``seed`` (every key LeRobot may use)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    state_mean = np.array([-0.05, 0.03, 1.0, 3.0, -0.1, 0.0, 0.03, -0.03])
    state_std = np.array([0.1, 0.15, 0.1, 0.3, 0.4, 0.3, 0.01, 0.01])
    action_mean = np.array([0.06, 0.09, -0.1, 0.0, 0.005, -0.005, -0.1])
    action_std = np.array([0.3, 0.35, 0.45, 0.04, 0.06, 0.08, 0.99])

    def stats(mean, std):
        mean = mean + rng.normal(0.0, 0.1, mean.shape) * std
        std = std * rng.uniform(0.8, 1.25, std.shape)
        return {
            "mean": mean.tolist(),
            "std": std.tolist(),
            "min": (mean - 3 * std).tolist(),
            "max": (mean + 3 * std).tolist(),
            "q01": (mean - 2.3 * std).tolist(),
            "q99": (mean + 2.3 * std).tolist(),
            "q10": (mean - 1.3 * std).tolist(),
            "q90": (mean + 1.3 * std).tolist(),
        }

    return {"observation.state": stats(state_mean, state_std), "action": stats(action_mean, action_std)}


def reinitialize_at_unit_gain(model) -> None:
    """Weights of std 1/sqrt(fan_in) (embeddings 1/width), from torch's seeded RNG.

    LeRobot's init (std 0.02, as for the full-size models) leaves a model of width 64 nearly blind to its
    inputs: activations shrink layer by layer and the actions are then decided by the noise alone. At unit
    gain, the image, the state and the prompt visibly move the actions, as in a trained model.
    """
    import torch
    from torch import nn

    with torch.no_grad():
        for module in model.modules():
            if isinstance(module, (nn.Linear, nn.Conv2d)):
                fan_in = module.weight[0].numel()
                module.weight.normal_(0.0, fan_in**-0.5)
                if module.bias is not None:
                    module.bias.zero_()
            elif isinstance(module, nn.Embedding):  # Gemma scales embeddings up by sqrt(width)
                module.weight.normal_(0.0, 1.0 / module.embedding_dim)


def build_checkpoint(policy: str, out: Path, seed: int) -> None:
    """Construct the tiny policy with LeRobot's own classes and save it as LeRobot saves a trained one."""
    import torch
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    policy_type = POLICY_TYPES[policy]
    chunk_size, n_action_steps = CHUNKS[policy_type]
    config_class = PreTrainedConfig.get_choice_class(policy_type)
    options = {"chunk_size": chunk_size, "n_action_steps": n_action_steps, "device": "cpu"}
    if policy_type == "pi0_fast":
        # Random weights never emit the "Action: " prefix; 32 decoding steps keep a call short.
        options.update(validate_action_token_prefix=False, max_decoding_steps=32)
    image = PolicyFeature(type=FeatureType.VISUAL, shape=(3, 224, 224))
    config = config_class(
        input_features={
            IMAGE_KEYS[0]: image,
            IMAGE_KEYS[1]: image,
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(STATE_DIM,)),
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_DIM,))},
        **options,
    )
    torch.manual_seed(seed)
    model = get_policy_class(policy_type)(config)
    reinitialize_at_unit_gain(model)
    model.save_pretrained(out)
    stats = {
        key: {name: torch.tensor(values) for name, values in entry.items()}
        for key, entry in libero_like_stats(seed).items()
    }
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=stats)
    preprocessor.save_pretrained(out)
    postprocessor.save_pretrained(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", choices=sorted(POLICY_TYPES), required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--hf-home", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    sizes = sys.modules.get("sitecustomize")
    if getattr(sizes, "TINY_VOCAB", None) is None:
        parser.error(f"put {PATCHES} on PYTHONPATH: the tiny model sizes are patched in there")
    # The hub client reads these once, at import: set them before anything imports it.
    os.environ["HF_HOME"] = str(args.hf_home.resolve())
    os.environ["HF_HUB_OFFLINE"] = "1"
    write_hub_stand_ins(args.hf_home.resolve(), sizes.TINY_VOCAB)
    build_checkpoint(args.policy, args.out, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
