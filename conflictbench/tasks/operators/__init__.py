"""Conflict operators, one module per family; :mod:`.frames` holds what they share.

An operator is ``generate(model, level, rng) -> iterable of Draft``: given a base task (as a
:class:`~conflictbench.tasks.scene.task_model.TaskModel`) and a level, it proposes conflict cases
of its family. Built-in operators register through the ``conflictbench_register_conflict_operators``
hook like any plugin's.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterable

from . import grounding, instruction, physical, spatial
from .frames import Draft

Generate = Callable[[object, str, random.Random], Iterable[Draft]]


def builtin_operators() -> list[tuple[str, str, Generate]]:
    """(name, family, generate) of every built-in operator."""
    return [*instruction.OPERATORS, *grounding.OPERATORS, *spatial.OPERATORS, *physical.OPERATORS]
