"""Train the learned subject (PyTorch, LeRobot's dataset format); runs in the training environment.

This file imports nothing of conflictbench: it is run by path with the training environment's Python
(``.venv/models/subject``: Python 3.12, ``lerobot[dataset]``), which cannot hold the simulator's stack.

    python train_torch.py dataset --prepared prepared.npz --root DATASET
    python train_torch.py train --root DATASET --out subject.npz --seed 0 --minutes 30
    python train_torch.py train --prepared prepared.npz --root DATASET ...   both, in one process

One process for both is what ``conflictbench train-subject`` runs: importing torch and LeRobot takes about 25 s here.

The network is the one ``model.py`` runs in NumPy, parameter for parameter.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

REPO_ID = "conflictbench/subject-demonstrations"
FPS = 20
UNKNOWN = 1
NO_VIDEO = "pyav"
"""The dataset has no video; named so that LeRobot does not probe torchcodec (a page of traceback without FFmpeg)."""
CONFIG = {"width": 64, "heads": 4, "layers": 3, "feedforward": 128, "chunk": 4, "positions": 96, "bins": 41}


# -- the dataset ------------------------------------------------------------------------------------


def features(prepared: dict[str, np.ndarray]) -> dict[str, dict]:
    """Flat vectors (an entity table is stored row after row; ``meta/subject.json`` has its shape): LeRobot
    stores a 2-D feature as an Arrow extension type that is 5x slower to write."""

    def spec(key: str, dtype: str, names: list[str] | None = None) -> dict:
        return {"dtype": dtype, "shape": (int(np.prod(prepared[key].shape[1:])),), "names": names}

    return {
        "observation.state": spec("arm", "float32", ["x", "y", "z", *(f"r{i}" for i in range(9)), "f0", "f1"]),
        "observation.environment_state": spec("entities", "float32"),
        "observation.entity_names": spec("names", "int64"),
        "observation.entity_kinds": spec("kinds", "int64"),
        "observation.language_tokens": spec("text", "int64"),
        "action": spec("action", "float32", ["dx", "dy", "dz", "rx", "ry", "rz", "gripper"]),
    }


COLUMNS = {
    "observation.state": "arm",
    "observation.environment_state": "entities",
    "observation.entity_names": "names",
    "observation.entity_kinds": "kinds",
    "observation.language_tokens": "text",
    "action": "action",
}


def write_dataset(prepared_path: Path, root: Path) -> None:
    """The prepared frames as a LeRobot dataset (the instruction is each frame's task)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    with np.load(prepared_path, allow_pickle=False) as f:
        prepared = {k: f[k] for k in f.files}
    dataset = LeRobotDataset.create(
        REPO_ID, FPS, features(prepared), root=root, robot_type="panda", use_videos=False, video_backend=NO_VIDEO
    )
    episodes = prepared["episode_index"]
    starts = np.flatnonzero(np.r_[True, episodes[1:] != episodes[:-1]])
    for number, (start, end) in enumerate(zip(starts, [*starts[1:], len(episodes)], strict=True)):
        n = int(end - start)
        # A whole episode at once (LeRobot's add_frame checks and copies each frame: minutes for 10^5 frames).
        episode = {key: prepared[column][start:end].reshape(n, -1) for key, column in COLUMNS.items()}
        episode.update(
            size=n,
            task=[str(t) for t in prepared["task"][start:end]],
            episode_index=number,
            frame_index=np.arange(n),
            timestamp=np.arange(n, dtype=np.float32) / FPS,
            index=None,  # LeRobot fills these two in
            task_index=None,
        )
        dataset.save_episode(episode)
    dataset.finalize()
    meta = {
        "vocabulary": [str(w) for w in prepared["vocabulary"]],
        "shapes": {column: list(prepared[column].shape[1:]) for column in COLUMNS.values()},
    }
    (Path(root) / "meta" / "subject.json").write_text(json.dumps(meta) + "\n")


def read_dataset(root: Path) -> tuple[dict[str, torch.Tensor], list[str]]:
    """Every frame of the dataset as tensors, with the vocabulary the tokens index."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(REPO_ID, root=root, video_backend=NO_VIDEO)
    table = dataset.hf_dataset.with_format("torch")[:]
    meta = json.loads((Path(root) / "meta" / "subject.json").read_text())
    frames = {column: table[key].reshape(-1, *meta["shapes"][column]) for key, column in COLUMNS.items()}
    frames["episode_index"] = table["episode_index"]
    return frames, meta["vocabulary"]


# -- the network ------------------------------------------------------------------------------------


def _mlp(inputs: int, width: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, width), nn.GELU(approximate="tanh"), nn.Linear(width, width))


class Layer(nn.Module):
    def __init__(self, width: int, heads: int, feedforward: int):
        super().__init__()
        self.heads = heads
        self.norm1, self.norm2 = nn.LayerNorm(width), nn.LayerNorm(width)
        self.qkv, self.out = nn.Linear(width, 3 * width), nn.Linear(width, width)
        self.ff1, self.ff2 = nn.Linear(width, feedforward), nn.Linear(feedforward, width)

    def forward(self, x: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        b, n, d = x.shape
        q, k, v = self.qkv(self.norm1(x)).reshape(b, n, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        scores = (q @ k.transpose(-1, -2)) / math.sqrt(d // self.heads) + bias
        x = x + self.out((scores.softmax(-1) @ v).transpose(1, 2).reshape(b, n, d))
        return x + self.ff2(F.gelu(self.ff1(self.norm2(x)), approximate="tanh"))


class SubjectNetwork(nn.Module):
    def __init__(self, vocabulary: int, entity_numbers: int, arm_numbers: int, config: dict):
        super().__init__()
        d = config["width"]
        self.config = config
        self.word = nn.Embedding(vocabulary, d)
        self.position = nn.Embedding(config["positions"], d)
        self.kind = nn.Embedding(5, d)
        self.entity_in, self.arm_in = _mlp(entity_numbers, d), _mlp(arm_numbers, d)
        self.layers = nn.ModuleList(Layer(d, config["heads"], config["feedforward"]) for _ in range(config["layers"]))
        self.head_norm = nn.LayerNorm(d)
        self.head = nn.Sequential(
            nn.Linear(d, d), nn.GELU(approximate="tanh"), nn.Linear(d, config["chunk"] * (6 * config["bins"] + 1))
        )
        for name, size in (("entity", entity_numbers), ("arm", arm_numbers)):
            self.register_buffer(f"{name}_mean", torch.zeros(size))
            self.register_buffer(f"{name}_std", torch.ones(size))

    def forward(self, text, names, kinds, entities, arm) -> torch.Tensor:
        """(B, chunk * (6 * bins + 1)): per step, six arm values' bin logits and a gripper logit (model.decode)."""
        text_tokens = self.word(text) + self.position.weight[: text.shape[1]] + self.kind.weight[0]
        name_valid = (names != 0).unsqueeze(-1).float()
        name = (self.word(names) * name_valid).sum(-2) / name_valid.sum(-2).clamp(min=1)
        entity = name + self.kind(kinds) + self.entity_in((entities - self.entity_mean) / self.entity_std)
        arm_token = self.arm_in((arm - self.arm_mean) / self.arm_std) + self.kind.weight[4]
        x = torch.cat([arm_token.unsqueeze(1), entity, text_tokens], dim=1)
        valid = torch.cat([torch.ones_like(kinds[:, :1], dtype=torch.bool), kinds != 0, text != 0], dim=1)
        bias = torch.where(valid, 0.0, -1e9)[:, None, None, :]
        for layer in self.layers:
            x = layer(x, bias)
        return self.head(self.head_norm(x[:, 0]))


def export(network: SubjectNetwork, vocabulary: list[str], path: Path, extra: dict) -> None:
    arrays = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in network.state_dict().items()}
    config = {**network.config, **extra}
    np.savez_compressed(path, config=np.array(json.dumps(config)), vocabulary=np.array(vocabulary), **arrays)


