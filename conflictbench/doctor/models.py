"""``conflictbench doctor model=NAME [model.checkpoint=DIR | model.server=URL]``: does this model answer here?

Each step a run takes before its first episode, in order, one line each, stopping at the first that fails (the
later ones cannot run without it): the plugin that registers the model is installed; the policy loads (for a
served model: its model environment is built and can host it, and the checkpoint folder is one of its kind); its
server starts, or the running one answers; one request makes the round trip in the model's native protocol and an
action of the right shape comes back; and what the server says it runs (its versions and device). A missing piece
is one line naming the command that fixes it. Nothing here plays an episode or writes a store.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from conflictbench.core import PluginError, ServerUnavailable, UserError
from conflictbench.core.plugins import Plugins
from conflictbench.hosting.client import ServedPolicy

from .checks import Check

#: The request a doctor sends: an observation as a worker sends it (two renders, an 8-D state), its instruction
#: one of LIBERO's own.
INSTRUCTION = "put the black bowl on the plate"


def model_overrides(argv: Sequence[str], plugins: Plugins) -> tuple[str, dict[str, Any]]:
    """The model's name and its settings from ``model=NAME model.FIELD=VALUE ...`` (values typed as Hydra types
    them); any other word, and a setting the model lacks, is a user mistake. A model nobody registers is left to
    :meth:`Plugins.policy` (the command line's own checks, ``conflictbench.cli.doctor``, say first which plugin
    brings a model of this project)."""
    for arg in argv:
        key = arg.partition("=")[0]
        if "=" not in arg or not (key == "model" or key.startswith("model.")) or key.count(".") > 1:
            raise UserError(
                f"doctor checks a model given as model=NAME [model.checkpoint=DIR | model.server=URL], got {arg!r}"
            )
    names = [arg.partition("=")[2] for arg in argv if arg.partition("=")[0] == "model"]
    if len(names) != 1 or "," in names[0]:
        raise UserError("doctor checks one model at a time: give model=NAME once (e.g. model=pi05)")
    dotlist = [arg for arg in argv if arg.startswith("model.")]
    settings = OmegaConf.to_container(OmegaConf.from_dotlist(dotlist), resolve=True).get("model", {}) if dotlist else {}
    spec = plugins.policies().get(names[0])
    if spec is not None:
        known = [f.name for f in dataclasses.fields(spec.config)] if dataclasses.is_dataclass(spec.config) else []
        for field in settings:
            if field not in known:
                raise UserError(f"model.{field}: {names[0]} has no setting {field!r} (its settings: "
                                f"{', '.join(known) or 'none'})")  # fmt: skip
    return names[0], dict(settings)


def _observation(policy) -> Any:
    from .observations import camera_observation  # runtime code: never the tests' helpers, which need pytest

    observation = camera_observation(0, INSTRUCTION, suite="libero_spatial")
    if not getattr(policy, "needs_images", True):
        observation = type(observation)(**{**observation.__dict__, "agentview_image": None, "wrist_image": None})
    return observation


def _round_trip(policy) -> np.ndarray:
    observation = _observation(policy)
    policy.reset(observation.instruction)
    if hasattr(policy, "act_batch"):
        (answer,) = policy.act_batch([observation])
        if isinstance(answer, BaseException):
            raise answer
        return np.asarray(answer)
    return np.asarray(policy.act(observation))


def _stack_words(metadata: dict[str, Any], identity: dict[str, Any]) -> str:
    """What the server says it runs: its device and versions (the packages that decide its numbers first)."""
    stack = metadata.get("model_stack") or identity.get("model_stack")
    if not isinstance(stack, dict):
        return "the server does not say what it runs (a server of conflictbench-serve does)"
    packages = dict(stack.get("packages") or {})
    first = [name for name in ("torch", "jax", "transformers", "lerobot", "numpy") if name in packages]
    shown = [f"{name} {packages.pop(name)}" for name in first] + [f"{n} {v}" for n, v in sorted(packages.items())][:6]
    more = len(packages) - len(shown) + len(first)
    return f"device {stack.get('device', '?')}; " + ", ".join(shown) + (f" and {more} more" if more > 0 else "")


def model_checks(argv: Sequence[str], plugins: Plugins) -> list[Check]:
    """The model's lines, in the order a run meets them; the first failure ends the list."""
    name, settings = model_overrides(argv, plugins)
    spec = plugins.policy(name)
    checks = [Check("plugin", True, f"model={name} comes from {spec.plugin} {spec.plugin_version}")]
    try:
        config = spec.make_config(settings)
        started = time.perf_counter()
        policy = spec.load(config)  # a served model's environment is checked here, a running server asked
        checks.append(Check("load", True, f"loaded in {time.perf_counter() - started:.1f} s" + _where(config)))
    except (UserError, PluginError, ServerUnavailable) as exc:
        return [*checks, Check("load", False, str(exc))]
    if getattr(policy, "needs_privileged", False) or getattr(policy, "needs_scene_state", False):
        return [*checks, Check("request", True, f"{name} reads the simulator's state: it answers only in a run "
                                                f"(`conflictbench model={name}` plays one)")]  # fmt: skip
    served = isinstance(policy, ServedPolicy)
    try:
        started = time.perf_counter()
        if hasattr(policy, "start"):
            policy.start()
        server = getattr(getattr(policy, "server", None), "log_path", None)
        if server is not None or getattr(config, "server", ""):
            where = f"started (log: {server})" if server is not None else f"answered at {config.server}"
            checks.append(Check("server", True, f"{where} in {time.perf_counter() - started:.1f} s"))
        started = time.perf_counter()
        action = _round_trip(policy)
        shape_ok = action.ndim in (1, 2) and action.shape[-1] == 7 and bool(np.isfinite(action).all())
        took = f"{1000 * (time.perf_counter() - started):.0f} ms"
        how = "one request in the model's native protocol" if served else "one observation, in process"
        text = f"{how}: an action of shape {action.shape} in {took}"
        checks.append(Check("request", shape_ok, text if shape_ok else f"{text}, not (7,) or (k, 7) finite values"))
        if served:
            identity = getattr(policy, "identity", {}) or {}
            checks.append(Check("versions", True, _stack_words(getattr(policy, "metadata", {}) or {}, identity)))
    except (UserError, ServerUnavailable, PluginError) as exc:
        checks.append(Check("server", False, str(exc)))
    except Exception as exc:  # the model's own failure on a well-formed request: say it, as a run would
        checks.append(Check("request", False, f"the policy failed on a request: {type(exc).__name__}: {exc}"))
    finally:
        if hasattr(policy, "close"):
            policy.close()
    return checks


def _where(config: Any) -> str:
    checkpoint, server = getattr(config, "checkpoint", ""), getattr(config, "server", "")
    return f" (server {server})" if server else (f" ({checkpoint})" if checkpoint else "")
