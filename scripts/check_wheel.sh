#!/usr/bin/env bash
# The package as a user gets it, not the checkout: what only the wheel can get wrong. Build a wheel from a clean
# copy of the sources and check that it holds every file of the package and of the config tree; install it (not
# editable) into a fresh virtual environment with the test tools but without the simulator, and run the tests that
# read what the wheel must carry or find what it must declare (the config tree, plugin discovery, the public API's
# import paths, imports without the simulator), not the whole selection again;
# then add the simulator and, from an empty directory, run `conflictbench list`, a real run of the default model
# (one reference and one conflict episode of libero_spatial, about 25 s), the viewer on it, `conflictbench new-plugin`
# (its packaged template) and `conflictbench doctor` (the packaged goldens replayed in this fresh environment); then,
# with conflictbench-serving and the protocols' extras added, every module of the installed wheel imported (what it
# declares is enough); last, each model plugin installed alone (not editable) beside it, as
# `pip install . ./serving ./plugins/NAME` would.
#
#   scripts/check_wheel.sh          PYTHON=... picks the interpreter (default: .venv's)
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD
PYTHON=${PYTHON:-.venv/bin/python}
case $PYTHON in */*) [[ $PYTHON == /* ]] || PYTHON=$repo/$PYTHON ;; esac  # a path holds from any directory

say() { printf '[check_wheel] %s\n' "$*" >&2; }
work=$(mktemp -d "${TMPDIR:-/tmp}/conflictbench-wheel.XXXXXX")
trap 'rm -rf "$work"' EXIT

# 1. The files a fresh clone has (tracked and new, not ignored): no build/, egg-info or caches,
#    which an in-place build would read (a stale build/lib puts deleted modules into the wheel).
mkdir "$work/src"
git ls-files -z --cached --others --exclude-standard | tar --null -T - --ignore-failed-read -cf - | tar -xf - -C "$work/src"

say "building the wheel"
"$PYTHON" -m pip wheel -q --no-deps --wheel-dir "$work/dist" "$work/src"
wheel=$(echo "$work"/dist/conflictbench-*.whl)

# 2. Every file under conflictbench/, conf/ (installed as conflictbench/conf/) and hydra_plugins/ (our Ray
#    launcher, in Hydra's namespace for plugins) is in the wheel.
"$PYTHON" - "$work/src" "$wheel" <<'EOF'
import sys
import zipfile
from pathlib import Path

src, wheel = Path(sys.argv[1]), sys.argv[2]
roots = {"conflictbench": "conflictbench", "conf": "conflictbench/conf", "hydra_plugins": "hydra_plugins"}
want = {f"{dest}/{p.relative_to(src / root).as_posix()}"
        for root, dest in roots.items() for p in (src / root).rglob("*") if p.is_file()}
missing = sorted(want - set(zipfile.ZipFile(wheel).namelist()))
if missing:
    sys.exit(f"[check_wheel] the wheel lacks {len(missing)} files of the package: {', '.join(missing)}")
print(f"[check_wheel] the wheel holds all {len(want)} files of the package and its config tree", file=sys.stderr)
EOF

# 3. A fresh environment with the wheel and the test tools, no simulator; a directory that is not
#    the checkout (the checkout's tests/ is on sys.path, its root is not: they test the wheel).
"$PYTHON" -m venv "$work/venv"
py=$work/venv/bin/python
mkdir "$work/run"
cd "$work/run"
say "installing the wheel with the test tools, without the simulator"
uv=$repo/.venv/bin/uv
install() {  # through set-up's uv where there is one (it links from its cache), else pip
  if [ -x "$uv" ]; then "$uv" pip install -q --python "$py" "$@"; else "$py" -m pip install -q "$@"; fi
}
uninstall() {
  if [ -x "$uv" ]; then "$uv" pip uninstall -q --python "$py" "$@"; else "$py" -m pip uninstall -q -y "$@"; fi
}
install "$wheel[test]"
if "$py" -c 'import libero' 2>/dev/null; then
  say "the simulator got installed without the sim extra"; exit 1
fi
say "the packaging tests against the installed wheel, no simulator"
# What only a packaging fault breaks: the config tree as package data, the public API's import paths, plugin
# discovery, what imports without the simulator. The console script, the viewer's assets and the subject's weights
# are checked below by using them (a real run, its site); the rest of these files' tests the default selection has.
packaging=(test_config.py test_cli_imports.py test_core_plugins.py test_public_api.py)
"$py" -m pytest -c "$repo/pyproject.toml" --rootdir "$repo" -m "not sim" -q "${packaging[@]/#/$repo/tests/}"

# 4. The simulator added: the command lists what it has and plays real episodes with the default model (the
#    learned subject, from the weights inside the wheel).
say "adding the simulator"
install "$wheel[sim]"
"$work/venv/bin/conflictbench" list
status=0
"$work/venv/bin/conflictbench" suite=physical level=L1 prompt=p0 run.init_states=1 \
  run.cases_per_cell=1 run.libero_suites=[libero_spatial] run.progress=false 2>"$work/run.log" || status=$?
cat "$work/run.log" >&2
[ "$status" -eq 0 ] || { say "the run exited with code $status"; exit 1; }
grep -q "2 played, 0 already stored, 0 played by another job, 0 with errors" "$work/run.log" \
  || { say "the run did not play its two episodes cleanly"; exit 1; }
# 5. The viewer from the wheel: its page assets are packaged, and videos encode with the sim extra's PyAV.
"$work/venv/bin/conflictbench" view results --no-progress >"$work/view.log" || { cat "$work/view.log" >&2; exit 1; }
cat "$work/view.log" >&2
grep -q "1 pair page, 1 reference episode page, 2 videos rendered" "$work/view.log" && [ -s results/view/assets/viewer.js ] \
  || { say "the viewer did not write its site with both videos"; exit 1; }

# 5b. new-plugin from the wheel: its template is package data, so a plugin is written from it, every file of it.
"$work/venv/bin/conflictbench" new-plugin x --protocol rest --dir "$work/new-plugin" >"$work/new-plugin.log" \
  || { say "new-plugin failed from the wheel"; exit 1; }
want=$("$py" -c 'from conflictbench.cli.new_plugin import FILES; print(len(FILES))')
[ "$(wc -l <"$work/new-plugin.log")" -eq "$want" ] && "$py" -m py_compile "$work"/new-plugin/x/conflictbench_x/*.py \
  || { say "new-plugin did not write the $want files of its template from the wheel"; exit 1; }
say "new-plugin wrote a plugin of $want files from the wheel's template"

# 6. doctor from the wheel: its goldens are packaged, and this environment (not the one that made them) replays
#    them as the reference simulator (exit 0: physics within tolerance, rendering identical or another renderer's).
"$work/venv/bin/conflictbench" doctor || { say "doctor says this simulator is not the reference one"; exit 1; }

# 7. Every module of the installed wheel imports, in this environment of exactly what the wheel declares: its
#    requirements and extras (sim and test above; the protocols' now, with conflictbench-serving, which their
#    extras require and which is not on PyPI). pkgutil walks the package; without its extra a protocol module would
#    name it in one line (tests/test_module_imports.py checks that); here every one must import.
say "every module of the wheel, with its extras"
install "$work/src/serving" "$wheel[openpi,zeromq,rest,openvla-family]"
"$py" "$repo/tests/import_every_module.py" --strict >"$work/imports.jsonl" \
  || { say "a module of the wheel does not import with what the wheel declares"; exit 1; }
"$py" - "$work/imports.jsonl" <<'PY'
import collections
import json
import sys

said = [json.loads(line) for line in open(sys.argv[1])]
counts = collections.Counter(s["outcome"] for s in said)
exempt = ", ".join(s["module"] for s in said if s["outcome"] == "exempt")
print(f"[check_wheel] all {counts['ok']} modules of the wheel import with its extras"
      + (f" (not imported: {exempt}, another environment's script)" if exempt else ""), file=sys.stderr)
PY

# 8. Each model plugin as a user installs it (not editable), alone beside the wheel and the server half: a plugin
#    needs conflictbench (with its protocol's extra) and conflictbench-serving, never another plugin (pip brings
#    none, and it loads alone).
say "each model plugin alone, not editable"
for plugin in "$work"/src/plugins/*/; do
  dist=$(sed -n 's/^name = "\(.*\)"$/\1/p' "$plugin/pyproject.toml" | head -n 1)
  install "$plugin"
  "$py" - "$dist" <<'PY'
