"""The inputs and the two sides of ``test_openvla_upstream_arithmetic.py``: statistics, LIBERO observations
(real and synthetic), replies as ``deploy.py`` answers them, a server answering as ``deploy.py`` does, and what
our worker passes to ``env.step`` for a reply."""

from __future__ import annotations

import contextlib
import dataclasses
import http.server
import json
import threading
from pathlib import Path
from types import SimpleNamespace

import json_numpy
import numpy as np
import upstream_openvla as upstream
import upstream_openvla_oft as upstream_oft

from conflictbench.sim.deciding import reply_for
from conflictbench.sim.messages import Actions
from conflictbench.testing import EDGE_QUATERNION_W, camera_observation, edge_quaternion, worker_observation
from conflictbench_openvla.client import OftConfig, load

GOLDEN = Path(__file__).resolve().parent / "golden"

#: LIBERO-like statistics as ``json.load`` gives them (Python floats: float64), the gripper masked out.
ACTION_STATS = {
    "q01": [-0.7454732114076613, -0.6616071462631226, -0.9375, -0.1071428582072258, -0.20678570866584778,
            -0.1842857152223587, 0.0],
    "q99": [0.9375, 0.8758928775787354, 0.9321428537368774, 0.1039285734295845, 0.17678570747375488,
            0.14571428298950195, 1.0],
    "mask": [True, True, True, True, True, True, False],
}  # fmt: skip
PROPRIO_STATS = {
    "q01": [-0.4828, -0.2939, 0.8803, 2.2412, -1.0183, -0.8497, 0.0012, -0.0399],
    "q99": [0.1445, 0.3493, 1.2625, 3.2746, 0.4352, 0.4226, 0.0399, -0.0011],
}
#: LIBERO's state at the frames ``golden/inputs.npz`` holds (read from the simulator; repr round-trips exactly).
REAL_STATES = [
    ([-0.2132534930122561, -0.004300895646637607, 1.1707250596348213],
     [0.9995769843149529, 0.00029088820724659797, -0.02907912054814414, -0.00041540344505068734],
     [0.0387247887791924, -0.038720802405686434]),
    ([-0.20136824171771897, 0.018699722167774255, 1.1893182827480369],
     [0.999622153034582, 0.0021363418752811114, -0.02740170699997399, 0.00036559456530795877],
     [0.03872168614175747, -0.038723892707541875]),
]  # fmt: skip
INSTRUCTIONS = (
    "push the plate to the front of the stove",
    "Turn On the Stove and put the MOKA pot on it.",
    "  pick up the alphabet soup and place it in the basket  ",
    "İstanbul: put the crème brûlée in the ΣΟΦΑ bowl",
)


# -- a server answering as deploy.py does -------------------------------------------------------------------------


def deploy_body(answer) -> bytes:
    """What deploy.py's ``JSONResponse(answer)`` writes with ``json.dumps`` patched by json-numpy (starlette's
    ``JSONResponse.render``: ``ensure_ascii=False, allow_nan=False, indent=None, separators=(",", ":")``)."""
    text = json_numpy.dumps(answer, ensure_ascii=False, allow_nan=False, indent=None, separators=(",", ":"))
    return text.encode("utf-8")


class DeployLike(http.server.BaseHTTPRequestHandler):
    """``POST /act`` answers the next queued body and keeps the request's; anything else is 404, as FastAPI's."""

    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True  # headers and body go in two writes: no 40 ms wait for a delayed ACK

    def log_message(self, *args) -> None:  # quiet
        pass

    def _send(self, status: int, body: bytes) -> None:
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self) -> None:
        metadata = self.server.metadata
        if self.path.endswith("/metadata") and metadata is not None:
            self._send(200, json.dumps(metadata).encode())
        else:
            self._send(404, b'{"detail":"Not Found"}')

    def do_POST(self) -> None:
        body = self.rfile.read(int(self.headers["Content-Length"]))
        self.server.requests.append(body)
        self._send(200, self.server.replies.pop(0))


@contextlib.contextmanager
def deploy_like(metadata: dict | None = None):
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), DeployLike)
    server.requests, server.replies, server.metadata = [], [], metadata
    thread = threading.Thread(target=server.serve_forever, args=(0.01,), daemon=True)
    thread.start()
    try:
        yield server, f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


