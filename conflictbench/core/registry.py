"""What the ``register`` callbacks record: one frozen spec per policy, metric and conflict operator.

Each spec carries the distribution (and version) of the plugin that registered it, so a policy or
metric can always say where it came from, and the episode identity can name the code behind it.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from .errors import PluginError, UserError
from .hookspecs import hookimpl
from .records import FAMILIES, LEVELS, LIBERO_SUITES

#: The one name pattern: policies, metrics and families are registered under it, and a store's names (a policy, an
#: episode id) become path parts only if they match it (``conflictbench.store.paths``). Matched whole (``fullmatch``):
#: ``$`` would also match before a final newline, and a name ending in one made a file name with a newline (#42).
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")

#: ``format_prompt(instruction, condition) -> str | None`` of one policy (None: the core's default).
PromptFormatter = Callable[[str, str], "str | None"]
#: ``postprocess(action, context) -> ndarray | None`` of one policy (None: the action unchanged).
ActionPostprocessor = Callable[[Any, Any], Any]


@dataclass(frozen=True)
class PluginSource:
    """The distribution a plugin came from (``conflictbench`` for built-ins)."""

    distribution: str
    version: str

    @property
    def pin(self) -> str:
        return f"{self.distribution}=={self.version}"


@dataclass(frozen=True)
class PolicySpec:
    name: str
    load: Callable[[Any], Any]
    config: type | None
    plugin: str
    """Distribution that registered the policy (``conflictbench`` for built-ins)."""
    plugin_version: str
    format_prompt: PromptFormatter | None = None
    """The model's own P0/P1 text (its native template); applies to this policy only."""
    postprocess: ActionPostprocessor | None = None
    """The model's own action post-processing; applies to this policy only, before any global one."""

    def make_config(self, values: dict[str, Any] | None = None) -> Any:
        if self.config is None:
            if values:
                raise UserError(f"policy {self.name!r} takes no settings, got: {', '.join(sorted(values))}")
            return None
        known = {f.name for f in dataclasses.fields(self.config)}
        unknown = sorted(set(values or {}) - known)
        if unknown:
            raise UserError(
                f"unknown setting(s) for model={self.name}: {', '.join(unknown)}; "
                f"valid: {', '.join(sorted(known)) or '(none)'}"
            )
        return self.config(**(values or {}))


@dataclass(frozen=True)
class MetricSpec:
    """A per-pair metric and everything a report needs to show it (built-ins and plugins alike)."""

    name: str
    compute: Callable[[Any], float | None] | None
    """``compute(pair) -> float | None`` (None where undefined for that pair)."""
    description: str
    plugin: str
    plugin_version: str
    label: str = ""
    """Column title in tables and figures (default: the name)."""
    unit: str = ""
    """``"%"``: the value is a fraction in [0, 1], shown as a percentage; any other text is shown after
    the value as it is (``"m"``, ``"s"``); ``""`` unitless."""
    higher_is_better: bool | None = None
    """Which way is more favourable (reports mark the best value); None: neither, left unmarked."""
    compute_many: Callable[[Sequence[Any], Sequence[Any]], Sequence[float | None]] | None = None
    """Optional batched form: ``compute_many(references, conflicts)`` -> one value per pair, aligned."""
    declared_bounds: tuple[float, float] | None = None
    """The range every value lies in, as registered (``bounds=``)."""

    @property
    def percent(self) -> bool:
        return self.unit == "%"

    @property
    def bounds(self) -> tuple[float, float] | None:
        """The range of its values: as registered, else [0, 1] for a "%" metric, else unknown (None). Reports
        give a measure with a range a score interval that stays inside it (README, "Uncertainty")."""
        return self.declared_bounds or ((0.0, 1.0) if self.percent else None)

    @property
    def direction(self) -> str | None:
        """``"higher"``, ``"lower"`` or None, as the report's tables mark values."""
        return None if self.higher_is_better is None else ("higher" if self.higher_is_better else "lower")

    def compute_pair(self, pair: Any) -> float | None:
        if self.compute is not None:
            return self.compute(pair)
        return list(self.compute_many([pair.reference], [pair.conflict]))[0]


@dataclass(frozen=True)
class ConflictOperatorSpec:
    name: str
    family: str
    generate: Callable[..., Any]
    levels: tuple[str, ...]
    witness_type: str | None
    check: Callable[..., Any] | None
    description: str
    plugin: str
    plugin_version: str


