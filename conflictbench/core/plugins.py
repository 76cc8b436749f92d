"""The plugin manager: loads plugins, calls every hook through pluggy, fills the registries.

Modelled on pluggy's eggsample and simonw's ``llm``: the specs live in :mod:`.hookspecs`, the
callers here. Every hook is called through pluggy (so its tracing and ``wrapper=True``
implementations work); each ``register`` callback knows which plugin (and distribution) is
calling, so a registered policy or metric can always say where it came from.

What runs for one episode, in order:

- prompt text: the global ``conflictbench_format_prompt`` implementations (first string wins),
  else the policy's own ``format_prompt``, else the core's default P0/P1 text;
- each action: the policy's own ``postprocess``, then the global ``conflictbench_postprocess_action``
  chain in pluggy's call order (``tryfirst`` ones, then the most recently registered first,
  ``trylast`` ones last), each link receiving the previous one's output; wrappers wrap each link.
"""

from __future__ import annotations

import difflib
import importlib
import re
from collections.abc import Callable, Iterable, Sequence
from importlib import metadata
from typing import Any

import numpy as np
import pluggy

from . import hookspecs, prompts
from .errors import PluginError, PolicyError, UserError
from .records import ACTION_DIM, FAMILIES, PROMPT_CONDITIONS, ActionContext
from .registry import (
    ConflictOperatorSpec,
    MetricSpec,
    PluginSource,
    PolicySpec,
    PublishedResult,
    check_name,
    metric_spec,
    operator_spec,
    policy_spec,
    published_spec,
)

ENTRY_POINT_GROUP = hookspecs.PROJECT_NAME
#: Installed plugins to leave unimported, comma-separated entry-point or distribution names (the command
#: line's ``--disable-plugins`` sets it, so that the processes a run starts leave them out too).
DISABLE_PLUGINS_VARIABLE = "CONFLICTBENCH_DISABLE_PLUGINS"
#: The hooks called once per episode or action for every policy (the deliberate cross-cutting ones).
GLOBAL_EPISODE_HOOKS = ("conflictbench_format_prompt", "conflictbench_postprocess_action")
_CORE_PROMPTS = "conflictbench.core.prompts"


