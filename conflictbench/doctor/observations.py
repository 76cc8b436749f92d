"""An observation as a simulator worker sends it to a policy that looks, made without a simulator: what
``conflictbench doctor model=NAME`` sends the model, and what the tests' pinned observations
(``conflictbench.testing.observations``) are made of. Runtime code, so it needs nothing of the tests (no pytest)."""

from __future__ import annotations

import numpy as np

from ..core import Observation


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
        # The raw robot state LeRobot's LIBERO env also reports: fixed (no draw, so the images stay as they were).
        eef_mat=np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),
        joint_positions=np.array([0.0, 0.2, 0.0, -2.4, 0.0, 2.6, 0.8]), joint_velocities=np.full(7, 0.01 * step),
        gripper_qvel=np.array([0.001, -0.001]),
    )  # fmt: skip
