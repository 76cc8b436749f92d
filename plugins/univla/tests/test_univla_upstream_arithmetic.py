"""Our UniVLA path against upstream's LIBERO loop, bit for bit (issue #43; the audit: docs/upstream/audit_univla.md).

Upstream (OpenDriveLab/UniVLA@0ab9e9d, ``experiments/robot/libero/run_libero_eval.py``) runs the model in its loop;
``upstream_univla.py``, written from upstream's source by a reader who did not read this plugin, restates what the
loop does before the model (``request``) and after it (``Executed``: from the action decoder's float32 output to
``env.step``). The same inputs go through our code as a run executes it:

- way out: the decoder's recorded float32 output -> our server's reply (``backend.reply_of``, json-numpy as the REST
  app sends it) -> the client's ``decode`` (history, ensembling window, un-normalization with the statistics our
  server's ``/metadata`` carried, gripper) -> the runner's ``reply_for`` (``as_action_chunk``, post-processing)
  -> the row the worker hands ``env.step``; compared as float64 bit patterns (the sign of zero included) with the
  list upstream passes, after ``np.asarray(..., np.float64)`` (what robosuite makes of either);
- way in: our client's ``encode`` -> the request body -> our server's ``request_row`` -> ``backend.model_inputs``
  (the prompt and the PIL image the processor gets), against ``request``'s prompt and image. Upstream's image steps
  are TensorFlow's, which this environment does not have: ``golden/upstream_images.npz`` holds what the
  restatement made of ``univla_upstream_inputs.observations()`` under TensorFlow 2.15.0 (upstream's pin), written
  by ``golden/make_upstream_images.py``.

Our server runs here in this process with the model replaced by the recorded outputs (``Recorded``): its REST app,
request parsing and reply encoding are those ``conflictbench-serve univla`` runs.
"""

from __future__ import annotations

import asyncio
import json
import socket
import threading
import time

import json_numpy
import numpy as np
import pytest
import upstream_univla as upstream
from univla_upstream_inputs import UPSTREAM_IMAGES, observations

from conflictbench import BUILTIN_PLUGINS
from conflictbench.core import Observation, Plugins, PolicyError, PolicyTraits
from conflictbench.hosting.rest import JsonNumpyTransport
from conflictbench.sim.deciding import reply_for
from conflictbench.sim.messages import Abort, Actions, EpisodeJob
from conflictbench.sim.plan import EpisodeSpec
from conflictbench.sim.slots import Item
from conflictbench.sim.worker import NOOP_ACTION
from conflictbench_univla import client as univla_client
from conflictbench_univla.backend import Row, action_statistics, model_inputs, reply_of
from conflictbench_univla.client import UnivlaConfig, load
from conflictbench_univla.processing import UNIVLA_MAX_STEPS, TemporalEnsemble
from conflictbench_univla.server import request_row

WINDOW = upstream.WINDOW_SIZE
CHECKPOINT = "/checkpoints/univla-7b-224-sft-libero"  # the path given: upstream's prompt looks for "openvla-v01"
F32 = np.float32


def _stats(seed: int, mask: bool = True, gripper=(0.0, 1.0)) -> dict:
    """One suite's entry as UniVLA's fine-tuning writes dataset_statistics.json: float32 values through .tolist()."""
    rng = np.random.default_rng(seed)
    low = np.append(rng.uniform(-0.95, -0.05, 6).astype(F32), F32(gripper[0]))
    high = np.append(rng.uniform(0.05, 0.95, 6).astype(F32), F32(gripper[1]))
    action = {"mean": ((low + high) / 2).tolist(), "std": (high - low).tolist(), "max": high.tolist(),
              "min": low.tolist(), "q01": low.tolist(), "q99": high.tolist()}  # fmt: skip
    if mask:
        action["mask"] = [True] * 6 + [False]
    return {"action": action, "proprio": {"mean": [0.0] * 7}, "num_transitions": 52970, "num_trajectories": 432}


#: The checkpoint's dataset_statistics.json, as text: libero_object without a mask (the gripper un-normalized too,
#: its threshold at a normalized 0), libero_10 only under its _no_noops key (both sides fall back to it).
STATISTICS_JSON = json.dumps(
    {
        "libero_spatial_no_noops": _stats(1),
        "libero_object_no_noops": _stats(2),
        "libero_spatial": _stats(3),
        "libero_object": _stats(4, mask=False),
        "libero_goal": _stats(5),
        "libero_10_no_noops": _stats(6),
    }
)
SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")


