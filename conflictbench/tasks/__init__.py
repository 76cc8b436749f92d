"""LIBERO base tasks, BDDL reading, and the conflict suite.

As a plugin module (listed in ``conflictbench.BUILTIN_PLUGINS``) it registers the built-in
conflict operators through ``conflictbench_register_conflict_operators``, the hook any
third-party operator uses too. Nothing heavy is imported until the hook runs.
"""

from conflictbench.core import hookimpl

_DESCRIPTIONS = {
    "instruction": "a step's goal paired with a constraint that rules it out",
    "grounding": "a referent replaced by something absent from the scene",
    "spatial": "a relational description that is false in the initial scene",
    "physical": "a present entity asked to do what its category cannot",
}


@hookimpl
def conflictbench_register_conflict_operators(register):
    from conflictbench.tasks.operators import builtin_operators
    from conflictbench.tasks.validation.rules import WITNESS_TYPES

    for name, family, generate in builtin_operators():
        register(
            name,
            family=family,
            generate=generate,
            witness_type=WITNESS_TYPES[family],
            description=_DESCRIPTIONS[family],
        )
