"""Observations as a simulator worker sends them, and actions pinned (no simulator needed): bit for bit on the
processor that recorded them, within a small tolerance on another."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np

from ..core import Observation
from ..doctor.observations import camera_observation  # runtime code too: doctor model= sends it

#: Set to 1 to (re)write the golden files :func:`check_pinned_actions` compares with.
RECORD_PINNED_ACTIONS = "CONFLICTBENCH_RECORD_ACTIONS"
#: How far another processor's actions may be from the pinned ones. Float kernels are picked by processor (MKL's,
#: oneDNN's), so one model's answers differ in the last digits across processors: between the machine that recorded
#: the goldens and an Intel Xeon with AMX, GR00T's tiny checkpoint differed by up to 7.3e-6 and UniVLA's by 3.5e-7,
#: the other five not at all. A change of code moves an action by orders of magnitude more.
OTHER_PROCESSOR_ATOL = 1e-4


def processor() -> str:
    """The processor's model name (Linux's /proc/cpuinfo), or the machine type where none is given."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    return next((line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")), platform.machine())


def pinned_observations(steps: int = 6) -> list[Observation]:
    """Two episodes of ``steps`` steps on streams 0 and 1 (other instructions, other sampling seeds), step by
    step in turn, as two workers would send them: the fixed input :func:`check_pinned_actions` plays."""
    texts = ("put the bowl on the plate", "open the top drawer and put the bowl inside")
    return [camera_observation(step, texts[stream], stream=stream) for step in range(steps) for stream in (0, 1)]


def check_pinned_actions(policy, golden: Path, fingerprint: str = "") -> None:
    """Play :func:`pinned_observations` through ``policy`` (started; one ``act`` at a time, so no batch shape or
    arrival order enters) and compare every action with the file ``golden``: bit for bit on the processor that
    recorded it, within :data:`OTHER_PROCESSOR_ATOL` on another (a file without its processor is another's).
    ``fingerprint`` names what the actions come from (a tiny checkpoint's digest): a different one there means the
    fixture changed, not the code. With ``CONFLICTBENCH_RECORD_ACTIONS=1`` in the environment the file is written
    instead."""
    actions = [np.asarray(policy.act(observation)) for observation in pinned_observations()]
    if os.environ.get(RECORD_PINNED_ACTIONS) == "1":
        golden.parent.mkdir(parents=True, exist_ok=True)
        recorded = {f"action{i}": a for i, a in enumerate(actions)}
        np.savez(golden, fingerprint=np.array(fingerprint), processor=np.array(processor()), **recorded)
        return
    pinned = np.load(golden)
    assert str(pinned["fingerprint"]) == fingerprint, f"the fixture behind {golden.name} changed: re-record it"
    expected_actions = [pinned[name] for name in sorted((n for n in pinned.files if n.startswith("action")),
                                                        key=lambda n: int(n.removeprefix("action")))]  # fmt: skip
    assert len(expected_actions) == len(actions)
    same_processor = "processor" in pinned.files and str(pinned["processor"]) == processor()
    deviations = []
    for i, (action, expected) in enumerate(zip(actions, expected_actions)):
        assert action.dtype == expected.dtype and action.shape == expected.shape, (i, action.shape, expected.shape)
        if same_processor:
            assert action.tobytes() == expected.tobytes(), (
                f"action {i} differs from {golden.name}:\n{action}\n{expected}"
            )
        deviations.append(float(np.max(np.abs(action.astype(np.float64) - expected))))
    worst = int(np.argmax(deviations))
    recorded_on = str(pinned["processor"]) if "processor" in pinned.files else "another processor"
    assert deviations[worst] <= OTHER_PROCESSOR_ATOL, (
        f"action {worst} is {deviations[worst]:.3g} from {golden.name} (recorded on {recorded_on}; "
        f"{OTHER_PROCESSOR_ATOL:g} allowed):\n{actions[worst]}\n{expected_actions[worst]}"
    )
    print(f"{golden.name}: every action within {deviations[worst]:.3g} of those recorded on {recorded_on}")


#: Real parts of a quaternion where an axis-angle conversion branches or clips: exactly +-1, just past +-1, just
#: below 1. The plugins' upstream tests feed each (with a tiny imaginary part) to their client and its restatement.
EDGE_QUATERNION_W = (
    1.0,
    -1.0,
    float(np.nextafter(1.0, 2.0)),
    -float(np.nextafter(1.0, 2.0)),
    float(np.nextafter(1.0, 0.0)),
)


def edge_quaternion(rng: np.random.Generator, w: float | None = None) -> np.ndarray:
    """(x, y, z, w): a random unit quaternion where ``w`` is None, else ``w`` with an imaginary part of order 1e-9."""
    if w is None:
        quat = rng.normal(size=4)
        return quat / np.linalg.norm(quat)
    return np.array([*(rng.normal(size=3) * 1e-9), w])


def worker_observation(
    raw: dict, instruction: str, *, suite: str, step: int = 0, episode_id: str = "e", sampling_key: str = ""
) -> Observation:
    """The observation a simulator worker makes of LIBERO's observation dict ``raw`` (``make_observation``, the run's
    own code), from a copy: an upstream client's quaternion conversion may clip ``raw``'s quaternion in place."""
    from ..sim.capture import make_observation  # the simulator's side: imported only where a test calls it

    return make_observation(
        {key: np.copy(value) for key, value in raw.items()},
        step=step, instruction=instruction, stream=0, episode_id=episode_id, suite=suite, images=True,
        privileged=None, sampling_key=sampling_key,
    )  # fmt: skip