def oft_policy(url: str, chunk_length: int):
    return load("openvla-oft", OftConfig(server=url, checkpoint="deploy-like", connect_retries=0, **{
        "chunk_length": chunk_length}))  # fmt: skip


def tf_image_functions():
    """TensorFlow 2.18.1's bytes for the golden inputs: upright render -> resized, resized -> cropped."""
    inputs = np.load(GOLDEN / "inputs.npz")["inputs"]
    made_by_tf = np.load(GOLDEN / "tf_images.npz")
    resized = {inputs[i].tobytes(): made_by_tf["resized"][i] for i in range(len(inputs))}
    cropped = {made_by_tf["resized"][i].tobytes(): made_by_tf["cropped"][i] for i in range(len(inputs))}

    def resize_fn(image: np.ndarray, size) -> np.ndarray:
        assert tuple(np.atleast_1d(size)) in ((224,), (224, 224)) and image.shape == (256, 256, 3)
        return resized[np.ascontiguousarray(image).tobytes()]  # KeyError: not an upright golden render

    def center_crop_fn(image: np.ndarray) -> np.ndarray:
        return cropped[np.ascontiguousarray(image).tobytes()]

    return inputs, resize_fn, center_crop_fn


def synthetic_states() -> list[tuple[list[float], list[float], list[float]]]:
    """eef position, quaternion (x, y, z, w) and finger positions: w at 1, past +-1, at nextafter(1, 0), random."""
    states = []
    for seed, w in enumerate([*EDGE_QUATERNION_W, *[None] * 5]):
        rng = np.random.default_rng(seed)
        quat = edge_quaternion(rng, w)
        states.append((list(rng.uniform([-0.3, -0.3, 0.8], [0.3, 0.3, 1.3])), list(quat), [0.039, -0.0387 * seed / 9]))
    return states


def raw_observations(inputs: np.ndarray) -> list[tuple[dict, str, str]]:
    """LIBERO observation dicts (images as rendered: upside down) with a task text and a suite."""
    rendered = [np.ascontiguousarray(image[::-1, ::-1]) for image in inputs]
    pairs = [(0, 1), (2, 3), (4, 5), (5, 4), (1, 0), (3, 2)]
    states = REAL_STATES + synthetic_states()
    suites = ("libero_goal", "libero_10", "libero_spatial", "libero_object")
    out = []
    for i, (pos, quat, fingers) in enumerate(states):
        agent, wrist = pairs[i % len(pairs)]
        raw = {
            "agentview_image": rendered[agent],
            "robot0_eye_in_hand_image": rendered[wrist],
            "robot0_eef_pos": np.array(pos, dtype=np.float64),
            "robot0_eef_quat": np.array(quat, dtype=np.float64),
            "robot0_gripper_qpos": np.array(fingers, dtype=np.float64),
            "robot0_joint_pos": np.zeros(7),
        }
        out.append((raw, INSTRUCTIONS[i % len(INSTRUCTIONS)], suites[i % len(suites)]))
    return out


def observation_of(raw: dict, instruction: str, suite: str, step: int = 0):
    return worker_observation(raw, instruction, suite=suite, step=step)


def same_payload(ours: dict, theirs: dict) -> None:
    assert sorted(ours) == sorted(theirs)
    for key, value in theirs.items():
        if isinstance(value, np.ndarray):
            assert isinstance(ours[key], np.ndarray), key
            assert (ours[key].dtype, ours[key].shape) == (value.dtype, value.shape), key
            assert ours[key].tobytes() == np.ascontiguousarray(value).tobytes(), key
        else:
            assert type(ours[key]) is type(value) and ours[key] == value, key


# -- replies ------------------------------------------------------------------------------------------------------


def at_threshold(dtype) -> list[float]:
    """Gripper values g at and around the threshold g = 0.5 (2 g - 1 = 0) and at the ends, in ``dtype``."""
    half, zero, one = dtype(0.5), dtype(0.0), dtype(1.0)
    return [half, np.nextafter(half, zero), np.nextafter(half, one), zero, -zero, one, np.nextafter(zero, one),
            np.nextafter(one, dtype(2)), dtype(-1.0), dtype(0.25), dtype(0.75)]  # fmt: skip


