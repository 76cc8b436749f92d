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
from conflictbench.cli.overrides import CHECKOUT
from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins

#: A name a distribution, a package (``conflictbench_NAME``), an entry point and a policy can all have: at most 20
#: characters, no ``_`` at the end (the distribution's name would end in ``-``, which no installer takes).
NAME = re.compile(r"[a-z][a-z0-9_]{0,18}[a-z0-9]|[a-z]")
#: What the generated plugin requires: the releases whose API the template uses (the plugin layout, ServedModel.of).
CONFLICTBENCH_VERSION = "0.3"
SERVING_VERSION = "0.2"


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
    client_imports: tuple[str, ...] = ()
    """What else the client module imports for the protocol, each ``MODULE:NAME``."""
    ready_check: str = ""
    """The client policy's ``ready_check`` where the protocol has no HTTP ``/healthz`` (a method's lines)."""


PROTOCOLS = {
    "openpi": Protocol("openpi's websocket protocol (msgpack-numpy)", "ws", 8000, "openpi:OpenpiTransport"),
    "zeromq": Protocol(
        "NVIDIA's ZeroMQ protocol (msgpack)",
        "tcp",
        5555,
        "zeromq:ZmqTransport",
        client_extra="[zeromq]",
        server_extra="[zeromq]",
        envelope='["data"]',  # the request is the data of a get_action call
        client_imports=("conflictbench.hosting.zeromq:answers_ping", "conflictbench_serving.zeromq:GET_ACTION"),
        ready_check="""
    def ready_check(self, url: str):
        return lambda: answers_ping(url)  # ZeroMQ has no HTTP /healthz: a started server answers a ping
""",
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


#: The README's first steps: in conflictbench's checkout (``plugins/NAME``), set-up installs both halves; elsewhere,
#: by hand, from the plugin's folder.
TRY_IN_CHECKOUT = """From conflictbench's checkout (`scripts/setup.sh` made `.venv`):

```bash
scripts/setup.sh --models ${name}   # the client into .venv, the server half into .venv/models/${name}
mkdir -p standin && echo '{"type": "${name}"}' > standin/config.json   # the stand-in's checkpoint
MUJOCO_GL=egl .venv/bin/conflictbench model=${name} model.checkpoint=standin suite=physical level=L1 \\
    run.cases_per_cell=1 run.libero_suites=[libero_spatial] run.max_steps=40
.venv/bin/pip install -e './plugins/${name}[test]' && .venv/bin/pytest plugins/${name}/tests
```

By hand, anywhere: `pip install ./serving ./plugins/${name}` beside conflictbench (the client half; neither is on
PyPI), `pip install ./serving ./plugins/${name}/server` in the Python that will host the model (the server half; not
both halves in one Python), and `model.python=` that Python in the run."""
TRY_ELSEWHERE = """From this folder, `CHECKOUT` being a checkout of conflictbench (conflictbench-serving, which both
halves require, is not on PyPI): the client half beside conflictbench, the server half in a Python of its own (not
both halves in one Python), `model.python=` that Python in the run.

```bash
pip install CHECKOUT/serving -e '.[test]'   # the client half, in the Python that has conflictbench
python3 -m venv model-env && model-env/bin/pip install CHECKOUT/serving ./server   # the server half
mkdir -p standin && echo '{"type": "${name}"}' > standin/config.json   # the stand-in's checkpoint
MUJOCO_GL=egl conflictbench model=${name} model.checkpoint=standin model.python=model-env/bin/python \\
    suite=physical level=L1 run.cases_per_cell=1 run.libero_suites=[libero_spatial] run.max_steps=40
pytest tests
```"""


def in_checkout(target: Path) -> bool:
    """Whether ``target`` is a folder of the ``plugins/`` of conflictbench's checkout (which README's table lists)."""
    return (CHECKOUT / "serving").is_dir() and target.resolve().parent == (CHECKOUT / "plugins").resolve()


def client_imports(spec: Protocol) -> str:
    """The client module's imports for the protocol: its transport and ``spec.client_imports``, one line a module."""
    names: dict[str, list[str]] = {}
    for entry in (f"conflictbench.hosting.{spec.transport}", *spec.client_imports):
        module, name = entry.split(":")
        names.setdefault(module, []).append(name)
    return "\n".join(f"from {module} import {', '.join(names[module])}" for module in sorted(names))


def substitutions(name: str, protocol: str, checkout: bool = True) -> dict[str, str]:
    """What the template's ``${...}`` stand for (``checkout``: the plugin is in conflictbench's ``plugins/``)."""
    spec = PROTOCOLS[protocol]
    transport = spec.transport.partition(":")[2]
    wire = '{"endpoint": GET_ACTION, "data": request}' if spec.envelope else "request"
    try_it = string.Template(TRY_IN_CHECKOUT if checkout else TRY_ELSEWHERE).substitute(name=name)
    return {
        "name": name,
        "Name": "".join(part.capitalize() for part in name.split("_")),
        "package": f"conflictbench_{name}",
        "dist": name.replace("_", "-"),
        "protocol": protocol,
        "protocol_words": spec.words,
        "scheme": spec.scheme,
        "port": str(spec.port),
        "transport_import": client_imports(spec),
        "transport": transport,
        "ready_check": spec.ready_check,
        "wire_request": wire,
        "inner": spec.envelope,
        "client_dependencies": "".join(f'    "{requirement}",\n' for requirement in spec.client_dependencies),
        "test_dependencies": "".join(f', "{requirement}"' for requirement in spec.test_dependencies),
        "client_extra": spec.client_extra,
        "server_extra": spec.server_extra,
        "conflictbench_extra": f"[{protocol}]",
        "conflictbench_version": CONFLICTBENCH_VERSION,
        "serving_version": SERVING_VERSION,
        "try_it": try_it,
    }


def check_name(name: str, plugins: Plugins) -> None:
    """One line (UserError) for a name a plugin cannot have, or one an installed plugin already uses."""
    if not NAME.fullmatch(name) or keyword.iskeyword(name):
        raise UserError(
            f"new-plugin: {name!r} cannot name a plugin: lower-case letters, digits and _, starting with a letter and "
            "not ending with _, at most 20 (it names the policy, the package conflictbench_NAME and both entry points)"
        )
    if name in plugins.policies():
        raise UserError(f"new-plugin: an installed plugin already registers the policy {name!r} (conflictbench list)")
    for group in ("conflictbench", "conflictbench_serving"):
        if any(entry.name == name for entry in metadata.entry_points(group=group)):
            raise UserError(f"new-plugin: an installed plugin already has the entry point {name!r} ({group})")


def write_plugin(name: str, protocol: str, target: Path) -> list[Path]:
    """Write the plugin into ``target`` (missing or empty); the files written."""
    values = substitutions(name, protocol, in_checkout(target))
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
    try:
        if target.exists() and (not target.is_dir() or any(target.iterdir())):
            raise UserError(f"new-plugin: {target} exists and is not empty")
        written = write_plugin(args.name, args.protocol, target)
    except OSError as error:  # a folder it may not write in, or not read
        raise UserError(f"new-plugin: cannot write {target}: {error.strerror or error}") from None
    for path in written:
        print(path)
    # README's table lists the checkout's plugins, and a test keeps it current: the new folder is a row to write.
    table = "; then add it to README's table: .venv/bin/python scripts/readme_plugins.py" if in_checkout(target) else ""
    print(
        f"conflictbench: wrote the {args.name} plugin ({args.protocol}) in {target}, {len(written)} files; "
        f"try it: {target / 'README.md'}{table}",
        file=sys.stderr,
    )
    return 0
