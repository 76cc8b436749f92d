"""``conflictbench new-plugin NAME --protocol openpi|zeromq|rest [--dir DIR]``: a served model plugin from a template.

It writes ``DIR/NAME`` (default ``plugins/NAME``): both halves of a plugin in the layout every model plugin has
(README, "Model plugins"), with a stand-in backend (numpy, deterministic) that answers, so the plugin plays real
LIBERO episodes as written; its author then replaces the protocol's keys, the processing, the checkpoint check and
the backend. The template is package data (``plugin_template/``, files ending ``.tmpl``, filled in with
:class:`string.Template`); ``servers/PROTOCOL.py.tmpl`` is the one file that differs by protocol, the rest differ
by a few names and lines given below.
"""

from __future__ import annotations

import keyword
import re
import string
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import metadata, resources
from pathlib import Path

from conflictbench.cli.args import Parser
from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins

#: A name a distribution, a package (``conflictbench_NAME``), an entry point and a policy can all have.
NAME = re.compile(r"[a-z][a-z0-9_]{0,19}")


@dataclass(frozen=True)
class Protocol:
    words: str
    scheme: str
    port: int
    transport: str
    """The client's transport class in ``conflictbench.hosting.MODULE``, as ``MODULE:CLASS``."""
    client_extra: str = ""
    """conflictbench-serving's extra for the client half (it imports ``server.py``, so its module-level imports)."""
    server_extra: str = ""
    """conflictbench-serving's extra with the protocol's server, for the server half."""
    client_dependencies: tuple[str, ...] = ()
    """What else the client half's own modules import."""
    test_dependencies: tuple[str, ...] = ()
    envelope: str = ""
    """Where the protocol's request sits in what the client sends (``["data"]``: inside ZeroMQ's envelope)."""


PROTOCOLS = {
    "openpi": Protocol("openpi's websocket protocol (msgpack-numpy)", "ws", 8000, "openpi:OpenpiTransport"),
    "zeromq": Protocol(
        "NVIDIA's ZeroMQ protocol (msgpack)",
        "tcp",
        5555,
        "zeromq:ZmqTransport",
        client_extra="[zeromq]",
        server_extra="[zeromq]",
        envelope='["data"]',
    ),  # fmt: skip
    "rest": Protocol(
        "REST POST /act with json-numpy bodies",
        "http",
        8000,
        "rest:JsonNumpyTransport",
        server_extra="[rest]",
        client_dependencies=("json-numpy>=2.1",),  # server.py's codec; FastAPI and uvicorn only where it serves
        test_dependencies=("fastapi>=0.110", "uvicorn>=0.29"),  # the server half, in the round trip's Python
    ),  # fmt: skip
}
#: What ZeroMQ's client adds: its envelope's endpoint, and a readiness check (it has no HTTP /healthz).
ZEROMQ_IMPORTS = "\nfrom conflictbench_serving.zeromq import GET_ACTION"
ZEROMQ_READY = """
    def ready_check(self, url: str):
        return lambda: answers_ping(url)  # ZeroMQ has no HTTP /healthz: a started server answers a ping
"""

#: Each template file and where it goes, below ``DIR/NAME``.
FILES = {
    "README.md.tmpl": "README.md",
    "pyproject.toml.tmpl": "pyproject.toml",
    "server/pyproject.toml.tmpl": "server/pyproject.toml",
    "package/__init__.py.tmpl": "${package}/__init__.py",
    "package/protocol.py.tmpl": "${package}/protocol.py",
    "package/processing.py.tmpl": "${package}/processing.py",
    "package/checkpoints.py.tmpl": "${package}/checkpoints.py",
    "package/client.py.tmpl": "${package}/client.py",
    "servers/${protocol}.py.tmpl": "${package}/server.py",
    "package/backend.py.tmpl": "${package}/backend.py",
    "tests/conftest.py.tmpl": "tests/conftest.py",
    "tests/test_protocol.py.tmpl": "tests/test_${name}_protocol.py",
    "tests/test_client.py.tmpl": "tests/test_${name}_client.py",
}