def openvla_replies() -> list[np.ndarray]:
    """Actions as deploy.py answers them: predict_action's float64 from generated tokens (every bin's end, the
    clipped ids past them, random ones), the bounds themselves, every gripper value near the threshold, and float32
    arrays (a server answering float32: json-numpy keeps the dtype on the wire)."""
    low, high = np.array(ACTION_STATS["q01"][:6]), np.array(ACTION_STATS["q99"][:6])
    vocab = 32000
    tokens = [np.full(7, vocab - 1), np.full(7, vocab - 255), np.full(7, vocab - 256), np.full(7, vocab - 300),
              np.full(7, vocab)]  # fmt: skip
    tokens += [np.random.default_rng(seed).integers(vocab - 256, vocab, 7) for seed in range(6)]
    replies = [upstream.unnormalize(upstream.detokenize(t, vocab), ACTION_STATS) for t in tokens]
    for dtype in (np.float64, np.float32):
        for g in at_threshold(dtype):
            replies.append(np.append(low, 0).astype(dtype))
            replies[-1][-1] = g
            replies.append(np.append(high, 0).astype(dtype))
            replies[-1][-1] = g
    for seed in range(4):
        rng = np.random.default_rng(100 + seed)
        action = np.append(rng.uniform(low, high), rng.uniform(-0.1, 1.1))
        replies += [action, action.astype(np.float32)]
    return replies


def oft_chunks() -> list[list[np.ndarray]]:
    """Chunks as OFT's deploy.py answers them: the L1 head's float32 un-normalized with +1e-8 (float64, (8, 7)) as
    a list of rows, and float32 chunks whose grippers sit at the threshold."""
    chunks = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        normalized = rng.uniform(-1.05, 1.05, (8, 7)).astype(np.float32)
        normalized[:, -1] = rng.uniform(-0.05, 1.05, 8).astype(np.float32)
        normalized[seed % 8] = [-1, 1, -1, 1, -1, 1, 0.5]  # the bounds and the threshold
        chunks.append(upstream_oft.server_reply(upstream_oft.unnormalize(normalized, ACTION_STATS)))
    for dtype in (np.float32, np.float64):
        values = at_threshold(dtype)
        chunk = np.random.default_rng(7).uniform(-1, 1, (8, 7)).astype(dtype)
        chunk[:, -1] = values[:8]
        chunks.append(list(chunk))
        chunk = chunk.copy()
        chunk[:3, -1] = values[8:]
        chunks.append(list(chunk))
    return chunks


# -- the two sides ------------------------------------------------------------------------------------------------


def small_observation():
    """An observation for the OUT tests, whose request nobody reads: 16-pixel images keep the image steps cheap."""
    tiny = np.random.default_rng(0).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    return dataclasses.replace(camera_observation(0), agentview_image=tiny, wrist_image=tiny)


#: What ``reply_for`` reads of the episode it answers (its action context).
ITEM = SimpleNamespace(
    job=SimpleNamespace(suite="libero_goal", task_id=0), spec=SimpleNamespace(prompt="p0", case_id="")
)


def ours_executed(policy, server, plugins, observation, answer) -> np.ndarray:
    """The rows our worker passes to ``env.step`` for ``answer``: sent by the server, read by our transport and
    client, then the runner's ``reply_for`` (``as_action_chunk``, post-processing)."""
    server.replies.append(deploy_body(answer))
    raw = policy.act_batch([observation])[0]
    if isinstance(raw, Exception):
        raise raw
    reply = reply_for(plugins, policy.name, ITEM, observation, raw)
    assert isinstance(reply, Actions), reply
    return reply.executed


def as_received(answer):
    """deploy.py's answer as upstream's client reads it (``requests``' ``.json()`` with json.loads patched)."""
    return json_numpy.loads(deploy_body(answer).decode())


def bits(action) -> np.ndarray:
    """The bits ``env.step`` works with (robosuite reads the action through ``np.clip``: float64)."""
    return np.asarray(action, dtype=np.float64).view(np.uint64)


def check_same_steps(ours: np.ndarray, theirs: list) -> int:
    """``ours`` (the worker's rows) and ``theirs`` (upstream's ``env.step`` arguments) bit for bit; their count."""
    assert len(ours) == len(theirs)
    for row, action in zip(ours, theirs):
        assert isinstance(row, np.ndarray) and row.dtype == np.float64 and row.shape == (7,)
        assert isinstance(action, list) and all(type(value) is float for value in action)  # .tolist() of float64/32
        assert bits(row).tolist() == bits(action).tolist(), (row, action)
    return len(ours)
