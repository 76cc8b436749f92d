"""A model environment's stack: what its probe says before the run plans, and how two stacks differ in words.

A served model's episodes count the model stack they ran on (the device kind and every distribution's version in the
model environment). The run reads it from the environment's files, through a probe run by that environment's Python,
before it plans; a started server must then report the same.
"""

from __future__ import annotations

import json
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..core.errors import UserError

#: Set for every model process unless the user set it: bfloat16 kernels beyond AVX512 kill some CPUs' VMs
#: (SIGILL), and CPU inference of these models never needs them.
MODEL_PROCESS_ENV: Mapping[str, str] = {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16"}
#: What a model environment's probe prints last (JSON): its distributions' versions, read from their files, and the
#: device the server will run on, ``auto`` decided as the server decides it (torch's word), so both are known before
#: the run plans.
_STACK_PROBE = """
import json, sys
try:
    from conflictbench_serving.stack import installed_versions
except ImportError:  # a plugin's own server, without the serving half: its stack is not known
    installed_versions = dict
device = sys.argv[1]
if device == "auto":
    try:
        import torch
        device = "cuda" if torch.cuda.is_available() else "cpu"
    except ImportError:
        device = "cpu"
print(json.dumps({"versions": installed_versions(), "device": device}))
"""
#: What the last probe of each model environment said, by interpreter and device setting.
_PROBED: dict[tuple[str, str], dict[str, Any]] = {}
UNREPORTED = "unreported"


def probe_environment(python: Path, importing: str, device: str, what: str, setup: str) -> None:
    """Run ``importing`` and the stack probe in ``python``: a failure is a :class:`UserError` naming ``what`` cannot
    run and ``setup`` (how to build it); what the probe says is kept for :func:`probed_stack`."""
    done = subprocess.run([str(python), "-c", importing + _STACK_PROBE, device], capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["?"])[-1]
        raise UserError(f"{python} cannot run {what} ({last}): build it with {setup}")
    try:
        _PROBED[(str(python), device)] = json.loads(done.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):  # something in the environment printed over it: the stack is not known
        _PROBED.pop((str(python), device), None)


def probed_stack(python: Path | None, device: str) -> tuple[dict[str, Any] | str, str | None]:
    """The model stack of ``python``'s environment as its last probe said it, and the device ``device`` (maybe
    ``auto``) was decided to be; (``unreported``, None) where not known."""
    said = _PROBED.get((str(python), device)) if python is not None else None
    if not said or not said.get("versions"):
        return UNREPORTED, None
    try:
        from conflictbench_serving.stack import model_stack
    except ImportError:  # a plugin's own client without the serving half here
        return UNREPORTED, None
    return model_stack(said["device"], said["versions"]), said["device"]


def version_changes(old: Mapping[str, str], new: Mapping[str, str]) -> list[str]:
    """Each name whose value differs, in words: ``name a -> b``, ``name added``, ``name removed`` (``device`` first,
    then by name). What a run says of two stacks, the model's or the simulator's."""
    words = []
    for name in sorted(old.keys() | new.keys(), key=lambda n: (n != "device", n)):
        if name not in new:
            words.append(f"{name} removed")
        elif name not in old:
            words.append(f"{name} added")
        elif old[name] != new[name]:
            words.append(f"{name} {old[name]} -> {new[name]}")
    return words


def stack_difference(counted: Mapping[str, Any], reported: Mapping[str, Any]) -> str:
    """The first few ways two model stacks differ, in words."""
    words = version_changes(
        {"device": counted.get("device"), **(counted.get("packages") or {})},
        {"device": reported.get("device"), **(reported.get("packages") or {})},
    )
    return ", ".join(words[:3]) + (f" and {len(words) - 3} more" if len(words) > 3 else "")
