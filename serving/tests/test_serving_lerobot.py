"""The LeRobot checkpoint checks every plugin's server shares, without torch."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conflictbench_serving.checkpoints import CheckpointError
from conflictbench_serving.lerobot import camera_order, check_checkpoint, checkpoint_fingerprint
from conflictbench_serving.requests import describe, is_noise_seed


def checkpoint(folder, kind="groot", files=("model.safetensors", "policy_preprocessor.json",
               "policy_postprocessor.json")):  # fmt: skip
    folder.mkdir()
    if kind is not None:
        (folder / "config.json").write_text(json.dumps({"type": kind}) if kind else "{not json")
    for name in files:
        (folder / name).write_bytes(name.encode())
    return folder


@pytest.mark.parametrize(
    "kind, files, fragment",
    [
        (None, (), "is not a LeRobot checkpoint (no config.json) (try the other server)"),
        ("", (), "cannot read"),
        ("pi05", (), "holds a pi05 policy, not a groot or vla_jepa one"),
        ("groot", ("model.safetensors",), "has no policy_preprocessor.json"),
    ],
)
def test_what_is_not_a_usable_checkpoint_says_why(tmp_path, kind, files, fragment):
    with pytest.raises(CheckpointError) as error:
        check_checkpoint(checkpoint(tmp_path / "c", kind, files), ["groot", "vla_jepa"], hint=" (try the other server)")
    assert fragment in str(error.value)
    with pytest.raises(CheckpointError, match="no checkpoint folder at"):
        check_checkpoint(tmp_path / "absent", ["groot"])


def test_a_checkpoint_is_known_by_its_content(tmp_path):
    first = check_checkpoint(checkpoint(tmp_path / "a"), ["groot"])
    moved = checkpoint(tmp_path / "b")
    (moved / "notes.txt").write_text("not part of the model")
    assert checkpoint_fingerprint(first) == checkpoint_fingerprint(moved)
    (moved / "policy_postprocessor_step_3_unnormalizer.safetensors").write_bytes(b"other statistics")
    assert checkpoint_fingerprint(first) != checkpoint_fingerprint(moved)


@pytest.mark.parametrize(
    "names, order",
    [
        (["image", "image2"], ["image", "image2"]),  # LeRobot's LIBERO names: image2 is the wrist camera
        (["image2", "image"], ["image", "image2"]),
        (["wrist_image", "image"], ["image", "wrist_image"]),
        (["top", "side"], ["top", "side"]),  # no wrist name: the config's order
    ],
)
def test_the_wrist_camera_is_found_by_name_whatever_the_order(names, order):
    assert camera_order([f"observation.images.{n}" for n in names]) == [f"observation.images.{n}" for n in order]


@pytest.mark.parametrize("value, valid", [(0, True), (2**63 - 1, True), (np.int64(5), True), (2**63, False),
                                          (-1, False), (True, False), (1.0, False), ("3", False)])  # fmt: skip
def test_the_seed_rule_every_server_checks(value, valid):
    assert is_noise_seed(value) is valid


def test_a_bad_value_is_described_briefly():
    assert describe(np.zeros((2, 3), np.float32)) == "float32 array of shape (2, 3)"
    assert describe("x" * 100) == f"str '{'x' * 36}..."
