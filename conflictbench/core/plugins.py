"""The plugin manager and the registries its ``register`` hooks fill.

Modelled on pluggy's eggsample and simonw's ``llm``: the specs live in :mod:`.hookspecs`, the
callers here; each ``register`` callback knows which plugin (and distribution) is calling, so a
registered policy or metric can always say where it came from.
"""

from __future__ import annotations

import dataclasses
import importlib
import re
from dataclasses import dataclass
from importlib import metadata
from typing import Any, Callable, Iterable, Sequence

import numpy as np
import pluggy

from . import hookspecs, prompts
from .errors import PluginError, PolicyError, UserError
from .records import ACTION_DIM, FAMILIES, LEVELS, ActionContext

ENTRY_POINT_GROUP = hookspecs.PROJECT_NAME
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class PolicySpec:
    name: str
    load: Callable[[Any], Any]
    config: type | None
    plugin: str
    """Distribution that registered the policy (``conflictbench`` for built-ins)."""
    plugin_version: str

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
    name: str
    compute: Callable[[Any], float | None]
    description: str
    plugin: str
    plugin_version: str


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


@dataclass(frozen=True)
class PluginSource:
    distribution: str
    version: str


class Plugins:
    """A configured plugin manager: built-ins registered by module name, then entry points.

    ``builtins`` are dotted module names (the core imports nothing of ours statically); plugins
    that fail to import are kept in :attr:`load_failures` instead of stopping every command.
    """

    def __init__(self, builtins: Sequence[str] = (), *, entry_points: bool = True,
                 extra: Iterable[object] = ()):
        self.pm = pluggy.PluginManager(hookspecs.PROJECT_NAME)
        self.pm.add_hookspecs(hookspecs)
        self._sources: dict[str, PluginSource] = {}
        self.load_failures: dict[str, str] = {}
        own = PluginSource("conflictbench", _version("conflictbench"))
        self._register(prompts, "conflictbench.core.prompts", own)
        for module_name in builtins:
            self._register(importlib.import_module(module_name), module_name, own)
        for plugin in extra:
            self._register(plugin, getattr(plugin, "__name__", repr(plugin)), PluginSource("(in-process)", ""))
        if entry_points:
            self._load_entry_points()
        self._registries: dict[str, dict[str, Any]] = {}
        self._postprocessors: list[Any] | None = None

    # -- discovery -------------------------------------------------------------------------
    def _register(self, plugin: object, name: str, source: PluginSource) -> None:
        self.pm.register(plugin, name=name)
        self._sources[name] = source

    def _load_entry_points(self) -> None:
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            if self.pm.get_plugin(ep.name) is not None or self.pm.is_blocked(ep.name):
                continue
            dist = getattr(ep, "dist", None)
            source = PluginSource(dist.name if dist else ep.value, dist.version if dist else "")
            try:
                plugin = ep.load()
            except Exception as exc:  # a broken third-party install must not take the tool down
                self.load_failures[f"{ep.name} ({source.distribution})"] = f"{type(exc).__name__}: {exc}"
                continue
            self._register(plugin, ep.name, source)

    def source(self, plugin_name: str) -> PluginSource:
        return self._sources.get(plugin_name, PluginSource(plugin_name, ""))

    def _call_each(self, hook: Any, **kwargs: Any) -> None:
        """Call every implementation of a register hook, telling it apart from the others."""
        for impl in reversed(hook.get_hookimpls()):
            if getattr(impl, "hookwrapper", False) or getattr(impl, "wrapper", False):
                continue
            impl.function(**{k: v(impl.plugin_name) for k, v in kwargs.items() if k in impl.argnames})

    # -- registries ------------------------------------------------------------------------
    def _collect(self, hook_name: str, kind: str, build: Callable[..., Any]) -> dict[str, Any]:
        """Fill one registry, once. Each implementation of the register hook gets its own
        ``register`` that knows which plugin calls it; ``build(where, source, name, ...)`` checks
        the call's arguments and makes the spec."""
        if hook_name not in self._registries:
            found: dict[str, Any] = {}

            def make_register(plugin_name: str) -> Callable[..., None]:
                source = self.source(plugin_name)

                def register(name: str, *args: Any, **kwargs: Any) -> None:
                    _check_name(kind, name, plugin_name)
                    if name in found:
                        raise PluginError(f"{kind} {name!r} registered twice ({found[name].plugin} and {source.distribution})")
                    where = f"{kind} {name!r} from {plugin_name}"
                    try:
                        found[name] = build(where, source, name, *args, **kwargs)
                    except TypeError as exc:  # wrong arguments to register()
                        raise PluginError(f"{where}: {exc}") from None

                return register

            self._call_each(getattr(self.pm.hook, hook_name), register=make_register)
            self._registries[hook_name] = found
        return self._registries[hook_name]

    def policies(self) -> dict[str, PolicySpec]:
        return self._collect("conflictbench_register_policies", "policy", _policy_spec)

    def metrics(self) -> dict[str, MetricSpec]:
        return self._collect("conflictbench_register_metrics", "metric", _metric_spec)

    def conflict_operators(self) -> dict[str, ConflictOperatorSpec]:
        return self._collect("conflictbench_register_conflict_operators", "conflict operator", _operator_spec)

    def families(self) -> tuple[str, ...]:
        """The built-in families, then any a plugin's operators add."""
        extra = sorted({s.family for s in self.conflict_operators().values()} - set(FAMILIES))
        return (*FAMILIES, *extra)

    def policy(self, name: str) -> PolicySpec:
        specs = self.policies()
        if name not in specs:
            raise UserError(unknown_choice("model", name, specs, self.load_failures))
        return specs[name]

    # -- per-episode hooks -----------------------------------------------------------------
    def format_prompt(self, instruction: str, condition: str, policy: str) -> str:
        text = self.pm.hook.conflictbench_format_prompt(instruction=instruction, condition=condition, policy=policy)
        if not isinstance(text, str):
            raise PluginError(f"conflictbench_format_prompt returned {type(text).__name__}, expected str")
        return text

    def postprocess_action(self, action: np.ndarray, context: ActionContext) -> np.ndarray:
        """Run the post-processing chain on one action (see the hook spec for the order)."""
        if self._postprocessors is None:
            impls = self.pm.hook.conflictbench_postprocess_action.get_hookimpls()
            self._postprocessors = [i for i in reversed(impls)
                                    if not (getattr(i, "hookwrapper", False) or getattr(i, "wrapper", False))]
        for impl in self._postprocessors:
            args = {"action": action, "context": context}
            out = impl.function(**{k: v for k, v in args.items() if k in impl.argnames})
            if out is not None:
                out = np.asarray(out, dtype=np.float64)
                if out.shape != (ACTION_DIM,):
                    raise PolicyError(f"post-processor {impl.plugin_name} returned shape {out.shape}, expected ({ACTION_DIM},)")
                action = out
        return action


