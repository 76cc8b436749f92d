"""Observations as a simulator worker sends them, and actions pinned bit for bit (no simulator needed)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..core import Observation

#: Set to 1 to (re)write the golden files :func:`check_pinned_actions` compares with.
RECORD_PINNED_ACTIONS = "CONFLICTBENCH_RECORD_ACTIONS"


def camera_observation(
    step: int = 0, instruction: str = "put the bowl on the plate", stream: int = 0, suite: str = "libero_goal"
) -> Observation:
    """An observation as a worker sends it to a policy that looks: two random 256-px renders (fixed by ``step``),
    a plausible 8-D state whose gripper fingers differ, episode ``episode-{stream}`` of ``suite`` on stream
    ``stream``."""
    rng = np.random.default_rng(step)
    state = np.array([0.1, 0.2, 1.0, 3.1, 0.1, -0.2, 0.04, -0.03])
    return Observation(
        step=step, instruction=instruction, eef_pos=state[:3], eef_quat=np.array([0, 0, 0, 1.0]),
        gripper_qpos=state[6:], state=state, stream=stream, episode_id=f"episode-{stream}", suite=suite,
        agentview_image=rng.integers(0, 256, (256, 256, 3), dtype=np.uint8),
        wrist_image=rng.integers(0, 256, (256, 256, 3), dtype=np.uint8),
    )  # fmt: skip


def pinned_observations(steps: int = 6) -> list[Observation]:
    """Two episodes of ``steps`` steps on streams 0 and 1 (other instructions, other sampling seeds), step by
    step in turn, as two workers would send them: the fixed input :func:`check_pinned_actions` plays."""
    texts = ("put the bowl on the plate", "open the top drawer and put the bowl inside")
    return [camera_observation(step, texts[stream], stream=stream) for step in range(steps) for stream in (0, 1)]


def check_pinned_actions(policy, golden: Path, fingerprint: str = "") -> None:
    """Play :func:`pinned_observations` through ``policy`` (started; one ``act`` at a time, so no batch shape or
    arrival order enters) and compare every action bit for bit with the file ``golden``. ``fingerprint`` names
    what the actions come from (a tiny checkpoint's digest): a different one there means the fixture changed,
    not the code. With ``CONFLICTBENCH_RECORD_ACTIONS=1`` in the environment the file is written instead."""
    actions = [np.asarray(policy.act(observation)) for observation in pinned_observations()]
    if os.environ.get(RECORD_PINNED_ACTIONS) == "1":
        golden.parent.mkdir(parents=True, exist_ok=True)
        np.savez(golden, fingerprint=np.array(fingerprint), **{f"action{i}": a for i, a in enumerate(actions)})
        return
    pinned = np.load(golden)
    assert str(pinned["fingerprint"]) == fingerprint, f"the fixture behind {golden.name} changed: re-record it"
    assert len(pinned.files) - 1 == len(actions)
    for i, action in enumerate(actions):
        expected = pinned[f"action{i}"]
        assert action.dtype == expected.dtype and action.shape == expected.shape, (i, action.shape, expected.shape)
        assert action.tobytes() == expected.tobytes(), f"action {i} differs from {golden.name}:\n{action}\n{expected}"