class Recorded:
    """Our server's backend with the model replaced by recorded decoder outputs: its metadata as
    ``UnivlaBackend``'s (the statistics through ``action_statistics``), each answer ``reply_of`` the next
    recorded (float32 decoder output, generated ids); the rows it was asked with, kept."""

    def __init__(self, statistics_json: str):
        self.metadata = {
            "policy_type": "univla",
            "checkpoint": CHECKPOINT,
            "checkpoint_fingerprint": "sha256:recorded",
            "model_stack": {"device": "cpu", "packages": {"recorded": "0"}},  # as conflictbench-serve adds it
            "window": WINDOW,
            "action_statistics": action_statistics(json.loads(statistics_json)),
        }
        self.queue: list[tuple[np.ndarray, np.ndarray]] = []
        self.rows: list[Row] = []

    def infer_batch(self, rows: list[Row]) -> list[dict]:
        self.rows.extend(rows)
        return [reply_of(*self.queue.pop(0), WINDOW) for _ in rows]


@pytest.fixture(scope="module")
def served():
    """Our server's REST app (``conflictbench_serving.rest.build_app`` with univla's ``request_row``, as
    ``conflictbench-serve univla`` builds it) on a free port in this process, and its backend."""
    import uvicorn

    from conflictbench_serving import rest

    backend = Recorded(STATISTICS_JSON)
    app = rest.build_app(backend, 1, request_row, "univla")
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", access_log=False))
    thread = threading.Thread(target=lambda: asyncio.run(server.serve(sockets=[sock])), daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started and thread.is_alive() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert server.started, "the in-process server did not start"
    yield backend, f"http://127.0.0.1:{sock.getsockname()[1]}"
    server.should_exit = True
    thread.join(10)


@pytest.fixture(scope="module")
def policy(served):
    _, url = served
    univla = load("univla", UnivlaConfig(server=url, checkpoint="recorded", connect_retries=0))
    yield univla
    univla.close()


PLUGINS = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[univla_client])
WIRE = JsonNumpyTransport("http://127.0.0.1:1")  # only its loads: the client's reading of a reply body


def item_for(observation: Observation) -> Item:
    spec = EpisodeSpec(observation.suite, 0, 0, "p0", observation.instruction)
    job = EpisodeJob(observation.episode_id, observation.suite, 0, "x.bddl", 0, 7, observation.instruction,
                     (), (), 10, 550, False)  # fmt: skip
    return Item(spec, job)


def env_step_argument(raw, observation: Observation) -> np.ndarray:
    """What the worker hands ``env.step`` for ``raw``, the policy's answer: the runner's ``reply_for``."""
    reply = reply_for(PLUGINS, "univla", item_for(observation), observation, raw)
    assert isinstance(reply, Actions), reply
    assert reply.executed.shape == (1, 7) and reply.executed.dtype == np.float64
    return reply.executed[0]


def bits(action) -> np.ndarray:
    """The float64 bit patterns of what env.step receives (robosuite reads either form as a float64 array)."""
    return np.asarray(action, dtype=np.float64).view(np.uint64)


def observation(step: int, suite: str, stream: int = 0, instruction: str = "Open the Top Drawer", image=None):
    return Observation(
        step=step, instruction=instruction, eef_pos=np.zeros(3), eef_quat=np.array([0.0, 0.0, 0.0, 1.0]),
        gripper_qpos=np.zeros(2), state=np.zeros(8), stream=stream, episode_id=f"{suite}-{stream}", suite=suite,
        agentview_image=image,
    )  # fmt: skip


# The decoder's outputs --------------------------------------------------------------------------------------------

HALF = F32(0.5)
#: The gripper (its normalized value, mask off) at the threshold: just below, at, just above, in float32.
AT_THRESHOLD = [np.nextafter(HALF, F32(0)), HALF, np.nextafter(HALF, F32(1))]
#: Where un-normalization or binarization has an edge: the bounds, zeros of both signs, the smallest values.
EDGES = [F32(-1), F32(1), np.nextafter(F32(-1), F32(0)), np.nextafter(F32(1), F32(0)), F32(0), F32(-0.0),
         np.nextafter(F32(0), F32(1)), np.nextafter(F32(0), F32(-1)), *AT_THRESHOLD]  # fmt: skip


def decoder_outputs(seed: int, queries: int) -> list[np.ndarray]:
    """``queries`` float32 outputs (1, 7 * 12) of the decoder's tanh: uniform in (-1, 1), a fifth of the values
    replaced by :data:`EDGES`, each query's first planned gripper value at the threshold in turn."""
    rng = np.random.default_rng(seed)
    outputs = []
    for k in range(queries):
        chunk = rng.uniform(-1, 1, (WINDOW, 7)).astype(F32)
        edge = rng.random((WINDOW, 7)) < 0.2
        chunk[edge] = rng.choice(np.array(EDGES, dtype=F32), int(edge.sum()))
        chunk[0, 6] = AT_THRESHOLD[k % 3]
        outputs.append(chunk.reshape(1, -1))
    return outputs


