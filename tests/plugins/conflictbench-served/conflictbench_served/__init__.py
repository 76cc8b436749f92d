"""A model plugin whose model runs behind a server, written as the eight VLA plugins are:
the shared client (``PolicyClient``, ``ServedPolicy``) does the connection work; this module only
says what a request holds and how to read the reply (tests/policy_server.py serves it)."""

from dataclasses import dataclass

import numpy as np

from conflictbench import PolicyClient, ServedPolicy, ServingConfig, hookimpl

SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")


@dataclass
class ServedTestConfig(ServingConfig):
    server: str = "http://127.0.0.1:8000/act"
    connect_retries: int = 2
    backoff_s: float = 0.2
    steps: int = 10
    """Policy steps per episode (short runs)."""


class ServedTestPolicy(ServedPolicy):
    needs_images = False

    def __init__(self, cfg: ServedTestConfig):
        super().__init__(PolicyClient.from_config(cfg))
        self.max_steps = {suite: cfg.steps for suite in SUITES}

    def encode(self, observation):
        return {
            "step": observation.step,
            "state": observation.state,
            "instruction": observation.instruction,
            "stream": observation.stream,
        }

    def decode(self, reply, observation):
        return np.asarray(reply["action"], dtype=np.float64)


@hookimpl
def conflictbench_register_policies(register):
    register("served-test", load=ServedTestPolicy, config=ServedTestConfig)
