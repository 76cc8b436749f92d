"""A GR00T server behaving as NVIDIA's ``PolicyServer`` (``gr00t/policy/server_client.py``), hosting a numpy stand-in.

NVIDIA's server cannot be installed here (it is not on PyPI), so this one restates its behaviour from the
source: a ZeroMQ REP socket; msgpack with ``np.save`` arrays, encoded here with msgpack and numpy directly
(not through our protocol module, so the client is checked against the format, not against itself); endpoint
``get_action`` by default; ``ping``, ``kill``, ``reset``, ``get_modality_config``; ``{"error": str}`` for an
unknown endpoint, a bad API token or any exception; observations checked as the sim wrapper checks them.
The stand-in's actions are a fixed function of every field of the observation and of ``options``
(:func:`actions_for`), so a test can tell that each arrived intact.

    python nvidia_standin_server.py PORT [--api-token T] [--fail-on TEXT] [--die-on TEXT] [--horizon 16]
"""

from __future__ import annotations

import argparse
import io
import os

import msgpack
import numpy as np
import zmq

VIDEO = ("video.image", "video.wrist_image")
STATE = ("state.x", "state.y", "state.z", "state.roll", "state.pitch", "state.yaw", "state.gripper")
LANGUAGE = "annotation.human.action.task_description"
ACTIONS = ("action.x", "action.y", "action.z", "action.roll", "action.pitch", "action.yaw", "action.gripper")


def to_bytes(obj) -> bytes:
    def encode(value):
        if isinstance(value, np.ndarray):
            buffer = io.BytesIO()
            np.save(buffer, value, allow_pickle=False)
            return {"__ndarray_class__": True, "as_npy": buffer.getvalue()}
        return value

    return msgpack.packb(obj, default=encode)


def from_bytes(data: bytes):
    def decode(obj):
        if "__ndarray_class__" in obj:
            return np.load(io.BytesIO(obj["as_npy"]), allow_pickle=False)
        return obj

    return msgpack.unpackb(data, object_hook=decode)


def check_observation(observation: dict) -> None:
    """What NVIDIA's sim wrapper asserts of an observation (keys, dtypes, ranks, one frame, a list of text)."""
    for key in VIDEO:
        value = observation[key]
        assert isinstance(value, np.ndarray) and value.dtype == np.uint8 and value.ndim == 5, key
        assert value.shape[1] == 1 and value.shape[-1] == 3, key
    for key in STATE:
        value = observation[key]
        assert isinstance(value, np.ndarray) and value.dtype == np.float32 and value.ndim == 3, key
        assert value.shape[1] == 1, key
    assert isinstance(observation[LANGUAGE], (list, tuple)) and isinstance(observation[LANGUAGE][0], str)


def features(observation: dict, options) -> np.ndarray:
    """Numbers that change with every field: which way up each image is, the state, the text, the seed."""
    image = observation["video.image"][0, 0].astype(np.float64)
    wrist = observation["video.wrist_image"][0, 0].astype(np.float64)
    seed = (options or {}).get("conflictbench/noise_seed", 0)
    return np.array(
        [
            (image[:128].mean() - image[128:].mean()) / 255.0,
            (wrist[:, :128].mean() - wrist[:, 128:].mean()) / 255.0,
            float(observation["state.x"][0, 0, 0]) + float(observation["state.yaw"][0, 0, 0]),
            float(observation["state.gripper"][0, 0, 0] - observation["state.gripper"][0, 0, 1]),
            len(observation[LANGUAGE][0]) / 100.0,
            (seed % 1000) / 1000.0,
        ]
    )


def actions_for(observation: dict, options, horizon: int) -> dict:
    """The stand-in's reply: (1, horizon, 1) float32 per action key; the gripper alternates 0, 1, 0.5."""
    values = features(observation, options)
    steps = np.arange(1, horizon + 1, dtype=np.float64)
    reply = {key: (values[i] * steps).astype(np.float32)[None, :, None] for i, key in enumerate(ACTIONS[:-1])}
    gripper = np.array([(0.0, 1.0, 0.5)[t % 3] for t in range(horizon)], dtype=np.float32)
    reply["action.gripper"] = gripper[None, :, None]
    return reply


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("port", type=int)
    parser.add_argument("--api-token")
    parser.add_argument("--horizon", type=int, default=16)
    parser.add_argument("--fail-on", help="answer a reply without action.gripper when the task contains this")
    parser.add_argument("--die-on", help="exit at once when the task contains this")
    args = parser.parse_args()

    socket = zmq.Context().socket(zmq.REP)
    socket.bind(f"tcp://127.0.0.1:{args.port}")
    print(f"Server is ready and listening on tcp://127.0.0.1:{args.port}", flush=True)

    def get_action(observation, options=None):
        check_observation(observation)
        task = observation[LANGUAGE][0]
        if args.die_on and args.die_on in task:
            os._exit(9)
        reply = actions_for(observation, options, args.horizon)
        if args.fail_on and args.fail_on in task:
            del reply["action.gripper"]
        return [reply, {}]

    endpoints = {
        "ping": (lambda: {"status": "ok", "message": "Server is running"}, False),
        "kill": (lambda: None, False),
        "get_action": (get_action, True),
        "reset": (lambda options=None: {}, True),
        "get_modality_config": (lambda: {}, False),
    }
    while True:
        message = socket.recv()
        try:
            request = from_bytes(message)
            if args.api_token is not None and request.get("api_token") != args.api_token:
                socket.send(to_bytes({"error": "Unauthorized: Invalid API token"}))
                continue
            endpoint = request.get("endpoint", "get_action")
            if endpoint not in endpoints:
                raise ValueError(f"Unknown endpoint: {endpoint}")
            handler, takes_input = endpoints[endpoint]
            result = handler(**request.get("data", {})) if takes_input else handler()
            socket.send(to_bytes(result))
        except Exception as error:  # NVIDIA's server answers every failure this way and goes on
            socket.send(to_bytes({"error": str(error)}))


if __name__ == "__main__":
    main()