def _version(distribution: str, fallback: str) -> str:
    """``MAJOR.MINOR`` of an installed distribution: the least the generated plugin requires."""
    try:
        return ".".join(metadata.version(distribution).split(".")[:2])
    except metadata.PackageNotFoundError:
        return fallback


def substitutions(name: str, protocol: str) -> dict[str, str]:
    """What the template's ``${...}`` stand for."""
    spec = PROTOCOLS[protocol]
    module, transport = spec.transport.split(":")
    wire = '{"endpoint": GET_ACTION, "data": request}' if spec.envelope else "request"
    return {
        "name": name,
        "Name": "".join(part.capitalize() for part in name.split("_")),
        "package": f"conflictbench_{name}",
        "dist": name.replace("_", "-"),
        "protocol": protocol,
        "protocol_words": spec.words,
        "scheme": spec.scheme,
        "port": str(spec.port),
        "transport_import": f"from conflictbench.hosting.{module} import {transport}"
        + (", answers_ping" + ZEROMQ_IMPORTS if spec.envelope else ""),
        "transport": transport,
        "ready_check": ZEROMQ_READY if spec.envelope else "",
        "wire_request": wire,
        "inner": spec.envelope,
        "client_dependencies": "".join(f'    "{requirement}",\n' for requirement in spec.client_dependencies),
        "test_dependencies": "".join(f', "{requirement}"' for requirement in spec.test_dependencies),
        "client_extra": spec.client_extra,
        "server_extra": spec.server_extra,
        "conflictbench_extra": f"[{protocol}]",
        "conflictbench_version": _version("conflictbench", "0.2"),
        "serving_version": _version("conflictbench-serving", "0.1"),
    }


def check_name(name: str, plugins: Plugins) -> None:
    """One line (UserError) for a name a plugin cannot have, or one an installed plugin already uses."""
    if not NAME.fullmatch(name) or keyword.iskeyword(name):
        raise UserError(
            f"new-plugin: {name!r} cannot name a plugin: lower-case letters, digits and _, starting with a letter, "
            "at most 20 (it names the policy, the package conflictbench_NAME and both entry points)"
        )
    if name in plugins.policies():
        raise UserError(f"new-plugin: an installed plugin already registers the policy {name!r} (conflictbench list)")
    for group in ("conflictbench", "conflictbench_serving"):
        if any(entry.name == name for entry in metadata.entry_points(group=group)):
            raise UserError(f"new-plugin: an installed plugin already has the entry point {name!r} ({group})")


def write_plugin(name: str, protocol: str, target: Path) -> list[Path]:
    """Write the plugin into ``target`` (missing or empty); the files written."""
    values = substitutions(name, protocol)
    template = resources.files(__package__) / "plugin_template"
    written = []
    for source, destination in FILES.items():
        text = (template / string.Template(source).substitute(values)).read_text(encoding="utf-8")
        path = target / string.Template(destination).substitute(values)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(string.Template(text).substitute(values), encoding="utf-8")
        written.append(path)
    return written


def command(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(
        prog="conflictbench new-plugin",
        description="Write a served model plugin, both halves, from a template: a client for the protocol, its "
        "server half with a stand-in backend (numpy) that answers, a README and tests. It plays real episodes as "
        "written; then replace its protocol's keys, processing, checkpoint check and backend with your model's.",
    )
    parser.add_argument("name", metavar="NAME", help="the policy's name (model=NAME), e.g. mymodel")
    parser.add_argument("--protocol", required=True, choices=sorted(PROTOCOLS), help="the wire protocol")
    parser.add_argument("--dir", default="plugins", help="where the plugin's folder goes (default: %(default)s)")
    args = parser.parse_args(argv)
    check_name(args.name, plugins)
    target = Path(args.dir) / args.name
    if target.exists() and (not target.is_dir() or any(target.iterdir())):
        raise UserError(f"new-plugin: {target} exists and is not empty")
    written = write_plugin(args.name, args.protocol, target)
    for path in written:
        print(path)
    print(
        f"conflictbench: wrote the {args.name} plugin ({args.protocol}) in {target}, {len(written)} files; "
        f"try it: {target / 'README.md'}",
        file=sys.stderr,
    )
    return 0
