"""README's default-run time says on what machine and under what load it was measured (scripts/readme_figures.py)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "readme_figures.py"


def load_script():
    if str(SCRIPT.parent) not in sys.path:  # as when it runs: its folder, with readme_block.py, on the path
        sys.path.insert(0, str(SCRIPT.parent))
    spec = importlib.util.spec_from_file_location("readme_figures", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def fake_store(tmp_path: Path, tables) -> Path:
    (tmp_path / "report").mkdir()
    for name in tables:
        (tmp_path / "report" / f"{name}.md").write_text(f"### {name}\n")
    return tmp_path


def test_the_time_names_the_machine_and_its_load_and_the_check_ignores_them(tmp_path):
    figures = load_script()
    store = fake_store(tmp_path, figures.TABLES)
    text = figures.block(store, 698.0, load=1.63)
    line = next(line for line in text.splitlines() if "played in" in line)
    assert "played in 11 min 38 s on a" in line and "load average 1.6 when it started" in line
    assert figures.TIME.sub("", text) == figures.TIME.sub("", figures.block(store, None))


def test_readmes_correlations_bounds_and_power_are_what_the_measurements_give():
    import subprocess

    script = SCRIPT.parent / "readme_design.py"
    done = subprocess.run([sys.executable, str(script), "--check"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr


TABLE = """### Table 1

| model   | prompt   |   tasks |        PCSR |        TAR |
|:--------|:---------|--------:|------------:|-----------:|
| subject | p0       |      13 | 68.8 (11/16) | **75.2** (n=16) |
"""


def test_on_another_processor_the_check_compares_the_outcome_columns_alone(monkeypatch):
    """The subject's float kernels are the processor's: its episodes' outcomes stay and their paths do not, so a
    run elsewhere is held to README's outcome columns; on the recording processor, to every column."""
    figures = load_script()
    recorded = ", played in 3 min 5 s on a 2-core machine (Chip A, no GPU used, load average 0.1 when it started)"
    block = f"`conflictbench`, the default slice (29 episodes{recorded}):\n\n{TABLE}"
    elsewhere = block.replace("75.2", "71.9").replace("Chip A", "Chip B")
    monkeypatch.setattr(figures, "processor", lambda: "Chip B")
    same, note = figures.comparison(block)
    assert "played on Chip A, this is Chip B" in note
    assert same(block) == same(elsewhere) and "TAR" not in same(block) and "68.8 (11/16)" in same(block)
    assert same(block) != same(block.replace("68.8 (11/16)", "62.5 (10/16)"))  # an outcome is still held
    monkeypatch.setattr(figures, "processor", lambda: "Chip A")
    same, note = figures.comparison(block)
    assert note is None and same(block) != same(block.replace("75.2", "71.9"))
