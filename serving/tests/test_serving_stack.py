"""The model stack as an episode's identity counts it, read from distributions' files (no import, no torch)."""

from __future__ import annotations

from pathlib import Path

from conflictbench_serving.stack import installed_versions, model_stack


def install(site: Path, name: str, version: str) -> None:
    info = site / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")


def test_versions_are_read_from_the_files_first_on_the_path_winning_without_installers(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    install(first, "LeRobot", "0.6.1")
    install(first, "pip", "24.0")
    install(second, "lerobot", "0.5.0")  # shadowed, as on import
    install(second, "Torch_Vision", "0.20.1")
    assert installed_versions([first, second]) == {"lerobot": "0.6.1", "torch-vision": "0.20.1"}


def test_the_stack_counts_the_device_kind_and_every_version():
    stack = model_stack("cuda:1", {"torch": "2.5.1", "lerobot": "0.6.1"})
    assert stack == {"device": "cuda", "packages": {"lerobot": "0.6.1", "torch": "2.5.1"}}
    assert list(stack["packages"]) == ["lerobot", "torch"]
