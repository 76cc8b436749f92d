"""The oracle: the ideal response to a premise conflict, as a calibration point for the metrics."""

from __future__ import annotations

import numpy as np

from conflictbench.core import Observation

from .control import OPEN
from .policy import ScriptedPolicy

STILL = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, OPEN])
"""Zero motion, gripper open: what the oracle does for a whole conflict episode."""


class OraclePolicy(ScriptedPolicy):
    """`scripted` on reference episodes; perfectly still on conflict episodes.

    It learns that the premise is invalid from the episode's case metadata
    (``observation.privileged.case`` is set only on conflict episodes), never from the text, so
    its expected measures are RGSR = 0, AMS = 1 and TAR = 0.
    """

    def act(self, observation: Observation) -> np.ndarray:
        if observation.privileged is not None and observation.privileged.case is not None:
            return STILL.copy()
        return super().act(observation)
