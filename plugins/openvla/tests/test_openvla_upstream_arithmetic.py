"""The openvla and openvla-oft clients against upstream's own LIBERO clients, bit for bit (issue #43).

Upstream's side is ``upstream_openvla.py`` (openvla/openvla@c8f03f4) and ``upstream_openvla_oft.py``
(moojink/openvla-oft@213c5ff), restated from upstream's source by a separate reader who never read this plugin.
Our side is the code a run executes: the policy loaded as a run loads it, its requests sent by our json-numpy
transport to a server answering as ``deploy.py`` does (``JSONResponse(action)`` with ``json_numpy.patch()``), its
replies decoded by our transport and client, then the runner's ``reply_for`` (``as_action_chunk`` and the
post-processing chain) gives the rows the worker passes to ``env.step``. robosuite's ``env.step`` reads an action
through ``np.clip`` (controllers/base_controller.py:120, models/grippers/panda_gripper.py:55-56), i.e. as float64:
both sides are compared after ``np.asarray(x, np.float64)``, by bit pattern.

OUT: deploy.py's float64 replies (un-normalized by the restatement of the model's own ``predict_action`` from
generated tokens at and between the bins' ends), values at the statistics' bounds, the gripper at, just below and
just above the threshold (``nextafter``), float32 replies, several seeds; OFT's chunk with every number of open-loop
steps. IN: LIBERO's own renders and state (``golden/inputs.npz``: libero_goal task 5 and libero_10 task 2, initial
state 0, after the 10 no-op steps; the state read from the same frames) and synthetic stress images and states
(quaternions at and past w = +-1); the images the restatement calls TensorFlow for are TensorFlow 2.18.1's own
bytes (``golden/tf_images.npz``), so our side is compared with TensorFlow itself, not with our restatement.
"""

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
import pytest
import upstream_openvla as upstream
import upstream_openvla_oft as upstream_oft

import conflictbench
import conflictbench_openvla.client as openvla_client
from conflictbench.hosting import openvla_family as family
from conflictbench.sim.capture import make_observation
from conflictbench.sim.deciding import reply_for
from conflictbench.sim.messages import Actions
from conflictbench.testing import camera_observation
from conflictbench_openvla import backend, processing
from conflictbench_openvla.client import OftConfig, OpenVlaConfig, load

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


@pytest.fixture(scope="module")
def plugins():
    """The plugins a run with this plugin alone has: the built-ins and this plugin (no action post-processor)."""
    return conflictbench.plugins(entry_points=False, extra=[openvla_client])


@pytest.fixture(scope="module")
def openvla_policy():
    with deploy_like() as (server, url):
        # OUT only: the crop (which changes no reply here) left out to keep the requests cheap
        policy = load("openvla", OpenVlaConfig(server=url, checkpoint="x", center_crop=False, connect_retries=0))
        try:
            yield policy, server
        finally:
            policy.close()


def oft_policy(url: str, chunk_length: int):
    return load("openvla-oft", OftConfig(server=url, checkpoint="deploy-like", connect_retries=0, **{
        "chunk_length": chunk_length}))  # fmt: skip


# -- observations -------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tf_images():
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
    special_w = [1.0, -1.0, float(np.nextafter(1.0, 2.0)), -float(np.nextafter(1.0, 2.0)), float(np.nextafter(1.0, 0))]
    for seed, w in enumerate(special_w + [None] * 5):
        rng = np.random.default_rng(seed)
        if w is None:
            quat = rng.normal(size=4)
            quat = quat / np.linalg.norm(quat)
        else:
            quat = np.array([*(rng.normal(size=3) * 1e-9), w])
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
    """The observation a worker sends for LIBERO's ``raw`` (conflictbench.sim.capture, as a run makes it)."""
    return make_observation(
        {key: np.copy(value) for key, value in raw.items()},  # upstream's quat2axisangle clips its argument in place
        step=step, instruction=instruction, stream=0, episode_id="e", suite=suite, images=True, privileged=None,
    )  # fmt: skip


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


# -- OUT ----------------------------------------------------------------------------------------------------------


def test_openvla_executes_upstreams_action_bit_for_bit(openvla_policy, plugins):
    policy, server = openvla_policy
    replies, observation = openvla_replies(), small_observation()
    assert len(replies) > 60
    for answer in replies:
        ours = ours_executed(policy, server, plugins, observation, answer)
        assert check_same_steps(ours, upstream.executed(as_received(answer))) == 1


@pytest.mark.parametrize("steps", [8, 1, 3, 5, 7, 9, 12])
def test_oft_executes_upstreams_open_loop_steps_of_each_chunk_bit_for_bit(plugins, steps):
    """``model.chunk_length`` is upstream's ``--num_open_loop_steps``: ``deque(maxlen=steps).extend(chunk)`` keeps
    the LAST ``steps`` actions of the 8, and all 8 where ``steps`` is more."""
    camera = small_observation()
    with deploy_like() as (server, url):
        policy = oft_policy(url, steps)
        try:
            for chunk in oft_chunks():
                ours = ours_executed(policy, server, plugins, camera, chunk)
                theirs = upstream_oft.executed(as_received(chunk), num_open_loop_steps=steps)
                assert check_same_steps(ours, theirs) == min(steps, 8)
        finally:
            policy.close()


