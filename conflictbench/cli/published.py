"""``model.published=<entry>``: the user's declaration of which published checkpoint the model is. Not a model
setting (it must not enter the episodes' identity), so it is taken off the command line before Hydra sees it."""

from __future__ import annotations

import difflib

from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins
from conflictbench.core.registry import PublishedResult
from conflictbench.report.paper import check_paper_model

from .overrides import default_model

KEY = "model.published"


def take_declaration(argv: list[str], plugins: Plugins) -> tuple[list[str], str | None]:
    """``argv`` without ``model.published=<entry>``, and the entry, checked against the one model of the line."""
    rest, entries = [], []
    for arg in argv:
        key, eq, value = arg.partition("=")
        if eq and key.lstrip("+") == KEY:
            entries.append(value.strip())
        else:
            rest.append(arg)
    if not entries:
        return rest, None
    if len(entries) > 1 or "," in entries[0] or not entries[0]:
        raise UserError(f"{KEY} names one published checkpoint, e.g. {KEY}=pi05-libero")
    models = [default_model()]
    for arg in rest:
        key, _, value = arg.partition("=")
        if key.lstrip("+") == "model":
            models = [item.strip() for item in value.split(",")]
    if len(models) != 1 or any(ch in models[0] for ch in "()[]{}*$"):
        raise UserError(f"{KEY} declares one model's checkpoint: name a single model, not a sweep over models")
    check_declaration(entries[0], models[0], plugins)
    return rest, entries[0]


def check_declaration(entry: str, model: str, plugins: Plugins) -> PublishedResult:
    """The published entry ``entry``, which must be one of ``model``'s (one line otherwise)."""
    results = plugins.published_results()
    if entry in results:
        found = results[entry]
        if not found.playable_by(model):
            players = " or ".join(f"model={p}" for p in (found.policy, *found.played_by))
            raise UserError(
                f"{KEY}={entry} is a published {found.policy} checkpoint, not one of model={model}'s; "
                f"declare it with {players}"
            )
        check_paper_model(found)  # the report would show the paper's rows beside it
        return found
    own = sorted(name for name, result in results.items() if result.playable_by(model))
    if not own:
        raise UserError(f"unknown published checkpoint {entry!r}: model={model} has no published results")
    close = difflib.get_close_matches(entry, own, n=3, cutoff=0.0)
    raise UserError(f"unknown published checkpoint {entry!r} for model={model}; closest: {', '.join(close)}")
