"""Hard-link identical files between the model environments under one folder (setup.sh runs it).

Each model environment holds its own torch and CUDA libraries (about 5 GB); most of those files are
byte-identical across environments. A file at the same path inside two environments, with the same size,
mode and bytes, is kept once and linked from the others, so five environments take the disk of about
two. pip never edits an installed file in place (it removes and writes anew), so an upgrade in one
environment leaves the others' files as they were.

    python scripts/link_identical.py .venv/models      prints what it shared
"""

from __future__ import annotations

import filecmp
import os
import sys
from pathlib import Path


def candidate_groups(root: Path) -> dict[tuple[str, int, int], list[Path]]:
    """Regular non-empty files of every environment under `root`, by (path inside it, size, mode)."""
    groups: dict[tuple[str, int, int], list[Path]] = {}
    for env in sorted(p for p in root.iterdir() if p.is_dir() and not p.is_symlink()):
        for folder, _, files in os.walk(env):
            for name in files:
                path = Path(folder, name)
                stat = path.lstat()
                if not path.is_symlink() and stat.st_size > 0:
                    key = (str(path.relative_to(env)), stat.st_size, stat.st_mode)
                    groups.setdefault(key, []).append(path)
    return groups


def link_identical(root: Path) -> tuple[int, int]:
    """Link each file to an identical one elsewhere under `root`; returns (files linked, bytes shared now)."""
    linked = shared = 0
    for (_, size, _), paths in candidate_groups(root).items():
        kept: list[Path] = []  # one file per distinct content seen in this group
        for path in paths:
            same = next((k for k in kept if k.samefile(path) or filecmp.cmp(k, path, shallow=False)), None)
            if same is None:
                kept.append(path)
            elif not same.samefile(path):
                temporary = path.with_name(path.name + ".conflictbench-link")
                os.link(same, temporary)
                os.replace(temporary, path)  # atomic: the path always names a whole file
                linked += 1
                shared += size
    return linked, shared


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not Path(argv[0]).is_dir():
        print("usage: link_identical.py FOLDER   (a folder of environments, e.g. .venv/models)", file=sys.stderr)
        return 2
    linked, shared = link_identical(Path(argv[0]))
    if linked:
        print(f"[setup] {shared / 1e9:.1f} GB of identical files now shared between environments ({linked} links)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
