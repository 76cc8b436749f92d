"""README's table of the model plugins, from their folders: each ``plugins/<folder>/pyproject.toml`` declares its
row under ``[tool.conflictbench]`` (``policies``, ``protocol``, ``model-environment``), so a new plugin is its folder.

    .venv/bin/python scripts/readme_plugins.py            writes the table into README.md
    .venv/bin/python scripts/readme_plugins.py --check    exit 1, showing the difference, where README's is not current

A test checks that the table is current.
"""

from __future__ import annotations

import argparse
import sys

from readme_block import ReadmeBlock

BLOCK = ReadmeBlock(
    "readme_plugins",
    "<!-- scripts/readme_plugins.py writes what follows, from plugins/*/pyproject.toml; do not edit it -->",
    "<!-- end of scripts/readme_plugins.py -->",
)


def block() -> str:
    from conflictbench.cli.overrides import checkout_plugins

    lines = [
        BLOCK.begin,
        "",
        "| plugin | policies | native protocol | model environment |",
        "| --- | --- | --- | --- |",
    ]
    for folder, row in checkout_plugins().items():
        policies = ", ".join(f"`{policy}`" for policy in row["policies"])
        link = f"[`plugins/{folder}`](plugins/{folder}/README.md)"
        lines.append(f"| {link} | {policies} | {row['protocol']} | {row['model-environment']} |")
    return "\n".join([*lines, "", BLOCK.end])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="compare README's table with the folders; write nothing")
    args = parser.parse_args()
    BLOCK.current()  # a README without the markers is said before anything is read
    return BLOCK.write_or_check(block(), args.check, "table of the model plugins")


if __name__ == "__main__":
    sys.exit(main())
