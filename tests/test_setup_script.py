"""scripts/setup.sh speaks in [setup] lines only: the installers' words go to <venv>/setup.log, and a real failure
stops set-up with one line naming what failed, the installer's reason and the log.

The failures are real ones: uv offline with an empty cache cannot install anything, and an installed distribution
whose requirement is missing is what `uv pip check` reports. Set-up runs in a temporary environment, never .venv.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SETUP = ROOT / "scripts" / "setup.sh"
UV = Path(sys.executable).with_name("uv")

pytestmark = pytest.mark.skipif(not UV.exists(), reason="uv is not in this environment (scripts/setup.sh installs it)")


def _python312() -> str | None:
    candidates = [shutil.which("python3.12"), *sorted(Path.home().glob(".pyenv/versions/3.12*/bin/python3.12"))]
    for candidate in filter(None, candidates):
        done = subprocess.run([str(candidate), "-c", "import sys; print(sys.version_info[:2] == (3, 12))"],
                              capture_output=True, text=True)  # fmt: skip
        if done.stdout.strip() == "True":
            return str(candidate)
    return None


def _environment(tmp_path: Path) -> Path:
    """A bare virtual environment with this one's uv, as set-up leaves it after its first two steps."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    (venv / "bin" / "uv").symlink_to(UV)
    return venv


def _setup(
    venv: Path, tmp_path: Path, *args: str, offline: bool = True, extra: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    leaking = ("UV_", "PIP_", "VIRTUAL_ENV", "MODEL_PYTHON", "FORCE_COLOR", "CLICOLOR_FORCE", "NO_COLOR")
    env = {k: v for k, v in os.environ.items() if not k.startswith(leaking)}  # the developer's shell's settings
    env.update(VENV=str(venv), PYTHON=sys.executable)
    if offline:  # nothing can be fetched and nothing is cached: every install fails, as without a network
        env.update(UV_OFFLINE="1", UV_CACHE_DIR=str(tmp_path / "empty-cache"))
    env.update(extra or {})
    return subprocess.run(["bash", str(SETUP), *args], capture_output=True, text=True, env=env, timeout=600)


def _stamp_main_job(venv: Path, plugins: tuple[str, ...] = ()) -> None:
    """Mark the main job (and these plugins' clients) installed, so set-up goes on to what follows."""
    (venv / ".conflictbench-installed").write_text("sim\n")
    if plugins:
        (venv / ".conflictbench-serving").touch()
    for name in plugins:
        (venv / f".conflictbench-plugin-{name}").write_text("\n")


def _one_failure_line(done: subprocess.CompletedProcess[str], what: str) -> str:
    lines = done.stderr.splitlines()
    assert done.returncode == 1, done.stderr
    assert done.stdout == "" and all(line.startswith("[setup] ") for line in lines), done.stderr
    failure = lines[-1]
    assert failure.startswith(f"[setup] failed: {what}: "), failure
    assert sum(line.startswith("[setup] failed") for line in lines) == 1
    return failure


@pytest.mark.parametrize("colour", [{}, {"FORCE_COLOR": "1", "CLICOLOR_FORCE": "1"}], ids=["plain", "forced-colour"])
def test_a_failing_install_stops_set_up_with_one_line_and_leaves_the_installers_words_in_the_log(tmp_path, colour):
    venv = _environment(tmp_path)
    done = _setup(venv, tmp_path, extra=colour)
    failure = _one_failure_line(done, "installing conflictbench [sim]")
    log = venv / "setup.log"
    assert failure.endswith(f"(all of it: {log})")
    reason = failure.removeprefix("[setup] failed: installing conflictbench [sim]: ").removesuffix(
        f" (all of it: {log})"
    )
    text = log.read_text()
    assert "uv --color never pip install --python" in text and reason and reason in text, text
    assert reason.startswith(("cause:", "Caused by:", "error:")), reason  # uv's reason, not its closing words
    assert not (venv / ".conflictbench-installed").exists()  # nothing is marked done that was not


def test_a_failure_without_a_cause_line_still_gets_its_one_line(tmp_path):
    """An environment without pip cannot install uv: Python's own one-line complaint is the reason."""
    venv = _environment(tmp_path)
    (venv / "bin" / "uv").unlink()
    failure = _one_failure_line(_setup(venv, tmp_path), "installing uv with pip")
    assert "No module named pip" in failure and failure.endswith(f"(all of it: {venv / 'setup.log'})")


def test_a_model_environment_that_fails_to_build_stops_set_up_and_is_not_marked_built(tmp_path):
    model_python = _python312()
    if model_python is None:
        pytest.skip("no Python 3.12 here for a model environment")
    venv = _environment(tmp_path)
    _stamp_main_job(venv, plugins=("univla",))
    done = _setup(venv, tmp_path, "--models", "univla")
    env_dir = venv / "models" / "univla"
    _one_failure_line(done, f"installing the univla server half into {env_dir}")
    assert (env_dir / "bin" / "python").exists()  # it got that far
    assert not (env_dir / ".conflictbench-installed").exists()  # and a run will not take it for built
    assert "ready" not in done.stderr


@pytest.mark.parametrize("colour", [{}, {"FORCE_COLOR": "1", "CLICOLOR_FORCE": "1"}], ids=["plain", "forced-colour"])
def test_an_unmet_requirement_in_an_environment_stops_set_up(tmp_path, colour):
    venv = _environment(tmp_path)
    _stamp_main_job(venv)
    site = next((venv / "lib").glob("python3.*/site-packages"))
    info = site / "needs_more-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: needs-more\nVersion: 1.0\nRequires-Dist: nothing-such\n"
    )
    (info / "RECORD").write_text("")
    done = _setup(venv, tmp_path, extra=colour)  # uv colours its words where asked: they are read all the same
    assert _one_failure_line(done, f"{venv} has an unmet requirement") == (
        f"[setup] failed: {venv} has an unmet requirement: The package `needs-more` requires `nothing-such`, but it's "
        f"not installed (all of it: {venv / 'setup.log'})"
    )
    assert "requires `nothing-such`" in (venv / "setup.log").read_text()
    shutil.rmtree(info)
    done = _setup(venv, tmp_path, extra=colour)
    assert done.returncode == 0 and done.stderr.splitlines()[-1] == f"[setup] ready: {venv}/bin/conflictbench"
    assert "failed" not in done.stderr


