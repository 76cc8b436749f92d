#!/usr/bin/env bash
# One-step install of conflictbench into ./.venv: system rendering libraries, a Python 3.11/3.12
# virtual environment, the package with the pinned LIBERO simulator, and the test tools.
# Safe to run again: it only does what is missing.
#
#   PYTHON=python3.12 scripts/setup.sh    choose the interpreter (default: python3.11, else python3.12)
#   VENV=/path/to/venv scripts/setup.sh   choose where the environment goes (default: .venv)
set -euo pipefail

cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
APT_PACKAGES=(libegl1 libegl-mesa0 libgl1-mesa-dri)

say() { printf '[setup] %s\n' "$*" >&2; }

# 1. Mesa's EGL for headless rendering (only camera-based policies render; the rest run without GL).
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
  if ! command -v apt-get >/dev/null; then
    say "please install the EGL/Mesa libraries for your system (Debian names: ${missing[*]})"
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
  "$VENV/bin/python" -m pip install -q -e ".[sim,test]"
  touch "$stamp"
fi
say "ready: $VENV/bin/conflictbench"