# -- training ---------------------------------------------------------------------------------------


def chunk_targets(actions: torch.Tensor, episodes: torch.Tensor, chunk: int) -> torch.Tensor:
    """(N, chunk, 7): each frame's action and the next ones of its episode (the last one repeated at its end)."""
    n = len(actions)
    index = torch.arange(n)
    last = torch.zeros(n, dtype=torch.long)
    ends = torch.nonzero(torch.cat([episodes[1:] != episodes[:-1], torch.tensor([True])])).flatten()
    starts = torch.cat([torch.tensor([0]), ends[:-1] + 1])
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        last[s : e + 1] = e
    steps = torch.minimum(index[:, None] + torch.arange(chunk)[None, :], last[:, None])
    return actions[steps]


def action_loss(raw: torch.Tensor, target: torch.Tensor, chunk: int, bins: int) -> torch.Tensor:
    """Cross-entropy of each arm value's bin (the nearest of ``bins`` over [-1, 1]) plus the gripper's."""
    raw = raw.reshape(len(raw), chunk, 6 * bins + 1)
    logits = raw[..., : 6 * bins].reshape(-1, bins)
    wanted = torch.round((target[..., :6].clamp(-1, 1) + 1) / 2 * (bins - 1)).long().reshape(-1)
    gripper = F.binary_cross_entropy_with_logits(raw[..., -1], (target[..., 6] > 0).float())
    return F.cross_entropy(logits, wanted) + gripper