import importlib.metadata as metadata
import sys

import conflictbench

dist = sys.argv[1]
ours = sorted(d.name for d in metadata.distributions() if d.name.startswith("conflictbench-"))
if ours != sorted({"conflictbench-serving", dist}):
    sys.exit(f"[check_wheel] installing {dist} alone brought {ours}")
plugins = conflictbench.plugins()
if plugins.load_failures:
    sys.exit(f"[check_wheel] {dist} alone fails to load: {plugins.load_failures}")
mine = [name for name, spec in plugins.policies().items() if spec.plugin == dist]
if not mine:
    sys.exit(f"[check_wheel] {dist} alone registers no policy")
print(f"[check_wheel] {dist} alone: {', '.join(mine)}", file=sys.stderr)
PY
  uninstall "$dist"
done

# 9. Each plugin's server half built as a wheel from the clean copy (its package lives beside it, ../conflictbench_X):
#    the whole package with its server modules, the entry point conflictbench-serve finds, and no requirement of
#    conflictbench. Installing it means its model's stack (torch, LeRobot): the model environments' build does that.
#    Built by this Python whatever the half requires (the LeRobot ones, 3.12): a wheel is only read here.
say "each model plugin's server half, as a wheel"
for server in "$work"/src/plugins/*/server/; do
  "$PYTHON" -m pip wheel -q --no-deps --ignore-requires-python --wheel-dir "$work/servers" "$server"
done
"$PYTHON" - "$work/servers" "$work/src/plugins" <<'PY'
import sys
import zipfile
from email.parser import Parser
from pathlib import Path

wheels, plugins = Path(sys.argv[1]), Path(sys.argv[2])
for source in sorted(plugins.glob("*/server")):
    package = next(source.parent.glob("conflictbench_*/server.py")).parent
    wheel = next(wheels.glob(f"{package.name}_server-*.whl"), None)
    if wheel is None:
        sys.exit(f"[check_wheel] no wheel for {source}")
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = {f"{package.name}/{p.relative_to(package)}" for p in package.rglob("*.py")} - names
    info = next(n for n in names if n.endswith(".dist-info/METADATA")).rpartition("/")[0]
    metadata = Parser().parsestr(zipfile.ZipFile(wheel).read(f"{info}/METADATA").decode())
    requires = [r.split(";")[0].split("[")[0].split("=")[0].split("<")[0].split(">")[0].strip().lower()
                for r in metadata.get_all("Requires-Dist", [])]
    points = zipfile.ZipFile(wheel).read(f"{info}/entry_points.txt").decode()
    if missing or "conflictbench" in requires or "[conflictbench_serving]" not in points:
        sys.exit(f"[check_wheel] {wheel.name}: missing {sorted(missing)}, requires {requires}, entry points {points!r}")
    print(f"[check_wheel] {wheel.name}: {len(names)} files, requires {len(requires)}, no conflictbench", file=sys.stderr)
PY
say "ok: the installed wheel passes the tests without a simulator, lists its plugins, plays real episodes and shows" \
  "them, imports every module with its extras, each model plugin installs and loads alone, and each server half" \
  "builds whole without conflictbench"