# -- IN -----------------------------------------------------------------------------------------------------------


def test_openvla_sends_what_upstreams_client_sends(tf_images):
    inputs, resize_fn, center_crop_fn = tf_images
    with deploy_like() as (server, url):
        policy = load("openvla", OpenVlaConfig(server=url, checkpoint="deploy-like", connect_retries=0))
        try:
            for raw, instruction, suite in raw_observations(inputs):
                observation = observation_of(raw, instruction, suite)
                theirs = upstream.request(raw, instruction, task_suite_name=suite, resize_fn=resize_fn,
                                          center_crop_fn=center_crop_fn)  # fmt: skip
                same_payload(policy.encode(observation), theirs)
                server.replies.append(deploy_body(np.zeros(7)))
                assert not isinstance(policy.act_batch([observation])[0], Exception)
                same_payload(json_numpy.loads(server.requests[-1]), theirs)  # as deploy.py reads it
        finally:
            policy.close()


@pytest.mark.parametrize(
    "setting, keys, expected",
    [
        ("suite", None, "{suite}"),  # deploy.py names no keys: the suite, as run_libero_eval.py:101
        ("suite", ["{suite}", "{suite}_no_noops"], "{suite}"),
        ("suite", ["{suite}_no_noops", "libero_90"], "{suite}_no_noops"),  # run_libero_eval.py:110-111's fallback
        ("suite_no_noops", None, "{suite}_no_noops"),
    ],
)
def test_openvla_sends_upstreams_unnorm_key(tf_images, setting, keys, expected):
    inputs, resize_fn, center_crop_fn = tf_images
    raw, instruction, _ = raw_observations(inputs)[0]
    for suite in ("libero_spatial", "libero_object", "libero_goal", "libero_10"):
        metadata = None if keys is None else {"unnorm_keys": [key.format(suite=suite) for key in keys]}
        with deploy_like(metadata) as (server, url):
            policy = load("openvla", OpenVlaConfig(server=url, checkpoint="x", unnorm_key=setting, connect_retries=0))
            try:
                theirs = upstream.request(raw, instruction, unnorm_key=expected.format(suite=suite),
                                          resize_fn=resize_fn, center_crop_fn=center_crop_fn)  # fmt: skip
                same_payload(policy.encode(observation_of(raw, instruction, suite)), theirs)
            finally:
                policy.close()


def test_openvla_without_the_crop_sends_upstreams_resized_image(tf_images):
    inputs, resize_fn, _ = tf_images
    with deploy_like() as (_, url):
        policy = load("openvla", OpenVlaConfig(server=url, checkpoint="x", center_crop=False, connect_retries=0))
        try:
            for raw, instruction, suite in raw_observations(inputs)[:6]:
                theirs = upstream.request(raw, instruction, task_suite_name=suite, center_crop=False,
                                          resize_fn=resize_fn)  # fmt: skip
                same_payload(policy.encode(observation_of(raw, instruction, suite)), theirs)
        finally:
            policy.close()


def test_oft_sends_what_upstreams_client_sends(tf_images):
    inputs, resize_fn, _ = tf_images
    with deploy_like() as (server, url):
        policy = oft_policy(url, 8)
        try:
            for raw, instruction, suite in raw_observations(inputs):
                observation = observation_of(raw, instruction, suite)
                theirs = upstream_oft.request(raw, instruction, resize_fn=resize_fn)
                assert theirs["state"].dtype == np.float64 and theirs["state"].shape == (8,)
                same_payload(policy.encode(observation), theirs)
                server.replies.append(deploy_body([np.zeros(7)] * 8))
                assert not isinstance(policy.act_batch([observation])[0], Exception)
                same_payload(json_numpy.loads(server.requests[-1]), theirs)
        finally:
            policy.close()


# -- the server's share, where ours restates it -------------------------------------------------------------------


def test_our_servers_prompt_is_deploy_pys():
    for instruction in INSTRUCTIONS:
        assert processing.prompt(instruction) == upstream.prompt(instruction) == upstream_oft.prompt(instruction)
        assert backend.v01_prompt(instruction) == upstream.prompt(instruction, "openvla/openvla-v01-7b")


