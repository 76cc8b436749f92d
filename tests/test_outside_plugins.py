"""The tests hold whatever else a user has installed beside conflictbench: with a third-party plugin installed (the
demo plugin, a real distribution found by its entry points: a metric, a policy, global hooks), the tests whose
expectations name what is registered run again and pass. No plugin is switched off for the tests."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

#: It plays again tests the default selection plays (20 s): marked by that cost, it runs in CI's marked lane.
pytestmark = pytest.mark.e2e

HERE = Path(__file__).parent
#: The tests that read what is registered (metrics on the pair pages, the policies a bad model= lists, the global
#: hooks left when one plugin is disabled), by node id.
REGISTRY_READERS = [
    "test_view_site.py::test_one_page_per_pair_with_its_texts_measures_and_plot_data",
    "test_view_site.py::test_each_page_and_index_row_belongs_to_its_own_pair",
    "test_core_plugins.py::test_a_disabled_plugin_is_not_imported_and_leaves_the_identity",
    "test_cli.py::test_bad_input_is_one_clear_line_and_exit_code_2[args0-message0]",  # model=nope
]


def test_the_tests_that_read_the_registry_pass_with_a_third_party_plugin_installed(demo_plugin_site, tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(demo_plugin_site), os.environ.get("PYTHONPATH", "")])}
    seen = subprocess.run(
        [sys.executable, "-c", "import conflictbench; p = conflictbench.plugins(); print(*p.metrics(), *p.policies())"],
        env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert {"demo_path_ratio", "demo-wave"} <= set(seen.stdout.split()), seen.stdout + seen.stderr
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:randomly", "-W", "ignore::DeprecationWarning",
         *(str(HERE / node) for node in REGISTRY_READERS),
         "--basetemp", str(tmp_path / "inner")],
        env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0 and "4 passed" in done.stdout, done.stdout[-3000:] + done.stderr[-3000:]
