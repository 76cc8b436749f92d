"""The policy contract has one list (``POLICY_DECLARATIONS``); hook spec, README and ``PolicyTraits`` agree."""

from __future__ import annotations

import re
from pathlib import Path

from conflictbench.core import hookspecs
from conflictbench.core.policy import DEFAULT_MAX_STEPS, POLICY_DECLARATIONS, PolicyTraits

README = Path(__file__).parents[1] / "README.md"
#: PolicyTraits' names for what a policy declares by a method or under another name.
TRAIT_NAMES = {"batched": "act_batch", "concurrent": "concurrent_requests"}


def test_readmes_table_is_the_list():
    lines = README.read_text().splitlines()
    start = lines.index("| declaration | default | meaning |") + 2
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        name, default, meaning = (cell.strip() for cell in line.strip("|").split(" | "))
        rows.append((name.strip("`"), default, meaning))
    assert rows == [(d.name, d.default, d.meaning) for d in POLICY_DECLARATIONS]


def test_the_hook_specs_docstring_names_each_declaration_with_its_default_and_no_other():
    doc = " ".join(hookspecs.conflictbench_register_policies.__doc__.split())
    documented = re.findall(r"``(\w+)`` \[([^\]]*)\]", doc)
    assert documented == [(d.name, d.default) for d in POLICY_DECLARATIONS]


def test_policy_traits_read_every_declaration_with_the_documented_default():
    traits = vars(PolicyTraits(object()))
    declared = {d.name: d.default for d in POLICY_DECLARATIONS}
    assert {TRAIT_NAMES.get(name, name) for name in traits} == set(declared) - {"start", "close"}
    for name, value in traits.items():
        name = TRAIT_NAMES.get(name, name)
        if name == "max_steps":
            assert value == DEFAULT_MAX_STEPS and "/".join(map(str, value.values())) == declared[name]
        elif name == "act_batch":
            assert value is False and declared[name] == "none"
        else:
            assert str(value) == declared[name], name