def test_the_restated_de_tokenization_and_normalizations_match_upstreams():
    """Off the executed path (a checkpoint's own ``predict_action`` runs in our server as in deploy.py): the
    restatements the tests and the tiny checkpoint's self-check rely on, on the values where they matter."""
    ids = np.arange(32000 - 300, 32001)
    assert bits(processing.detokenize(ids, 32000)).tolist() == bits(upstream.detokenize(ids, 32000)).tolist()
    normalized = processing.detokenize(np.random.default_rng(0).integers(31700, 32001, (50, 7)), 32000)
    ours = family.unnormalize(normalized, ACTION_STATS)
    assert bits(ours).tolist() == bits(upstream.unnormalize(normalized, ACTION_STATS)).tolist()
    # float64 input, as OFT's bins path gives (float64 centres); OFT's L1 and diffusion heads give float32
    # (moojink/openvla-oft@213c5ff modeling_prismatic.py:925, :875), where ours, widening first, is not upstream's:
    # off every executed path (docs/upstream/audit_openvla.md, after "Our server")
    ours = family.unnormalize(normalized, ACTION_STATS, processing.OFT_EPSILON)
    assert bits(ours).tolist() == bits(upstream_oft.unnormalize(normalized, ACTION_STATS)).tolist()
    states = np.array([np.concatenate([pos, upstream_oft.quat2axisangle(np.array(quat)), fingers])
                       for pos, quat, fingers in REAL_STATES + synthetic_states()])  # fmt: skip
    states = np.concatenate([states, np.array(PROPRIO_STATS["q01"])[None], np.array(PROPRIO_STATS["q99"])[None]])
    for state in states:
        ours = processing.normalize_proprio(state, PROPRIO_STATS)
        assert bits(ours).tolist() == bits(upstream_oft.normalize_proprio(state, PROPRIO_STATS)).tolist()


def test_episode_constants_are_upstreams():
    from conflictbench.core import PolicyTraits
    from conflictbench.sim.worker import NOOP_ACTION

    for restated in (upstream, upstream_oft):
        assert {suite: processing.MAX_STEPS[suite] for suite in processing.MAX_STEPS} == {
            suite: restated.MAX_STEPS[suite] for suite in processing.MAX_STEPS
        }
        assert bits(NOOP_ACTION).tolist() == bits(restated.DUMMY_ACTION).tolist()
    assert openvla_client.OFT_CHUNK == upstream_oft.NUM_OPEN_LOOP_STEPS == upstream_oft.NUM_ACTIONS_CHUNK
    with deploy_like() as (_, url):
        policy = load("openvla", OpenVlaConfig(server=url, checkpoint="x", connect_retries=0))
        try:
            traits = PolicyTraits(policy)
        finally:
            policy.close()
    assert traits.warmup_steps == upstream.NUM_STEPS_WAIT == upstream_oft.NUM_STEPS_WAIT
    assert traits.image_size == upstream.ENV_RESOLUTION == upstream_oft.ENV_RESOLUTION


RENDER_LIBERO = """
import os, sys
import numpy as np
from conflictbench.sim.libero_env import EnvSettings, configure_process, make_env
settings = EnvSettings(needs_images=True)
configure_process(settings)
from conflictbench.tasks.libero.base_tasks import base_task, load_init_states
frames = {}
for suite, task_id in (("libero_goal", 5), ("libero_10", 2)):
    env = make_env(base_task(suite, task_id).bddl_path, settings)
    env.seed(0)
    env.reset()
    env.set_init_state(load_init_states(suite, task_id)[0])
    for _ in range(10):
        raw, _, _, _ = env.step([0, 0, 0, 0, 0, 0, -1])
    for key in ("agentview_image", "robot0_eye_in_hand_image", "robot0_eef_pos", "robot0_eef_quat",
                "robot0_gripper_qpos"):
        frames[f"{suite}/{key}"] = raw[key]
np.savez(sys.argv[1], **frames)
os._exit(0)  # robosuite's EGL teardown at exit can fail harmlessly
"""


@pytest.mark.sim
@pytest.mark.e2e  # two LIBERO scenes with cameras (10-30 s here): CI's marked lane plays it
def test_the_real_observations_are_what_libero_gives_now(tmp_path):
    """``golden/inputs.npz``'s first four images and ``REAL_STATES`` are LIBERO's own observation (upstream's env
    settings: 256-px cameras, the 10 no-op steps): a fresh env at the same point gives them again, bit for bit."""
    import os
    import subprocess
    import sys

    out = tmp_path / "frames.npz"
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    done = subprocess.run([sys.executable, "-c", RENDER_LIBERO, str(out)], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    frames, inputs = np.load(out), np.load(GOLDEN / "inputs.npz")["inputs"]
    for i, (suite, (pos, quat, fingers)) in enumerate(zip(("libero_goal", "libero_10"), REAL_STATES)):
        assert np.array_equal(frames[f"{suite}/agentview_image"][::-1, ::-1], inputs[2 * i])
        assert np.array_equal(frames[f"{suite}/robot0_eye_in_hand_image"][::-1, ::-1], inputs[2 * i + 1])
        for key, value in (("robot0_eef_pos", pos), ("robot0_eef_quat", quat), ("robot0_gripper_qpos", fingers)):
            assert bits(frames[f"{suite}/{key}"]).tolist() == bits(value).tolist(), key
