"""The affordance table: what each LIBERO object category can and cannot do, kept as data.

``data/affordances.jsonl`` holds one line per category (every category of the 40 base tasks)::

    {"category": "plate", "names": [...], "synonyms": [...], "hypernyms": [...],
     "graspable": true, "container": false, "support": true, "openable": false,
     "turnable": false, "fixed": false, "foldable": false, "pourable": false,
     "size": 2, "note": "..."}

Affordances, judged for the real object the asset depicts (not for what the simulator happens to
allow), each ``true``, ``false`` or ``null``:

- ``graspable``: the robot's parallel gripper can pick it up and carry it;
- ``container``: other objects can be put inside it (an open vessel, drawer, basket);
- ``support``: other objects can rest stably on top of it;
- ``openable``: it has a door, drawer, lid or cover the robot could open or close;
- ``turnable``: it can be switched on or off (a knob, button or switch);
- ``fixed``: it is part of the scene's furniture and cannot be moved or pushed around;
- ``foldable``: it can be folded or bent like cloth or paper;
- ``pourable``: it holds a liquid or sauce that could be poured out.

``null`` means "not clear-cut": conflict operators never build a physical violation from it.
``size`` is a coarse class (1 hand-sized, 2 tableware/cookware, 3 large container or appliance,
4 furniture) used for "X does not fit inside Y"; ``names`` are the noun phrases instructions use
for the category (the first is the default), ``synonyms`` other words for the same thing, and
``hypernyms`` the categories it belongs to. Names, synonyms and hypernyms together are what a
grounding conflict's absent referent must never be (:mod:`.lexicon`).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from conflictbench.core import UserError
from conflictbench.tasks.json_lines import json_objects

AFFORDANCES = ("graspable", "container", "support", "openable", "turnable", "fixed", "foldable", "pourable")
SIZES = {1: "hand-sized", 2: "tableware or cookware", 3: "large container or appliance", 4: "furniture"}
TABLE = "affordances.jsonl"


class AffordanceTableError(UserError):
    pass


@dataclass(frozen=True)
class CategoryInfo:
    category: str
    names: tuple[str, ...]
    synonyms: tuple[str, ...]
    hypernyms: tuple[str, ...]
    affordances: Mapping[str, bool | None]
    size: int
    note: str

    @property
    def name(self) -> str:
        return self.names[0]

    def has(self, affordance: str) -> bool | None:
        return self.affordances[affordance]

    def lacks(self, affordance: str) -> bool:
        """True only where the table says plainly that the category lacks the affordance."""
        return self.affordances[affordance] is False


def parse_table(text: str, source: str) -> dict[str, CategoryInfo]:
    out: dict[str, CategoryInfo] = {}
    for _, where, row in json_objects(text, source, AffordanceTableError):
        for key in ("category", "names", "synonyms", "hypernyms", "size", "note", *AFFORDANCES):
            if key not in row:
                raise AffordanceTableError(f"{where}, field {key!r}: missing")
        for key in AFFORDANCES:
            if row[key] not in (True, False, None):
                raise AffordanceTableError(f"{where}, field {key!r}: expected true, false or null, got {row[key]!r}")
        if row["size"] not in SIZES:
            raise AffordanceTableError(f"{where}, field 'size': expected one of {sorted(SIZES)}, got {row['size']!r}")
        for key in ("names", "synonyms", "hypernyms"):
            if not isinstance(row[key], list) or not all(
                isinstance(w, str) and w == w.lower() and w.strip() for w in row[key]
            ):
                raise AffordanceTableError(f"{where}, field {key!r}: expected a list of lower-case phrases")
        if not row["names"]:
            raise AffordanceTableError(f"{where}, field 'names': needs at least one name")
        if row["category"] in out:
            raise AffordanceTableError(f"{where}, field 'category': {row['category']!r} repeats")
        out[row["category"]] = CategoryInfo(
            row["category"],
            tuple(row["names"]),
            tuple(row["synonyms"]),
            tuple(row["hypernyms"]),
            {k: row[k] for k in AFFORDANCES},
            int(row["size"]),
            str(row["note"]),
        )
    return out


def table_path() -> Path:
    return Path(str(resources.files("conflictbench.tasks") / "data" / TABLE))


@functools.cache
def load_table(path: str | None = None) -> dict[str, CategoryInfo]:
    p = Path(path) if path else table_path()
    return parse_table(p.read_text(encoding="utf-8"), str(p))


def category(name: str) -> CategoryInfo:
    table = load_table()
    if name not in table:
        raise AffordanceTableError(f"category {name!r} is not in the affordance table ({table_path()})")
    return table[name]


def fits_inside(item: str, holder: str) -> bool | None:
    """Can an object of category ``item`` go inside ``holder``? ``False`` only when it plainly cannot:
    the holder is no container, or the item is a whole size class larger."""
    inner, outer = category(item), category(holder)
    if outer.lacks("container"):
        return False
    if outer.has("container") and inner.size > outer.size:
        return False
    return None if outer.has("container") is None else True