def _policy_spec(where: str, src: PluginSource, name: str, load: Callable[[Any], Any],
                 config: type | None = None) -> PolicySpec:
    if not callable(load):
        raise PluginError(f"{where}: load must be callable")
    if config is not None and not (isinstance(config, type) and dataclasses.is_dataclass(config)):
        raise PluginError(f"{where}: config must be a dataclass type")
    return PolicySpec(name, load, config, src.distribution, src.version)


def _metric_spec(where: str, src: PluginSource, name: str, compute: Callable[[Any], float | None],
                 description: str = "") -> MetricSpec:
    if not callable(compute):
        raise PluginError(f"{where}: compute must be callable")
    return MetricSpec(name, compute, description, src.distribution, src.version)


def _operator_spec(where: str, src: PluginSource, name: str, family: str, generate: Callable[..., Any],
                   levels: Sequence[str] = LEVELS, witness_type: str | None = None,
                   check: Callable[..., Any] | None = None, description: str = "") -> ConflictOperatorSpec:
    if not callable(generate) or (check is not None and not callable(check)):
        raise PluginError(f"{where}: generate and check must be callable")
    if not isinstance(family, str) or not _NAME.match(family):
        raise PluginError(f"{where}: family {family!r} is not a valid name")
    if family not in FAMILIES and (check is None or not witness_type):
        raise PluginError(f"{where}: the new family {family!r} needs a witness_type and a check")
    if not levels or any(level not in LEVELS for level in levels):
        raise PluginError(f"{where}: levels must be among {', '.join(LEVELS)}, got {list(levels)}")
    return ConflictOperatorSpec(name, family, generate, tuple(levels), witness_type, check, description,
                                src.distribution, src.version)


def unknown_choice(what: str, value: str, choices: Iterable[str], failures: dict[str, str] | None = None) -> str:
    """The one-line message for an option value that does not exist."""
    msg = f"unknown {what} {value!r}; valid choices: {', '.join(sorted(choices))}"
    if failures:
        msg += "; plugins that failed to load: " + "; ".join(f"{k}: {v}" for k, v in failures.items())
    return msg


def _check_name(kind: str, name: Any, plugin_name: str) -> None:
    if not isinstance(name, str) or not _NAME.match(name):
        raise PluginError(f"{kind} name {name!r} from {plugin_name} is not valid (letters, digits, '_', '.', '-')")


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "0+unknown"
