"""openpi's own server (``openpi-server`` from PyPI, unchanged) hosting a numpy stand-in policy.

The client tests talk to it: the server is upstream's, so what our client sends and reads is checked
against the real protocol, not against our own server. The stand-in's actions are a fixed function of
every field of the request (``actions_for``), so a test can tell that each arrived intact.

    python numpy_openpi_server.py PORT [--policy-type pi0] [--fail-on TEXT]
"""

from __future__ import annotations

import argparse

import numpy as np

CHUNK = 10  # pi0.5's LIBERO action horizon
FAIL_PROMPT = "raise an error"


def actions_for(request: dict) -> np.ndarray:
    image = request["observation/image"].astype(np.float64)
    wrist = request["observation/wrist_image"].astype(np.float64)
    state = np.asarray(request["observation/state"], dtype=np.float64)
    features = np.array(
        [
            image[:112].mean() - image[112:].mean(),  # which way up the image is
            wrist[:, :112].mean() - wrist[:, 112:].mean(),
            state.sum(),
            state[7] - state[6],
            len(request["prompt"]),
            request.get("conflictbench/noise_seed", 0) % 1000,
            image.mean(),
        ]
    )
    return np.stack([features * (step + 1) for step in range(CHUNK)]).astype(np.float32)


class StandInPolicy:
    def __init__(self, fail_on: str | None = None):
        self.fail_on = fail_on

    def infer(self, obs: dict) -> dict:
        if obs["prompt"] == FAIL_PROMPT or (self.fail_on and self.fail_on in obs["prompt"]):
            raise RuntimeError("the model failed on purpose")
        received = {
            key: [str(value.dtype), list(value.shape)] if isinstance(value, np.ndarray) else type(value).__name__
            for key, value in obs.items()
        }
        return {"actions": actions_for(obs), "received": received}


def main() -> None:
    from openpi_server.websocket_policy_server import WebsocketPolicyServer

    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("--policy-type", help="sent as the metadata's policy_type, as our server does")
    parser.add_argument("--fail-on", help="fail every request whose prompt contains this text")
    args = parser.parse_args()
    metadata = {"policy_type": args.policy_type} if args.policy_type else {}
    server = WebsocketPolicyServer(StandInPolicy(args.fail_on), host="127.0.0.1", port=args.port, metadata=metadata)
    server.serve_forever()


if __name__ == "__main__":
    main()