@pytest.mark.slow
def test_a_whole_set_up_says_only_its_own_lines_and_the_model_environment_hosts_without_conflictbench(tmp_path):
    """From uv's cache (the real set-up filled it): the main job and UniVLA's model environment, whose server half
    brings everything its server needs and nothing of conflictbench, every requirement met."""
    model_python = _python312()
    if model_python is None:
        pytest.skip("no Python 3.12 here for a model environment")
    venv = _environment(tmp_path)
    done = _setup(venv, tmp_path, "--models", "univla", offline=False)
    assert done.returncode == 0, (venv / "setup.log").read_text()[-3000:]
    lines = done.stderr.splitlines()
    assert done.stdout == "" and all(line.startswith("[setup] ") for line in lines), done.stderr
    assert lines[-1] == f"[setup] ready: {venv}/bin/conflictbench"
    assert not any("failed" in line or "error" in line.lower() for line in lines), done.stderr
    python = venv / "models" / "univla" / "bin" / "python"
    probe = (
        "import importlib.util, importlib.metadata as m; from conflictbench_serving.command import served_model; "
        "print(served_model('univla').environment, importlib.util.find_spec('conflictbench') is None, "
        "sorted(d.name for d in m.distributions() if d.name.startswith('conflictbench')))"
    )
    # From elsewhere than the checkout, whose conflictbench/ `python -c` would find in its working directory.
    done = subprocess.run([str(python), "-c", probe], capture_output=True, text=True, check=True, cwd=tmp_path)
    shown = done.stdout.split(maxsplit=2)
    assert shown == ["univla", "True", "['conflictbench-serving', 'conflictbench-univla-server']\n"]
