"""Real checkpoints, where a machine has them: skipped with the reason unless the variables below name one.

- ``CONFLICTBENCH_OPENVLA_CHECKPOINT``: an OpenVLA LIBERO checkpoint folder (e.g. a download of
  ``openvla/openvla-7b-finetuned-libero-goal``), served by ``model.checkpoint=DIR`` (a GPU: ``model.device=cuda``);
- ``CONFLICTBENCH_OPENVLA_SERVER``: the URL of OpenVLA's own ``deploy.py`` hosting one;
- ``CONFLICTBENCH_OFT_SERVER``: the URL of OpenVLA-OFT's ``deploy.py`` (``--num_images_in_input 2 --unnorm_key``);
- ``CONFLICTBENCH_OPENVLA_SUITE``: the LIBERO suite of those checkpoints (default ``libero_goal``).

Each plays the suite's ten reference episodes at the first initial state and expects most to succeed (OpenVLA's
published LIBERO rates are 53.7 to 88.4 %, OFT's about 97 %): a pipeline step done wrong shows as a collapse.
"""

from __future__ import annotations

import os

import pytest

from conflictbench.store import EpisodeStore
from conflictbench.testing import episode_counts, run_cli

pytestmark = [pytest.mark.sim, pytest.mark.slow]
SUITE = os.environ.get("CONFLICTBENCH_OPENVLA_SUITE", "libero_goal")
SETTINGS = {
    "openvla-checkpoint": (
        "CONFLICTBENCH_OPENVLA_CHECKPOINT",
        ["model=openvla", "model.checkpoint={}", "model.device=cuda"],
    ),
    "openvla-deploy": ("CONFLICTBENCH_OPENVLA_SERVER", ["model=openvla", "model.server={}", "model.checkpoint=real"]),
    "oft-deploy": ("CONFLICTBENCH_OFT_SERVER", ["model=openvla-oft", "model.server={}", "model.checkpoint=real"]),
}


@pytest.mark.parametrize("case", sorted(SETTINGS))
def test_a_real_checkpoint_succeeds_on_most_reference_episodes(tmp_path, case):
    variable, settings = SETTINGS[case]
    value = os.environ.get(variable)
    if not value:
        pytest.skip(f"{variable} is not set: no real {case.split('-')[0]} weights on this machine")
    references = ["run.cases_per_cell=0", f"run.libero_suites=[{SUITE}]", "suite=all", "level=all"]
    out = run_cli(tmp_path, *(s.format(value) for s in settings), *references, timeout=7200)
    assert out.returncode == 0, out.stderr[-3000:]
    played, _, errors = episode_counts(out.stderr)
    assert played == 10 and errors == 0
    successes = sum(record.success for record in EpisodeStore(tmp_path / "results").records())
    assert successes >= 5, f"{successes}/10 reference episodes succeeded"
