"""A case's conflict factors, read the same way for every family: where each sits, what kind it is,
which entities it is about, and whether a later step depends on them.

L4 (multi-step compound) asks for factors "spread over components": at least two DISTINCT factors in
different steps. The same constraint repeated ("... without the robot arm moving at all" after each
step) is one global conflict, not two factors; so two factors count as distinct when their kinds
differ, or when they are about other entities with other requirements (:func:`signature`).

Each case's witness says which components each factor touches (``factor_components``, derived here
by :func:`factor_components` and checked to agree): the step, the kind, the entities, and the later
steps that act on one of those entities (``later_steps``: an L4 case whose second factor's step
depends on what the first factor is about is preferred when the suite is built).
"""

from __future__ import annotations

from dataclasses import dataclass

FAMILY_FACTORS = {  # witness type -> the witness field listing its factors
    "contradiction": "conflicts",
    "absent_referent": "referents",
    "false_relation": "relations",
    "affordance_violation": "violations",
}


@dataclass(frozen=True)
class Factor:
    step: int
    kind: str
    entities: tuple[str, ...]
    requirement: tuple
    """What conflicts, with its entities: a constraint literal, a replaced role, a relation, a violation."""


def _constraint(requirements: list[dict]) -> list[dict]:
    """Of a contradicting pair, the requirement(s) that constrain rather than ask for a goal."""
    kept = [r for r in requirements if (r.get("literal") or [""])[0] not in ("goal", "do")]
    return kept or requirements


def factors_of(witness: dict, wtype: str) -> list[Factor]:
    read = _FACTORS.get(wtype)
    return read(witness) if read else []


def _contradiction_factors(witness: dict) -> list[Factor]:
    out = []
    by_id = {r.get("id"): r for r in witness.get("requirements", []) if isinstance(r, dict)}
    for pair in witness.get("conflicts", []):
        reqs = [by_id[i] for i in pair[:2] if i in by_id]
        if len(reqs) < 2:
            continue
        constraint = _constraint(reqs)
        literals = tuple(tuple(map(str, r.get("literal", []))) for r in constraint)
        entities = sorted({str(e) for r in reqs for e in (r.get("literal") or [])[2:]})
        kind = "contradiction: " + " / ".join(" ".join(lit[:2]) for lit in literals)
        out.append(Factor(max(int(r.get("step", 0)) for r in reqs), kind, tuple(entities), literals))
    return out


def _referent_factors(witness: dict) -> list[Factor]:
    out = []
    for r in witness.get("referents", []):
        what = (r.get("role"), r.get("replaces"), r.get("concept"), r.get("attribute"))
        entities = (str(r["replaces"]),) if r.get("replaces") else ()
        out.append(Factor(int(r.get("step", 0)), f"absent {r.get('role')}", entities, what))
    return out


def _relation_factors(witness: dict) -> list[Factor]:
    out = []
    for r in witness.get("relations", []):
        subject = tuple(sorted(r.get("subject", {}).get("entities", [])))
        marks = tuple(tuple(sorted(lm.get("entities", []))) for lm in r.get("landmarks", []))
        entities = tuple(sorted({*subject, *(e for m in marks for e in m)}))
        what = (r.get("relation"), subject, marks)
        out.append(Factor(int(r.get("step", 0)), f"false {r.get('relation')}", entities, what))
    return out


def _violation_factors(witness: dict) -> list[Factor]:
    out = []
    for v in witness.get("violations", []):
        what = (v.get("kind"), v.get("needs"), v.get("entity"))
        kind = f"{v.get('kind')}: needs {v.get('needs')}"
        out.append(Factor(int(v.get("step", 0)), kind, (str(v.get("entity")),), what))
    return out


_FACTORS = {
    "contradiction": _contradiction_factors,
    "absent_referent": _referent_factors,
    "false_relation": _relation_factors,
    "affordance_violation": _violation_factors,
}
"""How each built-in witness type lists its factors (a plugin's own type has none here)."""


def signature(f: Factor) -> tuple:
    """What makes two factors the same one: the requirement (with its entities) that conflicts."""
    return (f.kind, f.requirement)


def distinct_spread(factors: list[Factor]) -> bool:
    """At least two factors in different steps that are not the same factor repeated."""
    return any(a.step != b.step and signature(a) != signature(b) for a in factors for b in factors)


def factor_components(witness: dict, wtype: str) -> list[dict]:
    """Per factor: its step, kind and entities, and the later steps acting on one of those entities."""
    acted = witness.get("step_entities") or []
    out = []
    for f in factors_of(witness, wtype):
        mine = set(f.entities)
        later = [k + 1 for k in range(f.step, len(acted)) if mine & set(map(str, acted[k] or []))]
        out.append({"step": f.step, "kind": f.kind, "entities": list(f.entities), "later_steps": later})
    return out


def with_components(witness: dict) -> dict:
    """The witness with ``factor_components`` derived from its factors, for the built-in witness
    types (a plugin's own type is left as its operator wrote it)."""
    wtype = witness.get("type")
    if wtype not in FAMILY_FACTORS:
        return witness
    rest = {k: v for k, v in witness.items() if k != "factor_components"}
    return {**rest, "factor_components": factor_components(rest, wtype)}


def bears_on(witness: dict) -> bool:
    """Does a later step depend on what an earlier factor is about (the preferred L4 shape)?"""
    return any(c.get("later_steps") for c in witness.get("factor_components", []))


def components_missing(level: str, witness: dict) -> list[str]:
    """A multi-step case says which components each factor touches (an operator's draft does not yet:
    the build adds the field, so only a finished case is held to it)."""
    if level in ("L3", "L4") and "factor_components" not in witness:
        return ["witness field 'factor_components' must say which components each factor touches"]
    return []


def check_factors(level: str, witness: dict, wtype: str) -> list[str]:
    out = []
    factors = factors_of(witness, wtype)
    if level == "L4" and not distinct_spread(factors):
        out.append(
            "L4 needs two distinct factors in different steps: these repeat one constraint "
            f"({'; '.join(sorted({f.kind for f in factors}))}), which is one global conflict"
        )
    said = witness.get("factor_components")
    if said is not None and said != factor_components(witness, wtype):
        out.append("witness field 'factor_components' does not match the factors (steps, kinds, entities)")
    return out