# -- building specs from register(...) calls: each checks its arguments -------------------------
def policy_spec(
    where: str,
    src: PluginSource,
    name: str,
    load: Callable[[Any], Any],
    config: type | None = None,
    *,
    format_prompt: PromptFormatter | None = None,
    postprocess: ActionPostprocessor | None = None,
) -> PolicySpec:
    if not callable(load):
        raise PluginError(f"{where}: load must be callable")
    if config is not None and not (isinstance(config, type) and dataclasses.is_dataclass(config)):
        raise PluginError(f"{where}: config must be a dataclass type")
    for label, fn in (("format_prompt", format_prompt), ("postprocess", postprocess)):
        if fn is not None and not callable(fn):
            raise PluginError(f"{where}: {label} must be callable")
    return PolicySpec(name, load, config, src.distribution, src.version, format_prompt, postprocess)


def metric_spec(
    where: str,
    src: PluginSource,
    name: str,
    compute: Callable[[Any], float | None] | None = None,
    description: str = "",
    *,
    label: str | None = None,
    unit: str = "",
    higher_is_better: bool | None = None,
    compute_many: Callable[..., Sequence[float | None]] | None = None,
    bounds: Sequence[float] | None = None,
) -> MetricSpec:
    if compute is None and compute_many is None:
        raise PluginError(f"{where}: give compute(pair) or compute_many(references, conflicts)")
    if (compute is not None and not callable(compute)) or (compute_many is not None and not callable(compute_many)):
        raise PluginError(f"{where}: compute and compute_many must be callable")
    if higher_is_better is not None and not isinstance(higher_is_better, bool):
        raise PluginError(f"{where}: higher_is_better must be True, False or None")
    if not isinstance(unit, str) or (label is not None and not isinstance(label, str)):
        raise PluginError(f"{where}: label and unit must be strings")
    if bounds is not None:
        try:
            low, high = (float(b) for b in bounds)
        except (TypeError, ValueError):
            raise PluginError(f"{where}: bounds must be two numbers (low, high), got {bounds!r}") from None
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise PluginError(f"{where}: bounds must be finite with low < high, got {bounds!r}")
        bounds = (low, high)
    return MetricSpec(
        name, compute, description, src.distribution, src.version, label or name, unit, higher_is_better, compute_many,
        bounds,
    )  # fmt: skip


def operator_spec(
    where: str,
    src: PluginSource,
    name: str,
    family: str,
    generate: Callable[..., Any],
    levels: Sequence[str] = LEVELS,
    witness_type: str | None = None,
    check: Callable[..., Any] | None = None,
    description: str = "",
) -> ConflictOperatorSpec:
    if not callable(generate) or (check is not None and not callable(check)):
        raise PluginError(f"{where}: generate and check must be callable")
    if not isinstance(family, str) or not NAME_PATTERN.fullmatch(family):
        raise PluginError(f"{where}: family {family!r} is not a valid name")
    if family not in FAMILIES and (check is None or not witness_type):
        raise PluginError(f"{where}: the new family {family!r} needs a witness_type and a check")
    if not levels or any(level not in LEVELS for level in levels):
        raise PluginError(f"{where}: levels must be among {', '.join(LEVELS)}, got {list(levels)}")
    return ConflictOperatorSpec(
        name, family, generate, tuple(levels), witness_type, check, description, src.distribution, src.version
    )


def check_name(kind: str, name: Any, plugin_name: str) -> None:
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
        raise PluginError(f"{kind} name {name!r} from {plugin_name} is not valid (letters, digits, '_', '.', '-')")


#: The keys of a published result's ``protocol``, and the type of each.
PROTOCOL_KEYS = {
    "episodes_per_suite": int,
    "trials_per_task": int,
    "seeds": int,
    "init_states": str,
    "max_steps": dict,
    "warmup_steps": int,
    "actions_per_query": str,
    "notes": str,
}


@dataclass(frozen=True)
class PublishedResult:
    """What a model's authors published for one official checkpoint on LIBERO, with its citation."""

    name: str
    policy: str
    checkpoint: str
    success: dict[str, float]
    """LIBERO suite -> success in percent, as the source prints it."""
    protocol: dict[str, Any]
    source: str
    url: str
    date: str
    plugin: str
    plugin_version: str
    paper_model: str | None = None
    status: str = "primary"
    """``primary``: read in the source; ``secondary``: only consistent third-party copies could be read."""
    caveats: tuple[str, ...] = ()
    counts: dict[str, str] | None = None
    """Suite -> ``"k/n"`` where the source prints counts too (they may disagree with its percentages)."""
    played_by: tuple[str, ...] = ()
    """Other policies that play this checkpoint the way its source evaluated it (a LeRobot port of a model:
    ``lerobot``, which plays it as ``lerobot-eval`` does); ``reproduce`` accepts them beside ``policy``."""

    def playable_by(self, policy: str) -> bool:
        return policy == self.policy or policy in self.played_by

    @property
    def citation(self) -> str:
        return f"{self.source}, {self.url} ({self.date})"


