#!/usr/bin/env bash
# One-step install of conflictbench into ./.venv: system rendering libraries, a Python 3.11/3.12
# virtual environment, the package with the pinned LIBERO simulator, the test tools, the model
# plugins' clients (plugins/*), and each model plugin's model environment: a Python 3.12 environment
# at .venv/models/<plugin> holding the model's backend (LeRobot for pi0) and the plugin's server.
# Safe to run again: it only does what is missing or changed.
#
#   PYTHON=python3.12 scripts/setup.sh    choose the interpreter (default: python3.11, else python3.12)
#   VENV=/path/to/venv scripts/setup.sh   choose where the environment goes (default: .venv)
#   scripts/setup.sh --models pi0         build only these model environments (default: all; "none")
#   MODEL_PYTHON=python3.12 scripts/setup.sh   the model environments' interpreter (default: a 3.12)
set -euo pipefail

MODELS=all
while (($#)); do
  case "$1" in
    --models) MODELS=${2:?--models needs a list, e.g. --models pi0 (or all, none)}; shift 2 ;;
    --models=*) MODELS=${1#--models=}; shift ;;
    -h|--help) sed -n '2,13p' "$0"; exit 0 ;;
    *) echo "[setup] unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done

cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
APT_PACKAGES=(libegl1 libegl-mesa0 libgl1-mesa-dri chromium)

say() { printf '[setup] %s\n' "$*" >&2; }

# 1. Mesa's EGL for headless rendering (camera-based policies and the viewer's videos; the rest run without GL),
#    and Chromium, in which the tests open the viewer's pages.
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
  if ! command -v apt-get >/dev/null; then
    say "please install the EGL/Mesa libraries and Chromium for your system (Debian names: ${missing[*]})"
  else
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    say "installing ${missing[*]}"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  fi
fi

# 2. The interpreter: 3.11 or 3.12 (LIBERO's pinned stack needs numpy 1.26).
if [ -z "${PYTHON:-}" ]; then
  for candidate in python3.11 python3.12 python3; do
    # `command -v` is not enough: a pyenv shim exists even where its version is not selected.
    if "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] not in ((3, 11), (3, 12)))' 2>/dev/null; then
      PYTHON=$candidate
      break
    fi
  done
  PYTHON=${PYTHON:-python3}
fi
version=$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
case "$version" in
  3.11|3.12) ;;
  *) say "conflictbench needs Python 3.11 or 3.12; $PYTHON is $version (set PYTHON=...)"; exit 1 ;;
esac

# 3. The environment and the package (editable), with the simulator and test extras.
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV with $PYTHON ($version)"
  "$PYTHON" -m venv "$VENV"
fi
stamp="$VENV/.conflictbench-installed"
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  say "installing conflictbench with the LIBERO simulator (first time: about two minutes)"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e ".[sim,test,cluster]"
  touch "$stamp"
fi
# 4. The model plugins' clients, with the upstream counterparts their tests talk to; first the server half
#    they share (serving/: not on PyPI, so pip must find it installed before a plugin asks for it).
stamp="$VENV/.conflictbench-serving"
if [ ! -f "$stamp" ] || [ serving/pyproject.toml -nt "$stamp" ]; then
  "$VENV/bin/python" -m pip install -q -e serving
  touch "$stamp"