def latent_ids(seed: int, queries: int) -> list[np.ndarray]:
    """What ``predict_latent_action`` returns as ids: (1, 4) int64 in <ACT_0> .. <ACT_31>, now and then fewer."""
    rng = np.random.default_rng(seed + 1000)
    return [rng.integers(32001, 32033, (1, 4 if k % 5 else 3)) for k in range(queries)]


# Way out ----------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("suite", SUITES)
def test_every_executed_action_is_upstreams_bit_for_bit(policy, suite, seed):
    """30 queries of one episode (the window fills, ages and wraps): our reply, decode and runner against
    upstream's ``Executed`` on the same decoder outputs, every value's bits."""
    outputs, ids = decoder_outputs(seed, 30), latent_ids(seed, 30)
    theirs = upstream.Executed(json.loads(STATISTICS_JSON), task_suite_name=suite)
    differing = []
    for step, (output, generated) in enumerate(zip(outputs, ids, strict=True)):
        obs = observation(step, suite, stream=seed)
        reply = WIRE.loads(json_numpy.dumps(reply_of(output, generated, WINDOW)).encode())  # as the server sends it
        ours = env_step_argument(policy.decode(reply, obs), obs)
        (upstreams,) = theirs(output)
        assert all(type(value) is float for value in upstreams)  # Python floats: float64, as ours
        if not np.array_equal(bits(ours), bits(upstreams)):
            differing.append((step, ours.tolist(), upstreams))
    assert differing == []


def test_the_gripper_at_its_threshold_and_the_bounds(policy):
    """A first query executes the first planned action itself: the gripper g just below, at and above 0.5 gives
    +1, -0.0 (upstream's sign(0) * -1.0) and -1, and the bounds give q01 and q99 as upstream computes them; where
    the statistics have no mask (libero_object here) the gripper is un-normalized first, its threshold at a
    normalized 0. Then 14 queries that all plan the same gripper value: the ensembled mean lands on or beside the
    threshold, as upstream's."""
    statistics = json.loads(STATISTICS_JSON)
    cases = [("libero_goal", g, bound) for g, bound in zip(AT_THRESHOLD, (F32(-1), F32(0), F32(1)), strict=True)]
    # here x -> 0.5 * (x + 1) * (1 - 0) + 0: a denormal vanishes in x + 1, 2^-23 is the nearest that does not
    near_zero = (F32(-(2**-23)), F32(0), F32(-0.0), np.nextafter(F32(0), F32(1)), F32(2**-23))
    cases += [("libero_object", g, F32(1)) for g in near_zero]
    expected = [1.0, -0.0, -1.0, 1.0, -0.0, -0.0, -0.0, -1.0]
    for k, ((suite, gripper, bound), executed) in enumerate(zip(cases, expected, strict=True)):
        output = np.full((WINDOW, 7), bound, dtype=F32)
        output[:, 6] = gripper
        theirs = upstream.Executed(statistics, task_suite_name=suite)
        for step in range(14):
            obs = observation(step, suite, stream=10 + k)
            reply = WIRE.loads(json_numpy.dumps(reply_of(output.reshape(1, -1), np.array([[32001] * 4]), 12)).encode())
            ours = env_step_argument(policy.decode(reply, obs), obs)
            assert bits(ours).tolist() == bits(theirs(output.reshape(1, -1))[0]).tolist(), (suite, gripper, step)
            if step == 0:
                assert bits(ours)[6] == bits([executed])[0], (suite, gripper)


def test_a_whole_episode_through_our_server_is_upstreams_both_ways(policy, served):
    """14 steps of one episode by ``act``, over HTTP to our server: each executed action upstream's, each
    prompt the one upstream builds from the last query's tokens, each image the client made arriving intact."""
    backend, _ = served
    from conflictbench.hosting.openvla_family import policy_image

    rng = np.random.default_rng(7)
    outputs, ids = decoder_outputs(11, 14), latent_ids(11, 14)
    backend.queue[:] = list(zip(outputs, ids, strict=True))
    backend.rows.clear()
    theirs, history = upstream.Executed(json.loads(STATISTICS_JSON), task_suite_name="libero_10"), ""
    for step in range(14):
        render = rng.integers(0, 256, (256, 256, 3), dtype=np.uint8)
        obs = observation(step, "libero_10", stream=20, instruction="Put BOTH moka pots on the stove", image=render)
        ours = env_step_argument(policy.act(obs), obs)
        assert bits(ours).tolist() == bits(theirs(outputs[step])[0]).tolist(), step
        text, image = model_inputs(backend.rows[step], CHECKPOINT)
        assert text == upstream.prompt_text(obs.instruction, history, CHECKPOINT), step
        assert np.array_equal(np.asarray(image), policy_image(render, crop=True))
        history = upstream.history_string(ids[step])
    assert backend.queue == []


