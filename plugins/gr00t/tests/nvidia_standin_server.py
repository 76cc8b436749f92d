"""A GR00T server behaving as NVIDIA's ``PolicyServer`` (``gr00t/policy/server_client.py``), hosting a numpy stand-in.

NVIDIA's server cannot be installed here (it is not on PyPI), so this one restates its behaviour from the
source: a ZeroMQ REP socket; msgpack with ``np.save`` arrays, encoded here with msgpack and numpy directly
(not through our protocol module, so the client is checked against the format, not against itself); endpoint
``get_action`` by default; ``ping``, ``kill``, ``reset``, ``get_modality_config``; ``{"error": str}`` for an
unknown endpoint, a bad API token or any exception; observations checked as the sim wrapper checks them.
The stand-in's actions are a fixed function of every field of the observation and of ``options``
(:func:`actions_for`), so a test can tell that each arrived intact. ``get_modality_config`` answers the LIBERO
modality configs (``libero_sim``, ``gr00t/configs/data/embodiment_configs.py:145-162`` at ``23ace64``), each a
``ModalityConfig`` as the serializer marks it.

``--revision main`` speaks the wire of Isaac-GR00T's main branch since ``3df8b38`` (2026-05-07; ``MsgSerializer``,
``server_client.py:31-112`` at ``626af89``), restated from its source: msgpack_numpy 0.4.8 (main's pin,
``pyproject.toml:20``) encodes an array as ``{b"nd": True, b"type": dtype.str, b"kind": b"", b"shape": shape,
b"data": bytes}`` and decodes only such maps, so a map marked ``__ndarray_class__`` stays a map (``:50-55``,
``:99-112``); a ``ModalityConfig`` is ``{"__ModalityConfig__": True, "as_json": ...}`` (``:93-96``) where
``n1.7-release`` writes ``__ModalityConfig_class__`` (``server_client.py:50-55`` at ``23ace64``).

    python nvidia_standin_server.py PORT [--api-token T] [--fail-on TEXT] [--die-on TEXT] [--horizon 16]
                                         [--revision release|main]
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


class ModalityConfig:
    """What NVIDIA's ``ModalityConfig`` is on the wire: its fields as JSON (``to_json_serializable``)."""

    def __init__(self, delta_indices: list[int], modality_keys: list[str]):
        self.as_json = {
            "delta_indices": delta_indices,
            "modality_keys": modality_keys,
            "sin_cos_embedding_keys": None,
            "mean_std_embedding_keys": None,
            "action_configs": None,
        }


#: ``libero_sim``'s modality configs, what ``get_modality_config`` answers.
MODALITY_CONFIGS = {
    "video": ModalityConfig([0], ["image", "wrist_image"]),
    "state": ModalityConfig([0], ["x", "y", "z", "roll", "pitch", "yaw", "gripper"]),
    "action": ModalityConfig(list(range(16)), ["x", "y", "z", "roll", "pitch", "yaw", "gripper"]),
    "language": ModalityConfig([0], [LANGUAGE]),
}


def to_bytes(obj, revision: str = "release") -> bytes:
    def encode(value):
        if isinstance(value, ModalityConfig):
            mark = "__ModalityConfig__" if revision == "main" else "__ModalityConfig_class__"
            return {mark: True, "as_json": value.as_json}
        if isinstance(value, np.ndarray) and revision == "main":  # msgpack_numpy 0.4.8's map
            data = np.ascontiguousarray(value).tobytes()
            return {b"nd": True, b"type": value.dtype.str, b"kind": b"", b"shape": value.shape, b"data": data}
        if isinstance(value, np.ndarray):
            buffer = io.BytesIO()
            np.save(buffer, value, allow_pickle=False)
            return {"__ndarray_class__": True, "as_npy": buffer.getvalue()}
        return value

    return msgpack.packb(obj, default=encode)


def from_bytes(data: bytes, revision: str = "release"):
    def decode(obj):
        if revision == "main":  # msgpack_numpy's maps only; any other map stays a map
            if obj.get(b"nd") is True:
                return np.ndarray(buffer=obj[b"data"], dtype=np.dtype(obj[b"type"]), shape=obj[b"shape"])
            return obj
        if "__ndarray_class__" in obj:
            return np.load(io.BytesIO(obj["as_npy"]), allow_pickle=False)
        return obj

    return msgpack.unpackb(data, object_hook=decode, raw=False)


def check_observation(observation: dict) -> None:
    """What NVIDIA's sim wrapper asserts of an observation (keys, dtypes, ranks, one frame, a list of text)."""
    for key in VIDEO:
        value = observation[key]
        name = key.removeprefix("video.")  # NVIDIA's message (gr00t_policy.py:547-549 at 23ace64)
        assert isinstance(value, np.ndarray), f"Video key '{name}' must be a numpy array. Got {type(value)}"
        assert value.dtype == np.uint8 and value.ndim == 5, key
        assert value.shape[1] == 1 and value.shape[-1] == 3, key
    for key in STATE:
        value = observation[key]
        name = key.removeprefix("state.")  # (:581-583)
        assert isinstance(value, np.ndarray), f"State key '{name}' must be a numpy array. Got {type(value)}"
        assert value.dtype == np.float32 and value.ndim == 3, key
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
    parser.add_argument("--revision", choices=("release", "main"), default="release", help="whose wire to speak")
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
        "get_modality_config": (lambda: MODALITY_CONFIGS, False),
    }
    while True:
        message = socket.recv()
        try:
            request = from_bytes(message, args.revision)
            if args.api_token is not None and request.get("api_token") != args.api_token:
                socket.send(to_bytes({"error": "Unauthorized: Invalid API token"}, args.revision))
                continue
            endpoint = request.get("endpoint", "get_action")
            if endpoint not in endpoints:
                raise ValueError(f"Unknown endpoint: {endpoint}")
            handler, takes_input = endpoints[endpoint]
            result = handler(**request.get("data", {})) if takes_input else handler()
            socket.send(to_bytes(result, args.revision))
        except Exception as error:  # NVIDIA's server answers every failure this way and goes on
            socket.send(to_bytes({"error": str(error)}, args.revision))


if __name__ == "__main__":
    main()