class Plugins:
    """A configured plugin manager: built-ins registered by module name, then entry points.

    ``builtins`` are dotted module names (the core imports nothing of ours statically); plugins
    that fail to import are kept in :attr:`load_failures` instead of stopping every command. A
    plugin that implements a hook that does not exist (a misspelling) is an error naming both.
    """

    def __init__(
        self,
        builtins: Sequence[str] = (),
        *,
        entry_points: bool = True,
        extra: Iterable[object] = (),
        disabled: Iterable[str] = (),
    ):
        self.pm = pluggy.PluginManager(hookspecs.PROJECT_NAME)
        self.pm.add_hookspecs(hookspecs)
        self._sources: dict[str, PluginSource] = {}
        self.load_failures: dict[str, str] = {}
        #: The installed plugins the user switched off (by entry-point or distribution name), never imported.
        self.disabled: dict[str, PluginSource] = {}
        self.disabled_requested: tuple[str, ...] = tuple(name.strip() for name in disabled if name.strip())
        own = PluginSource("conflictbench", _version("conflictbench"))
        self._register(prompts, _CORE_PROMPTS, own)
        for module_name in builtins:
            self._register(importlib.import_module(module_name), module_name, own)
        for plugin in extra:
            self._register(plugin, getattr(plugin, "__name__", repr(plugin)), PluginSource("(in-process)", ""))
        if entry_points:
            self._load_entry_points()
        self._check_hooks()
        self._registries: dict[str, dict[str, Any]] = {}
        self._chain: list[tuple[str, Any]] | None = None
        self._global_prompt = self.pm.subset_hook_caller(
            "conflictbench_format_prompt", remove_plugins=[self.pm.get_plugin(_CORE_PROMPTS)]
        )

    # -- discovery -------------------------------------------------------------------------
    def _register(self, plugin: object, name: str, source: PluginSource) -> None:
        try:
            self.pm.register(plugin, name=name)
        except pluggy.PluginValidationError as exc:  # e.g. an argument the hook spec does not have
            why = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
            raise PluginError(f"plugin {name} ({source.distribution}): {why}") from None
        self._sources[name] = source

    def _load_entry_points(self) -> None:
        twice = _installed_twice()
        if twice:  # which copy imports first is up to the file system: its version would be guesswork
            raise PluginError(
                "; ".join(
                    f"plugin distribution {name} is installed more than once ({', '.join(v)})"
                    for name, v in sorted(twice.items())
                )
                + ": remove the stale copy, or episodes could be stored under the wrong version"
            )
        off = {_canonical(name) for name in self.disabled_requested}
        installed: set[str] = set()
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            dist = getattr(ep, "dist", None)
            source = PluginSource(dist.name if dist else ep.value, dist.version if dist else "")
            names = {_canonical(ep.name), _canonical(source.distribution)}
            installed |= names
            if names & off:  # blocked before it is imported: a disabled plugin runs no code at all
                self.disabled[ep.name] = source
                self.pm.set_blocked(ep.name)
                continue
            if self.pm.get_plugin(ep.name) is not None or self.pm.is_blocked(ep.name):
                continue
            try:
                plugin = ep.load()
            except Exception as exc:  # a broken third-party install must not take the tool down
                self.load_failures[f"{ep.name} ({source.distribution})"] = f"{type(exc).__name__}: {exc}"
                continue
            self._register(plugin, ep.name, source)
        unknown = sorted(off - installed)
        if unknown:
            raise UserError(
                f"cannot disable {', '.join(unknown)}: no installed plugin has that entry-point or distribution name; "
                f"installed plugins: {', '.join(sorted(installed)) or '(none)'}"
            )

    def _check_hooks(self) -> None:
        """Refuse hook implementations without a spec: a misspelled hook would otherwise never run."""
        known = sorted(n for n in dir(hookspecs) if n.startswith(hookspecs.PROJECT_NAME + "_"))
        for name, caller in sorted(vars(self.pm.hook).items()):
            if not isinstance(caller, pluggy.HookCaller) or caller.has_spec():
                continue
            for impl in caller.get_hookimpls():
                close = difflib.get_close_matches(name, known, n=1)
                hint = f" (did you mean {close[0]}?)" if close else ""
                raise PluginError(
                    f"plugin {impl.plugin_name} ({self.source(impl.plugin_name).distribution}) "
                    f"implements an unknown hook {name!r}{hint}; the hooks are: {', '.join(known)}"
                )
        self.pm.check_pending()

    def source(self, plugin_name: str) -> PluginSource:
        return self._sources.get(plugin_name, PluginSource(plugin_name, ""))

    # -- registries ------------------------------------------------------------------------
    def _collect(self, hook_name: str, kind: str, build: Callable[..., Any]) -> dict[str, Any]:
        """Fill one registry, once: each plugin's implementation called through pluggy on its own, with a
        ``register`` callback bound to that plugin (so two plugins sharing a helper are still told apart).

        Plugins are called in registration order (built-ins, in-process extras, entry points), so a
        registry lists each plugin's names in the order it gave them. ``build(where, source, name, ...)``
        checks the call's arguments and makes the spec."""
        if hook_name in self._registries:
            return self._registries[hook_name]
        hook = getattr(self.pm.hook, hook_name)
        implementers = {impl.plugin_name for impl in hook.get_hookimpls() if not (impl.hookwrapper or impl.wrapper)}
        found: dict[str, Any] = {}
        for plugin_name in [name for name in self._sources if name in implementers]:
            others = [self.pm.get_plugin(name) for name in implementers if name != plugin_name]
            register = self._register_callback(hook_name, kind, plugin_name, build, found)
            self.pm.subset_hook_caller(hook_name, remove_plugins=others)(register=register)
            register.closed = True  # type: ignore[attr-defined]
        self._registries[hook_name] = found
        return found

    def _register_callback(
        self, hook_name: str, kind: str, plugin_name: str, build: Callable[..., Any], found: dict[str, Any]
    ) -> Callable[..., None]:
        source = self.source(plugin_name)

        def register(name: str, *args: Any, **kwargs: Any) -> None:
            if register.closed:  # type: ignore[attr-defined]
                raise PluginError(
                    f"plugin {plugin_name} ({source.distribution}) called register() of {hook_name} after its "
                    "implementation returned; register everything while the hook runs"
                )
            check_name(kind, name, plugin_name)
            if name in found:
                raise PluginError(f"{kind} {name!r} registered twice ({found[name].plugin} and {source.distribution})")
            where = f"{kind} {name!r} from {plugin_name}"
            try:
                found[name] = build(where, source, name, *args, **kwargs)
            except TypeError as exc:  # wrong arguments to register()
                raise PluginError(f"{where}: {exc}") from None

        register.closed = False  # type: ignore[attr-defined]
        return register

    def policies(self) -> dict[str, PolicySpec]:
        return self._collect("conflictbench_register_policies", "policy", policy_spec)

    def metrics(self) -> dict[str, MetricSpec]:
        return self._collect("conflictbench_register_metrics", "metric", metric_spec)

    def conflict_operators(self) -> dict[str, ConflictOperatorSpec]:
        return self._collect("conflictbench_register_conflict_operators", "conflict operator", operator_spec)

    def published_results(self) -> dict[str, PublishedResult]:
        """Entry name -> what a model's authors published for that checkpoint (``model.published=<name>``)."""
        return self._collect("conflictbench_register_published_results", "published result", published_spec)

    def families(self) -> tuple[str, ...]:
        """The built-in families, then any a plugin's operators add."""
        extra = sorted({s.family for s in self.conflict_operators().values()} - set(FAMILIES))
        return (*FAMILIES, *extra)

    def policy(self, name: str) -> PolicySpec:
        specs = self.policies()
        if name not in specs:
            raise UserError(unknown_choice("model", name, specs, self.load_failures))
        return specs[name]

    def global_hook_plugins(self) -> dict[str, list[str]]:
        """``distribution==version`` -> the global per-episode hooks it implements (they run for every policy)."""
        found: dict[str, list[str]] = {}
        for hook_name in GLOBAL_EPISODE_HOOKS:
            for impl in getattr(self.pm.hook, hook_name).get_hookimpls():
                if impl.plugin_name != _CORE_PROMPTS:
                    found.setdefault(self.source(impl.plugin_name).pin, []).append(hook_name)
        return found

    def provenance(self, policy: str) -> tuple[str, ...]:
        """``distribution==version`` of all code that can change this policy's episodes: conflictbench
        itself (its rollout loop and environment set-up), the plugin that registered the policy (with
        its own prompt format and post-processing) and every plugin that implements a global
        per-episode hook. Part of every episode's identity."""
        spec = self.policy(policy)
        own = self.source(_CORE_PROMPTS).pin
        return tuple(sorted({own, f"{spec.plugin}=={spec.plugin_version}", *self.global_hook_plugins()}))

    # -- per-episode hooks -----------------------------------------------------------------
    def format_prompt(self, instruction: str, condition: str, policy: str) -> str:
        """The text ``policy`` receives: a global hook's (first string wins), else the policy's own
        ``format_prompt``, else the core's default (P0 the text; P1 the preamble, then the text)."""
        if condition not in PROMPT_CONDITIONS:
            raise UserError(f"unknown prompt condition {condition!r}; choose one of {', '.join(PROMPT_CONDITIONS)}")
        text = self._global_prompt(instruction=instruction, condition=condition, policy=policy)
        where = "conflictbench_format_prompt"
        if text is None:
            spec = self.policies().get(policy)
            if spec is not None and spec.format_prompt is not None:
                text, where = spec.format_prompt(instruction, condition), f"format_prompt of policy {policy!r}"
        if text is None:
            text = prompts.default_format_prompt(instruction, condition)
        if not isinstance(text, str):
            raise PluginError(f"{where} returned {type(text).__name__}, expected str")
        return text

    def _global_chain(self) -> list[tuple[str, Any]]:
        """One pluggy caller per global post-processor, in call order: each holds that implementation
        and every wrapper, so links are called through pluggy one at a time."""
        if self._chain is None:
            name = "conflictbench_postprocess_action"
            impls = [
                i for i in reversed(getattr(self.pm.hook, name).get_hookimpls()) if not (i.hookwrapper or i.wrapper)
            ]
            self._chain = [
                (
                    impl.plugin_name,
                    self.pm.subset_hook_caller(name, remove_plugins=[o.plugin for o in impls if o is not impl]),
                )
                for impl in impls
            ]
        return self._chain

    def postprocess_action(self, action: np.ndarray, context: ActionContext) -> np.ndarray:
        """The action the environment executes: the policy's own post-processing, then the global chain."""
        spec = self.policies().get(context.policy)
        if spec is not None and spec.postprocess is not None:
            action = _checked_action(
                spec.postprocess(action, context), action, f"postprocess of policy {context.policy!r}"
            )
        for plugin_name, call in self._global_chain():
            results = call(action=action, context=context)
            action = _checked_action(results[0] if results else None, action, f"post-processor {plugin_name}")
        return action


