"""scripts/link_identical.py: what setup.sh runs so the model environments share their identical files."""

import runpy
import stat
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "link_identical.py"
link_identical = runpy.run_path(str(SCRIPT))["link_identical"]


def write(path: Path, data: bytes, mode: int = 0o644) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    path.chmod(mode)
    return path


def test_identical_files_at_the_same_place_become_one_and_others_stay_apart(tmp_path):
    lib = "lib/python3.12/site-packages/torch/lib/libtorch.so"
    a = write(tmp_path / "pi0" / lib, b"x" * 5000)
    b = write(tmp_path / "gr00t" / lib, b"x" * 5000)
    c = write(tmp_path / "openvla" / lib, b"x" * 4999 + b"y")  # same size, other bytes
    moved = write(tmp_path / "univla" / "elsewhere.so", b"x" * 5000)  # same bytes, other path
    script_a = write(tmp_path / "pi0" / "bin/tool", b"#!/a/python\n", 0o755)
    script_b = write(tmp_path / "gr00t" / "bin/tool", b"#!/a/python\n", 0o644)  # other mode

    assert link_identical(tmp_path) == (1, 5000)
    assert a.samefile(b)
    assert not c.samefile(a) and c.read_bytes().endswith(b"y")
    assert not moved.samefile(a) and not script_a.samefile(script_b)
    assert stat.S_IMODE(script_b.stat().st_mode) == 0o644
    assert not list(tmp_path.rglob("*.conflictbench-link"))
    assert link_identical(tmp_path) == (0, 0)  # a second pass has nothing left to do


def test_a_reinstall_in_one_environment_leaves_the_other_as_it_was(tmp_path):
    lib = "lib/python3.12/site-packages/numpy/core.so"
    a = write(tmp_path / "pi0" / lib, b"1.26" * 1000)
    b = write(tmp_path / "openvla" / lib, b"1.26" * 1000)
    link_identical(tmp_path)
    b.unlink()  # what pip does on an upgrade: remove, then write anew
    write(b, b"2.20" * 1000)
    assert a.read_bytes() == b"1.26" * 1000