fi
for plugin in plugins/*/; do
  name=$(basename "$plugin")
  stamp="$VENV/.conflictbench-plugin-$name"
  if [ ! -f "$stamp" ] || [ "$plugin/pyproject.toml" -nt "$stamp" ]; then
    say "installing the $name plugin's client"
    "$VENV/bin/python" -m pip install -q -e "$plugin[test]"
    touch "$stamp"
  fi
done

# 5. Model environments: Python 3.12 (LeRobot needs >= 3.12 and numpy 2, which the simulator's stack
#    cannot share). Each gets the shared server half (serving/), its plugin without dependencies (no
#    conflictbench, no simulator), exactly the plugin's `server` extra (a plugin of ours named there from its
#    folder, without dependencies), and its `server-test` extra
#    without dependencies (upstream servers the tests compare with). About 5 GB and 90 s each on the first build
#    (torch); files identical across environments are then hard-linked, so all of them take about 9 GB.
has_server() {  # a plugin whose pyproject has a `server` extra has a model environment to build
  grep -q '^server = \[' "plugins/$1/pyproject.toml" 2>/dev/null
}
case "$MODELS" in
  none) MODELS="" ;;
  all) MODELS=$(for p in plugins/*/; do if has_server "$(basename "$p")"; then basename "$p"; fi; done) ;;
  *) MODELS=${MODELS//,/ } ;;
esac
if [ -n "$MODELS" ]; then
  if [ -z "${MODEL_PYTHON:-}" ]; then
    for candidate in python3.12 $(pyenv root 2>/dev/null)/versions/3.12*/bin/python3.12; do
      if "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' 2>/dev/null; then
        MODEL_PYTHON=$candidate
        break
      fi
    done
  fi
  if [ -z "${MODEL_PYTHON:-}" ]; then
    say "the model environments need Python 3.12 (set MODEL_PYTHON=...), or skip them: --models none"
    exit 1
  fi
  if ! "$MODEL_PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] < (3, 12))' 2>/dev/null; then
    say "MODEL_PYTHON=$MODEL_PYTHON is not a Python 3.12 or newer (LeRobot 0.6.1 needs it), or skip them: --models none"
    exit 1
  fi
fi
for name in $MODELS; do
  plugin=plugins/$name
  [ -f "$plugin/pyproject.toml" ] || { say "no model plugin $plugin (have: $(ls plugins))"; exit 2; }
  has_server "$name" || { say "the $name plugin has no server of its own (no model environment to build)"; exit 2; }
  env_dir="$VENV/models/$name"
  stamp="$env_dir/.conflictbench-installed"
  # What the environment is built from: serving/, the plugin, and any plugin of ours its server extra names.
  sources=(serving/pyproject.toml "$plugin/pyproject.toml")
  for other in plugins/*/; do
    other_name=conflictbench-$(basename "$other" | tr _ -)
    sed -n '/^server = \[/,/^\]/p' "$plugin/pyproject.toml" | grep -q "\"$other_name[<>=!~ \"]" &&
      sources+=("$other/pyproject.toml")
  done
  fresh=1
  for source in "${sources[@]}"; do
    [ -f "$stamp" ] && [ ! "$source" -nt "$stamp" ] || fresh=0
  done
  ((fresh)) && continue
  say "building the $name model environment in $env_dir with $MODEL_PYTHON (first time: a few minutes)"
  [ -x "$env_dir/bin/python" ] || "$MODEL_PYTHON" -m venv "$env_dir"
  "$env_dir/bin/python" -m pip install -q --upgrade pip
  "$env_dir/bin/python" -m pip install -q -e serving
  mapfile -t requirements < <("$env_dir/bin/python" - "$plugin/pyproject.toml" <<'EOF'
import re, sys, tomllib
project = tomllib.load(open(sys.argv[1], "rb"))["project"]
extra = project.get("optional-dependencies", {})
# Another plugin of ours named in the server extra (not on PyPI) is installed from its folder, first.
local = [r for r in extra.get("server", []) if re.match(r"conflictbench-(?!serving\b)", r)]
print("--no-deps", *("plugins/" + re.split(r"[<>=!~;\[ ]", r)[0][len("conflictbench-"):].replace("-", "_") for r in local))
print("\n".join(r for r in extra.get("server", []) if r not in local))
print("--no-deps", *extra.get("server-test", []))  # counterparts for the tests, without their pins
EOF
)
  read -ra locals <<<"${requirements[0]}"
  editable=()
  for local_plugin in "${locals[@]:1}"; do editable+=(-e "$local_plugin"); done
  ((${#editable[@]} == 0)) || "$env_dir/bin/python" -m pip install -q --no-deps "${editable[@]}"
  ((${#requirements[@]} < 3)) || "$env_dir/bin/python" -m pip install -q "${requirements[@]:1:${#requirements[@]}-2}"
  read -ra counterparts <<<"${requirements[-1]}"
  [ "${#counterparts[@]}" -le 1 ] || "$env_dir/bin/python" -m pip install -q "${counterparts[@]}"
  "$env_dir/bin/python" -m pip install -q --no-deps -e "$plugin"
  "$VENV/bin/python" scripts/link_identical.py "$VENV/models"  # the same torch in each: keep its files once
  touch "$stamp"
done
# 6. The learned subject's training environment (`conflictbench train-subject`): Python 3.12 with LeRobot's
#    dataset stack and PyTorch, pinned in the file below. Built with the model environments (not with --models none).
if [ -n "$MODELS" ]; then
  requirements=conflictbench/policies/subject/training-requirements.txt
  env_dir="$VENV/models/subject"
  stamp="$env_dir/.conflictbench-installed"
  if [ ! -f "$stamp" ] || [ "$requirements" -nt "$stamp" ]; then
    say "building the subject's training environment in $env_dir with $MODEL_PYTHON"
    [ -x "$env_dir/bin/python" ] || "$MODEL_PYTHON" -m venv "$env_dir"
    "$env_dir/bin/python" -m pip install -q --upgrade pip
    "$env_dir/bin/python" -m pip install -q -r "$requirements"
    "$VENV/bin/python" scripts/link_identical.py "$VENV/models"
    touch "$stamp"
  fi
fi
[ ! -d "$VENV/models" ] || "$VENV/bin/python" scripts/link_identical.py "$VENV/models"  # environments built before
say "ready: $VENV/bin/conflictbench"
