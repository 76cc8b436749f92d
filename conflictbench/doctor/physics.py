"""The physics check: the replayed end-effector paths and success states against the goldens'."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from conflictbench.sim.replay import path_deviation

from .checks import Check
from .goldens import Goldens
from .replaying import Replayed

#: The largest end-effector path deviation (metres) that still counts as the reference physics; every success step
#: must be equal as well. Measured with scripts/doctor_tolerance.py (2-core development machine, the four golden
#: episodes replayed camera-less against the py3.11-mujoco2.3.7 goldens; solver defaults: 100 iterations, tolerance
#: 1e-8, timestep 0.002):
#:   perturbation                          max deviation   success steps changed
#:   none (the same stack again)           0 m             0/4
#:   initial qpos 1 ulp off (qpos_ulp=1)   3.6e-3 m        0/4   (goal episode; spatial 1e-15, object 1.4e-7)
#:   solver iterations 50                  0 m             0/4   (the solver converges sooner)
#:   solver tolerance 1e-4                 2.6e-3 m        1/4   (libero_10 never solved)
#:   solver iterations 5                   3.6e-2 m        3/4
#:   timestep 0.0021                       4.1e-2 m        4/4
#:   MuJoCo 3.3.2 replaying these goldens  2.8e-2 m        1/4   (libero_goal never solved)
#: A last-bit change (another CPU's rounding, in effect) grows to millimetres in a contact-rich episode without
#: changing its behaviour, so a path alone cannot tell rounding from another simulator below ~4 mm; behaviour changes
#: show in the success steps (solver tolerance 1e-4 moves paths less than one ulp does, and loses an episode). 1 cm
#: keeps ~3x the rounding's deviation as margin and is exceeded by every perturbation that changes behaviour here.
TOLERANCE_M = 1e-2


@dataclass(frozen=True)
class PathComparison:
    episode: str
    cameras: bool
    deviation_m: float | None  # None: it could not be replayed
    success_state: int | None
    golden_success_state: int | None
    error: str | None = None

    @property
    def label(self) -> str:
        return f"{self.episode} {'with' if self.cameras else 'without'} cameras"


def compare(replayed: Replayed, golden_path: np.ndarray, golden_success_state: int | None) -> PathComparison:
    deviation = None if replayed.path is None else path_deviation(replayed.path, golden_path)
    return PathComparison(
        replayed.name, replayed.cameras, deviation, replayed.success_state, golden_success_state, replayed.error
    )


def compare_all(replays: Sequence[Replayed], goldens: Goldens) -> list[PathComparison]:
    success = {episode.name: episode.success_state for episode in goldens.episodes}
    return [compare(r, goldens.eef_pos[r.name], success[r.name]) for r in replays]


def physics_passes(max_deviation_m: float, success_states_equal: bool, tolerance_m: float = TOLERANCE_M) -> bool:
    """The reference physics: every path within the tolerance, and every episode solved at the goldens' state."""
    return success_states_equal and max_deviation_m <= tolerance_m


def physics_check(comparisons: Sequence[PathComparison], against: str, tolerance_m: float = TOLERANCE_M) -> Check:
    failed = [c for c in comparisons if c.deviation_m is None]
    if failed:
        return Check("physics", False, f"{failed[0].label} could not be replayed: {failed[0].error}")
    deviation = max((c.deviation_m for c in comparisons), default=0.0)
    unequal = [c for c in comparisons if c.success_state != c.golden_success_state]
    episodes = len({c.episode for c in comparisons})
    exact = " (bit-identical)" if deviation == 0 else ""
    text = (
        f"max path deviation {deviation:.3g} m{exact} (tolerance {tolerance_m:g} m) over {len(comparisons)} replays of "
        f"{episodes} golden episodes with and without cameras; success steps equal "
        f"{len(comparisons) - len(unequal)}/{len(comparisons)}"
    )
    if unequal:
        c = unequal[0]
        text += f" ({c.label}: {_state(c.success_state)}, golden {_state(c.golden_success_state)})"
    elif deviation > tolerance_m:
        worst = max(comparisons, key=lambda c: c.deviation_m)
        text += f" ({worst.label} deviates most)"
    return Check("physics", physics_passes(deviation, not unequal, tolerance_m), f"{text}; {against}")


def _state(state: int | None) -> str:
    return "never solved" if state is None else f"solved at step {state}"
