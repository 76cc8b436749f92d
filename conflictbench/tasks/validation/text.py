"""Words in an instruction: normalising text, and whether a text names a scene entity."""

from __future__ import annotations

from collections.abc import Iterable

from conflictbench.tasks.scene.lexicon import words
from conflictbench.tasks.scene.task_model import TaskModel

PRONOUNS = {"it", "them", "its", "both"}


def normalise(text: str) -> str:
    return " ".join(words(text))


def entity_names(model: TaskModel, entity: str) -> set[str]:
    return model.entity_names(entity)


def names_in(text: str, names: Iterable[str]) -> bool:
    t = f" {normalise(text)} "
    return any(f" {normalise(n)} " in t for n in names)


def _named_or_pronoun(model: TaskModel, entity: str, text: str, instruction: str) -> bool:
    names = entity_names(model, entity)
    if names_in(text, names):
        return True
    return bool(PRONOUNS & set(words(text))) and names_in(instruction, names)