def _checked_action(out: Any, previous: np.ndarray, where: str) -> np.ndarray:
    if out is None:
        return previous
    out = np.asarray(out, dtype=np.float64)
    if out.shape != (ACTION_DIM,):
        raise PolicyError(f"{where} returned shape {out.shape}, expected ({ACTION_DIM},)")
    return out


def unknown_choice(what: str, value: str, choices: Iterable[str], failures: dict[str, str] | None = None) -> str:
    """The one-line message for an option value that does not exist."""
    msg = f"unknown {what} {value!r}; valid choices: {', '.join(sorted(choices))}"
    if failures:
        msg += "; plugins that failed to load: " + "; ".join(f"{k}: {v}" for k, v in failures.items())
    return msg


def _installed_twice() -> dict[str, list[str]]:
    """Plugin distributions found in several versions on the import path (``pip --target --upgrade``
    can leave both), by name."""
    versions: dict[str, set[str]] = {}
    for dist in metadata.distributions():
        if any(ep.group == ENTRY_POINT_GROUP for ep in dist.entry_points):
            name = (dist.metadata["Name"] or "").lower().replace("_", "-")
            versions.setdefault(name, set()).add(dist.version)
    return {name: sorted(v) for name, v in versions.items() if len(v) > 1}


def _canonical(name: str) -> str:
    """A name as PyPI compares names: ``Conflictbench_Demo`` is ``conflictbench-demo``."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "0+unknown"
