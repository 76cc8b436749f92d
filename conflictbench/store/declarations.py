"""Which published checkpoint a user declared a run's model to be (``model.published=<entry>``).

Not a model setting: the declaration never enters an episode's identity (the same checkpoint reuses its stored
episodes), so it is kept beside the episodes, by (policy, config_hash), in ``<store>/declarations.json``.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

FILE = "declarations.json"


def declarations(store_root: Path) -> dict[tuple[str, str], str]:
    """(policy, config_hash) -> the published entry declared for it; ``{}`` when none."""
    path = Path(store_root) / FILE
    try:
        rows = json.loads(path.read_text(encoding="utf-8"))
    except (FileNotFoundError, json.JSONDecodeError):
        return {}
    return {(row["policy"], row["config_hash"]): row["entry"] for row in rows}


def record_declaration(store_root: Path, policy: str, config_hash: str, entry: str) -> None:
    """Keep the declaration, merged with those already there (a later one for the same key replaces it); the
    file is replaced atomically, so a reader never sees half of it."""
    root = Path(store_root)
    root.mkdir(parents=True, exist_ok=True)
    merged = {**declarations(root), (policy, config_hash): entry}
    rows = [{"policy": p, "config_hash": h, "entry": e} for (p, h), e in sorted(merged.items())]
    fd, temporary = tempfile.mkstemp(dir=root, prefix=f".{FILE}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            json.dump(rows, out, indent=1)
        os.replace(temporary, root / FILE)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