def standardize(values: torch.Tensor, valid: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    flat = values.reshape(-1, values.shape[-1])
    if valid is not None:
        flat = flat[valid.reshape(-1)]
    return flat.mean(0), flat.std(0).clamp(min=1e-3)


def train(root: Path, out: Path, *, seed: int, minutes: float, epochs: int, batch: int, threads: int) -> dict:
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    frames, vocabulary = read_dataset(root)
    targets = chunk_targets(frames["action"], frames["episode_index"], CONFIG["chunk"])
    network = SubjectNetwork(len(vocabulary), frames["entities"].shape[-1], frames["arm"].shape[-1], CONFIG)
    network.entity_mean[:], network.entity_std[:] = standardize(frames["entities"], frames["kinds"] != 0)
    network.arm_mean[:], network.arm_std[:] = standardize(frames["arm"])
    optimizer = torch.optim.AdamW(network.parameters(), lr=1e-3, weight_decay=1e-4)
    n = len(targets)
    steps_per_epoch = math.ceil(n / batch)
    total = epochs * steps_per_epoch
    generator = torch.Generator().manual_seed(seed)
    started, step, history = time.monotonic(), 0, []
    for epoch in range(epochs):
        order = torch.randperm(n, generator=generator)
        running = 0.0
        for first in range(0, n, batch):
            rows = order[first : first + batch]
            lr = 1e-3 * 0.5 * (1 + math.cos(math.pi * step / total))
            for group in optimizer.param_groups:
                group["lr"] = lr
            text, kinds = frames["text"][rows], frames["kinds"][rows]
            words, things = int((text != 0).sum(1).max()), int((kinds != 0).sum(1).max())  # padding trimmed
            text, kinds = text[:, :words], kinds[:, :things]
            dropped = (torch.rand(text.shape, generator=generator) < 0.1) & (text != 0)
            text = torch.where(dropped, torch.full_like(text, UNKNOWN), text)
            out_ = network(
                text, frames["names"][rows, :things], kinds, frames["entities"][rows, :things], frames["arm"][rows]
            )
            loss = action_loss(out_, targets[rows], CONFIG["chunk"], CONFIG["bins"])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            running += loss.item() * len(rows)
            step += 1
        history.append(running / n)
        elapsed = time.monotonic() - started
        print(f"epoch {epoch + 1}/{epochs}: loss {history[-1]:.4f} ({elapsed:.0f} s)", flush=True)
        if elapsed > minutes * 60:
            print(f"stopping after {epoch + 1} epochs: the {minutes:g}-minute budget is spent", flush=True)
            break
    report = {"frames": n, "epochs": len(history), "loss": history, "seconds": round(time.monotonic() - started, 1)}
    export(network, vocabulary, out, {"seed": seed, "frames": n, "epochs": len(history)})
    return report


def main(argv: list[str]) -> int:
    import datasets

    datasets.disable_progress_bars()  # a bar per episode written
    parser = argparse.ArgumentParser(prog="train_torch.py")
    commands = parser.add_subparsers(dest="command", required=True)
    write = commands.add_parser("dataset")
    write.add_argument("--prepared", type=Path, required=True)
    write.add_argument("--root", type=Path, required=True)
    fit = commands.add_parser("train")
    fit.add_argument("--root", type=Path, required=True)
    fit.add_argument("--out", type=Path, required=True)
    fit.add_argument("--seed", type=int, default=0)
    fit.add_argument("--epochs", type=int, default=30)
    fit.add_argument("--minutes", type=float, default=45.0)
    fit.add_argument("--batch", type=int, default=256)
    fit.add_argument("--threads", type=int, default=2)
    fit.add_argument("--report", type=Path, default=None, help="where to write the run's figures (JSON)")
    fit.add_argument("--prepared", type=Path, default=None, help="first write the dataset at --root from this")
    args = parser.parse_args(argv)
    if args.command == "dataset":
        write_dataset(args.prepared, args.root)
    else:
        dataset_s = None
        if args.prepared is not None:
            started = time.monotonic()
            write_dataset(args.prepared, args.root)
            dataset_s = round(time.monotonic() - started, 1)
            print(
                f"conflictbench: 3/3 training: seed {args.seed}, up to {args.epochs} epochs or {args.minutes:g} min",
                file=sys.stderr,
                flush=True,
            )
        report = train(
            args.root,
            args.out,
            seed=args.seed,
            minutes=args.minutes,
            epochs=args.epochs,
            batch=args.batch,
            threads=args.threads,
        )
        if args.report:
            args.report.write_text(json.dumps({**report, "dataset_s": dataset_s}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