def published_spec(
    where: str,
    src: PluginSource,
    name: str,
    *,
    policy: str,
    checkpoint: str,
    success: dict[str, float],
    protocol: dict[str, Any],
    source: str,
    url: str,
    date: str,
    paper_model: str | None = None,
    status: str = "primary",
    caveats: Sequence[str] = (),
    counts: dict[str, str] | None = None,
    played_by: Sequence[str] = (),
) -> PublishedResult:
    for label, text in (("policy", policy), ("checkpoint", checkpoint), ("source", source), ("date", date)):
        if not isinstance(text, str) or not text.strip():
            raise PluginError(f"{where}: {label} must be a non-empty string")
    if not isinstance(url, str) or not url.startswith(("https://", "http://")):
        raise PluginError(f"{where}: url must be a web address, got {url!r}")
    if not isinstance(success, dict) or not success:
        raise PluginError(f"{where}: success must map LIBERO suites to percentages")
    for suite, value in success.items():
        if suite not in LIBERO_SUITES:
            raise PluginError(f"{where}: {suite!r} is not a LIBERO suite ({', '.join(LIBERO_SUITES)})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 100:
            raise PluginError(f"{where}: success of {suite} must be a percentage in [0, 100], got {value!r}")
    if not isinstance(protocol, dict) or not isinstance(protocol.get("episodes_per_suite"), int):
        raise PluginError(f"{where}: protocol needs episodes_per_suite (an integer)")
    for key, value in protocol.items():
        if key not in PROTOCOL_KEYS or not isinstance(value, PROTOCOL_KEYS[key]):
            raise PluginError(f"{where}: protocol {key}={value!r}; keys and types: {PROTOCOL_KEYS}")
    if set(protocol.get("max_steps", {})) - set(LIBERO_SUITES):
        raise PluginError(f"{where}: protocol max_steps names suites LIBERO lacks")
    if paper_model is not None and (not isinstance(paper_model, str) or not paper_model.strip()):
        # which of the paper's models it names is the report's to check (conflictbench.report.paper)
        raise PluginError(f"{where}: paper_model must be a model's name (the paper's) or None, got {paper_model!r}")
    if status not in ("primary", "secondary"):
        raise PluginError(f"{where}: status must be 'primary' or 'secondary', got {status!r}")
    if counts is not None and (
        set(counts) - set(success) or not all(re.fullmatch(r"\d+/\d+", c) for c in counts.values())
    ):
        raise PluginError(f"{where}: counts must map suites of success to 'k/n'")
    if isinstance(played_by, str) or not all(isinstance(p, str) and p.strip() for p in played_by):
        raise PluginError(f"{where}: played_by must be a list of policy names, got {played_by!r}")
    return PublishedResult(
        name, policy, checkpoint, {s: float(v) for s, v in success.items()}, dict(protocol), source, url, date,
        src.distribution, src.version, paper_model, status, tuple(caveats), dict(counts) if counts else None,
        tuple(played_by),
    )  # fmt: skip


def read_published(path: Any) -> list[dict[str, Any]]:
    """The ``register(**entry)`` arguments of a model plugin's published-results TOML file.

    The file has ``[protocol.NAME]`` tables, then one table per group of entries that share a citation: its keys
    apply to each of its ``entries`` (name -> own keys; ``suite`` + ``success`` for a one-suite checkpoint; own
    ``caveats`` add to the group's). A ``protocol`` is a table, or ``{base = NAME, ...}`` extending a named one."""
    import tomllib
    from pathlib import Path

    data = tomllib.loads(Path(str(path)).read_text(encoding="utf-8"))
    protocols = data.pop("protocol", {})
    found = []
    for group in data.values():
        shared = {key: value for key, value in group.items() if key != "entries"}
        for name, own in group["entries"].items():
            entry = {**shared, **own, "name": name, "caveats": [*shared.get("caveats", []), *own.get("caveats", [])]}
            if "suite" in entry:
                entry["success"] = {entry.pop("suite"): entry["success"]}
            protocol = dict(entry.get("protocol", {}))
            if "base" in protocol:
                protocol = {**protocols[protocol.pop("base")], **protocol}
            entry["protocol"] = protocol
            found.append(entry)
    return found


def published_results(package: str) -> Callable[..., None]:
    """A model plugin's ``conflictbench_register_published_results`` hook for the ``published.toml`` of its
    ``package``: ``conflictbench_register_published_results = published_results(__package__)`` in the module its
    entry point names registers each entry :func:`read_published` reads."""

    @hookimpl
    def conflictbench_register_published_results(register):
        """What the model's authors published on LIBERO, with its citations (published.toml)."""
        from importlib import resources

        for entry in read_published(resources.files(package) / "published.toml"):
            register(**entry)

    return conflictbench_register_published_results