def test_a_latent_token_upstream_cannot_read_back_ends_the_episode(policy):
    """An id above <ACT_31>: upstream's history lookup raises IndexError and its loop's ``except`` ends the episode
    before acting; ours ends it as the model's failure, before acting, its window and history untouched."""
    with pytest.raises(IndexError):
        upstream.history_string(np.array([[32001, 32002, 32033, 32004]]))
    obs = observation(0, "libero_goal", stream=30)
    reply = WIRE.loads(json_numpy.dumps(reply_of(decoder_outputs(0, 1)[0], np.array([[32001, 32033]]), 12)).encode())
    with pytest.raises(PolicyError, match="32033") as raised:
        policy._decode(reply, obs)  # as act_batch reads a reply: the model's answer, not our client's failure
    ended = reply_for(PLUGINS, "univla", item_for(obs), obs, raised.value)
    assert isinstance(ended, Abort) and ended.kind == "policy"  # scored as the model's, as upstream counts a failure
    assert policy._episode(obs).history == "" and not policy._episode(obs).ensemble.mask.any()


# Way in -----------------------------------------------------------------------------------------------------------


def _arrived(policy, obs: Observation) -> Row:
    """The row our server reads from the body our client sends for ``obs``."""
    row, encoded = request_row(WIRE.dumps(policy.encode(obs)).encode())
    assert not encoded
    return row


@pytest.mark.parametrize("crop", [True, False])
def test_the_image_and_prompt_reaching_the_processor_are_upstreams(served, crop):
    """The real LIBERO observation and the synthetic renders: the pixels the processor gets are those upstream's
    TensorFlow steps make (0 of 150528 values differ), with and without the centre crop; the prompt lower-cased,
    without history at an episode's first query."""
    _, url = served
    univla = load("univla", UnivlaConfig(server=url, checkpoint="recorded", connect_retries=0, center_crop=crop))
    made = dict(np.load(UPSTREAM_IMAGES))
    try:
        for i, raw in enumerate(observations()):
            instruction = str(raw.get("instruction", "Pick Up the Alphabet Soup and place it in the BASKET"))
            obs = observation(0, "libero_goal", stream=40 + i, instruction=instruction, image=raw["agentview_image"])
            text, image = model_inputs(_arrived(univla, obs), CHECKPOINT)
            theirs = made["image" if crop else "full_image"][i]
            assert image.mode == "RGB" and np.asarray(image).dtype == np.uint8
            assert int(np.count_nonzero(np.asarray(image) != theirs)) == 0, i
            assert text == upstream.prompt_text(instruction, "", CHECKPOINT)
    finally:
        univla.close()


def test_an_openvla_v01_checkpoint_path_gets_upstreams_v01_prompt_at_a_first_query():
    """Upstream picks OpenVLA v0.1's template where the checkpoint path says ``openvla-v01`` (history or not, the
    history form after)."""
    image = np.zeros((224, 224, 3), np.uint8)
    for path in ("/ckpt/openvla-v01-univla-libero", CHECKPOINT):
        for history in ("", "<ACT_1><ACT_2><ACT_3><ACT_4>"):
            text, _ = model_inputs(Row(image, "Turn ON the stove", history, "libero_goal", 1), path)
            assert text == upstream.prompt_text("Turn ON the stove", history, path), (path, history)


# Episode constants ------------------------------------------------------------------------------------------------


def test_episode_constants_and_ensembling_weights_are_upstreams(policy):
    traits = PolicyTraits(policy)
    assert traits.warmup_steps == upstream.NUM_STEPS_WAIT
    assert traits.image_size == upstream.ENV_RESOLUTION
    assert UNIVLA_MAX_STEPS == {suite: upstream.MAX_STEPS[suite] for suite in SUITES}
    assert traits.max_steps == UNIVLA_MAX_STEPS
    assert bits(NOOP_ACTION).tolist() == bits(upstream.NOOP_ACTION).tolist()
    assert policy.window == WINDOW
    ours, theirs = TemporalEnsemble(WINDOW), upstream.TemporalEnsemble(WINDOW)
    assert bits(ours.weights).tolist() == bits(theirs.temporal_weights).tolist()  # computed alike, on this CPU
    assert [float.hex(float(w)) for w in ours.weights[:, 0]] in [
        [float.hex(float.fromhex(h)) for h in weights] for weights in upstream.TEMPORAL_WEIGHTS_HEX.values()
    ]
    assert np.array_equal(ours.valid, theirs.temporal_mask)
