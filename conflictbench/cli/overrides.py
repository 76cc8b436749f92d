"""The checks of a command line's overrides that come before Hydra composes anything (one line, exit code 2)."""

from __future__ import annotations

import dataclasses
import functools
import tomllib
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins, unknown_choice

GROUPS = ("model", "suite", "level", "prompt", "run")

#: Where conflictbench's own folder sits in a checkout of the project (an editable install): ``plugins/`` beside it.
CHECKOUT = Path(__file__).resolve().parents[2]


@functools.cache
def checkout_plugins() -> dict[str, dict[str, Any]]:
    """The model plugins of the checkout conflictbench runs from, by folder (``plugins/<folder>``): what each
    declares in its ``pyproject.toml`` under ``[tool.conflictbench]`` (``policies``, ``protocol``,
    ``model-environment``). Nothing lists them elsewhere, so a new plugin is its folder alone. Empty where
    conflictbench is not run from a checkout (an installed wheel)."""
    try:
        if tomllib.loads((CHECKOUT / "pyproject.toml").read_text())["project"]["name"] != "conflictbench":
            return {}
    except (OSError, KeyError, tomllib.TOMLDecodeError):
        return {}
    found = {}
    for pyproject in sorted(CHECKOUT.glob("plugins/*/pyproject.toml")):
        table = tomllib.loads(pyproject.read_text()).get("tool", {}).get("conflictbench")
        if isinstance(table, dict):
            found[pyproject.parent.name] = table
    return found


def project_plugins() -> dict[str, str]:
    """Policy -> the folder of this project's plugin that registers it (:func:`checkout_plugins`): a run naming
    one whose plugin is not installed says which command installs it (tests/test_cli.py keeps each
    plugin's declared policies what it registers)."""
    return {policy: folder for folder, table in checkout_plugins().items() for policy in table.get("policies", ())}


def group_choices(group: str, plugins: Plugins) -> list[str]:
    """The options of a config group: registered policies for ``model``, YAML files otherwise."""
    if group == "model":
        return sorted(plugins.policies())
    folder = resources.files("conflictbench.conf") / group
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def default_model() -> str:
    """The ``model`` of ``conf/config.yaml``'s defaults."""
    defaults = OmegaConf.load(str(resources.files("conflictbench.conf") / "config.yaml")).defaults
    return next(str(entry["model"]) for entry in defaults if isinstance(entry, DictConfig) and "model" in entry)


def check_model_fields(argv: Sequence[str], plugins: Plugins) -> None:
    """Reject ``model.<field>=...`` for a field the chosen policies lack (one line naming theirs), before Hydra
    answers with its multi-line "To append to your config use +model...", and ``+model.<field>=`` too (the
    model would ignore it). Where the model is not a plain choice on this line (a sweep function, another config,
    a sweeper's params), Hydra checks."""
    models = [default_model()]
    for arg in argv:
        key, _, value = arg.partition("=")
        if arg.startswith(("-c", "--config", "hydra.sweeper")) or key.startswith("model@"):
            return
        if key == "model":
            if not value or any(ch in value for ch in "()[]{}*$"):
                return
            models = [item.strip() for item in value.split(",")]
    for arg in argv:
        key = arg.partition("=")[0]
        key = key.lstrip("+")  # an append (+model.x=) of a field the model lacks would be silently ignored
        if arg.startswith(("-", "~")) or not key.startswith("model.") or "=" not in arg:
            continue
        field = key.split(".")[1]
        for model in models:
            spec = plugins.policies().get(model)
            if spec is None:
                continue  # an unknown model: check_group_overrides says so
            names = [f.name for f in dataclasses.fields(spec.config)] if dataclasses.is_dataclass(spec.config) else []
            if field not in names:
                settings = ", ".join(names) if names else "none"
                raise UserError(f"{key}: {model} has no setting {field!r} (its settings: {settings})")


def check_group_overrides(argv: Sequence[str], plugins: Plugins) -> None:
    """Reject ``group=unknown`` before Hydra composes anything (one line, exit code 2)."""
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.lstrip("+~").split("=", 1)
        if key not in GROUPS or any(ch in value for ch in "()[]{}*$"):
            continue  # a field override or a sweep function: Hydra checks those
        choices = group_choices(key, plugins)
        for item in value.split(","):
            if item.strip() not in choices:
                failures = plugins.load_failures if key == "model" else None
                if key == "model" and item.strip() in project_plugins():
                    raise UserError(not_installed(item.strip()))
                raise UserError(unknown_choice(key, item.strip(), choices, failures))


def not_installed(model: str) -> str:
    """The one-line message for a model of this project whose plugin is not installed."""
    folder = project_plugins()[model]
    return (
        f"model={model} comes with the {folder} model plugin, which is not installed here: "
        f"scripts/setup.sh --models {folder} installs it with its model environment "
        f"(or pip install ./serving ./plugins/{folder}, see plugins/{folder}/README.md)"
    )


#: Flags that bring in another configuration (its own groups and keys): then Hydra alone knows what is valid.
OTHER_CONFIG_FLAGS = ("-cn", "--config-name", "-cp", "--config-path", "-cd", "--config-dir")


def group_keys(group: str) -> list[str]:
    """The options of a YAML group (``run``, ``suite``...): the keys of any of its files."""
    folder = resources.files("conflictbench.conf") / group
    keys = set()
    for path in folder.iterdir():
        if path.name.endswith(".yaml"):
            keys |= {str(k) for k in OmegaConf.load(str(path)) if k != "defaults"}
    return sorted(keys)


def _closest(name: str, choices: Sequence[str], what: str) -> str:
    import difflib

    close = difflib.get_close_matches(name, choices, n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else f"; {what}: {', '.join(choices)}"


def check_known_keys(argv: Sequence[str]) -> None:
    """Reject a key the configuration does not have (``run.init_state=2``, ``levl=L1``), and the same key
    appended (``+run.init_state=2``, which Hydra advises and which would run silently with the default): one line
    naming the closest valid key. ``model.<field>`` is check_model_fields'; Hydra's own keys pass."""
    if any(arg.partition("=")[0] in OTHER_CONFIG_FLAGS for arg in argv):
        return
    for arg in argv:
        if arg.startswith(("-", "~")) or "=" not in arg:
            continue
        key = arg.partition("=")[0].lstrip("+")
        if key == "hydra" or key.startswith(("hydra.", "hydra/")) or "@" in key:
            continue  # Hydra's settings, launcher/sweeper groups, and package overrides
        head, _, field = key.partition(".")
        if head not in GROUPS:
            raise UserError(f"{key}: no such option{_closest(head, GROUPS, 'options')}")
        if field and head != "model":
            keys = group_keys(head)
            name = field.split(".")[0]
            if name not in keys:
                raise UserError(
                    f"{head}.{name}: the {head} has no option {name!r}{_closest(name, keys, 'its options')}"
                )


def check_verb(argv: Sequence[str], verbs: Sequence[str]) -> None:
    """A first word that is neither an override (``key=value``, ``~key``) nor a flag is a mistyped verb."""
    first = argv[0] if argv else ""
    if not first or first.startswith(("-", "~", "+")) or "=" in first or first in verbs:
        return
    raise UserError(f"unknown command {first!r}{_closest(first, sorted(verbs), 'commands')}")
