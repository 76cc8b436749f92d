"""The π clients (pi0, pi0-fast, pi05) against openpi's own LIBERO client, bit for bit (issue #43).

Upstream's side is ``upstream_openpi.py`` (Physical-Intelligence/openpi@15a9616, ``examples/libero/main.py`` with
openpi-client), restated from upstream's source by a separate reader who never read this plugin. Our side is the code
a run executes: the policy loaded as a run loads it (``model.server=ws://...``), its requests sent by our websocket
transport to a server that frames as openpi's ``websocket_policy_server`` does (metadata first, then one msgpack-numpy
frame back per request, packed by the restatement of openpi's ``msgpack_numpy``), its replies decoded by our transport
and client, then the runner's ``ask_policy`` and ``reply_for`` (``as_action_chunk`` and the post-processing chain), and
the pickling of the worker's pipe, give the rows the worker passes to ``env.step``. robosuite's ``env.step`` reads an
action only through ``np.clip`` and ``np.sign`` (controllers/base_controller.py:120, models/grippers/
panda_gripper.py:55-56), i.e. as float64: both sides are compared after ``np.asarray(x, np.float64)``, by bit
pattern, and the marked test steps LIBERO itself with both.

OUT: float32 replies (our server's and the stand-ins') and float64 ones (openpi's ``Unnormalize`` with statistics
loaded from JSON), values at the normalization bounds (+-1 and their neighbours), the gripper at, just below and just
above robosuite's threshold 0 (``np.sign``: -0.0, the subnormals), large and random values, several seeds; each
policy's chunk length (π0 50, π0-FAST and π0.5 10 in openpi's LIBERO configs) and every replan_steps up to it.
IN: one real LIBERO observation (``golden/libero_observation.npz``: libero_spatial task 0, initial state 0, after the
10 no-op steps, recorded with LIBERO's OffScreenRenderEnv at 256 px, seed 7, as main.py builds it) and synthetic
observations with realistic content (smooth renders with sensor noise, edges, saturated colours; quaternions at and
past w = +-1); the bytes on the wire are compared, not only the decoded values.
"""

from __future__ import annotations

import contextlib
import pickle
import sys
import threading
from pathlib import Path

import msgpack
import numpy as np
import pytest
from websockets.sync.server import serve

sys.path.insert(0, str(Path(__file__).parent))
import upstream_openpi as upstream  # noqa: E402

import conflictbench  # noqa: E402
import conflictbench_pi0.client as pi_client  # noqa: E402
from conflictbench.core.sampling import sampling_seed  # noqa: E402
from conflictbench.sim.deciding import ask_policy, reply_for  # noqa: E402
from conflictbench.sim.messages import Actions, EpisodeJob  # noqa: E402
from conflictbench.sim.plan import EpisodeSpec  # noqa: E402
from conflictbench.sim.slots import Item  # noqa: E402
from conflictbench.testing import EDGE_QUATERNION_W, edge_quaternion, worker_observation  # noqa: E402
from conflictbench_pi0.client import PiConfig, load  # noqa: E402

GOLDEN = Path(__file__).resolve().parent / "golden"
#: The action horizon of each policy's LIBERO config in openpi (src/openpi/training/config.py: pi0_libero takes
#: Pi0Config's default 50, pi0_fast_libero and pi05_libero 10).
HORIZONS = {"pi0": 50, "pi0-fast": 10, "pi05": 10}
INSTRUCTIONS = (
    "pick up the black bowl between the plate and the ramekin and place it on the plate",
    "Turn On the Stove and put the MOKA pot on it.",
    "  open the top drawer and put the bowl inside \n",
    "İstanbul: put the crème brûlée in the ΣΟΦΑ bowl",
    "",
)


# -- a server framing as openpi's websocket_policy_server does ------------------------------------------------------


@contextlib.contextmanager
def openpi_like():
    """openpi's framing (src/openpi/serving/websocket_policy_server.py:50-71): the packed metadata first, then per
    request one binary frame back. Replies are queued frames; each request's frame is kept as received."""
    state = {"requests": [], "replies": []}

    def handler(ws):
        ws.send(upstream.encode({}))
        for frame in ws:
            state["requests"].append(frame)
            ws.send(state["replies"].pop(0))

    server = serve(handler, "127.0.0.1", 0, compression=None, max_size=None)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield state, f"ws://127.0.0.1:{server.socket.getsockname()[1]}"
    finally:
        server.shutdown()
        thread.join(5)


@pytest.fixture(scope="module")
def plugins():
    """The plugins a run with this plugin alone has: the built-ins and this plugin (no action post-processor)."""
    return conflictbench.plugins(entry_points=False, extra=[pi_client])


@pytest.fixture(scope="module")
def served():
    with openpi_like() as (state, url):
        policies = {}
        try:
            for name in HORIZONS:
                for replan in sorted({1, 5, HORIZONS[name]}):
                    config = PiConfig(server=url, checkpoint="openpi-like", replan_steps=replan, connect_retries=0)
                    policies[name, replan] = load(name, config)
            yield state, policies
        finally:
            for policy in policies.values():
                policy.close()


def item_for(name: str, instruction: str = INSTRUCTIONS[0]) -> Item:
    spec = EpisodeSpec("libero_spatial", 0, 0, "p0", instruction)
    job = EpisodeJob("e", "libero_spatial", 0, "x.bddl", 0, 7, instruction, (), (), 10, 220, False)
    return Item(spec, job)


# -- observations -------------------------------------------------------------------------------------------------


def real_observation() -> tuple[dict, str]:
    recorded = np.load(GOLDEN / "libero_observation.npz")
    raw = {key: recorded[key] for key in recorded.files if key.startswith(("agentview", "robot0"))}
    return raw, str(recorded["language"])


def rendered_like(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A render-like uint8 image: smooth shading, hard edges, saturated patches and sensor noise."""
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    base = np.stack([120 + 100 * np.sin(3 * x + c) * np.cos(2 * y - c) for c in rng.uniform(0, 3, 3)], axis=-1)
    base[(x - rng.uniform()) ** 2 + (y - rng.uniform()) ** 2 < 0.03] = rng.integers(0, 256, 3)  # an object's edge
    base[: height // 8, : width // 8] = [255, 0, 0]  # saturated, in LIBERO's first rows: the upright view's bottom
    base += rng.normal(0, 6, base.shape)
    return np.clip(np.rint(base), 0, 255).astype(np.uint8)


def synthetic_observations() -> list[tuple[dict, str]]:
    """LIBERO observation dicts (images upside down, as rendered): w at +-1, past +-1, next to 1, random."""
    sizes = [(256, 256), (256, 256), (128, 128), (480, 640), (97, 131)]
    out = []
    for seed, w in enumerate([*EDGE_QUATERNION_W, *[None] * 5]):
        rng = np.random.default_rng(seed)
        quat = edge_quaternion(rng, w)
        height, width = sizes[seed % len(sizes)]
        raw = {
            "agentview_image": rendered_like(rng, height, width),
            "robot0_eye_in_hand_image": rendered_like(rng, height, width),
            "robot0_eef_pos": rng.uniform([-0.3, -0.3, 0.8], [0.3, 0.3, 1.3]),
            "robot0_eef_quat": quat,
            "robot0_gripper_qpos": np.array([0.039 * seed / 9, -0.0387 * seed / 9]),
            "robot0_joint_pos": rng.normal(size=7),
        }
        out.append((raw, INSTRUCTIONS[seed % len(INSTRUCTIONS)]))
    return out


def observation_of(raw: dict, instruction: str, step: int = 0):
    return worker_observation(raw, instruction, suite="libero_spatial", step=step, sampling_key="pi-upstream")


# -- replies ------------------------------------------------------------------------------------------------------


def special_values(dtype) -> list:
    """The normalization bounds and their neighbours, robosuite's gripper threshold 0 and its neighbours, large."""
    one, zero = dtype(1.0), dtype(0.0)
    return [one, -one, np.nextafter(one, zero), np.nextafter(one, dtype(2)), -np.nextafter(one, zero),
            -np.nextafter(one, dtype(2)), zero, -zero, np.nextafter(zero, one), np.nextafter(zero, -one),
            dtype(0.5), dtype(-0.5), dtype(1e-30), dtype(-1e-30), dtype(3.0e4), dtype(-3.0e4)]  # fmt: skip


def replies(horizon: int, dtype, seeds=range(4)) -> list[np.ndarray]:
    """Chunks of ``horizon`` x 7: the special values cycling through every column, then random ones."""
    special = np.array(special_values(dtype), dtype=dtype)
    chunks = [np.resize(np.roll(special, k), (horizon, 7)).astype(dtype) for k in range(7)]
    for seed in seeds:
        rng = np.random.default_rng(seed)
        chunk = rng.normal(0, 0.5, (horizon, 7)) * rng.choice([1e-8, 1e-3, 1.0, 10.0], (horizon, 1))
        chunk[:, 6] = rng.choice([-1.0, 1.0, rng.uniform(-1, 1)], horizon)
        chunks.append(chunk.astype(dtype))
    return chunks


def reply_frame(actions: np.ndarray) -> bytes:
    """What openpi's server sends: the policy's outputs with its timings (policy.py:92-105, ws_server:64-71)."""
    timings = {"policy_timing": {"infer_ms": 1.5}, "server_timing": {"infer_ms": 2.0}}
    return upstream.encode({"state": np.zeros(8), "actions": actions, **timings})


def our_executed(plugins, policy, state, frame: bytes, observation) -> list[np.ndarray]:
    """The rows our worker passes to env.step for the reply ``frame`` (through the runner and the worker's pipe)."""
    state["replies"].append(frame)
    (raw,) = ask_policy(policy, [observation], batched=True)
    decided = pickle.loads(pickle.dumps(reply_for(plugins, policy.name, item_for(policy.name), observation, raw)))
    assert isinstance(decided, Actions), decided
    return list(decided.executed)


def bits(action) -> np.ndarray:
    return np.asarray(action, dtype=np.float64).view(np.uint64)


# -- OUT: reply -> env.step ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("name", list(HORIZONS))
def test_every_executed_action_is_upstreams_to_the_bit(name, dtype, plugins, served):
    state, policies = served
    observation = observation_of(*synthetic_observations()[0])
    compared = 0
    for (policy_name, replan), policy in policies.items():
        if policy_name != name:
            continue
        for actions in replies(HORIZONS[name], dtype):
            frame = reply_frame(actions)
            ours = our_executed(plugins, policy, state, frame, observation)
            theirs = upstream.executed(upstream.decode(frame), replan_steps=replan)
            assert len(ours) == len(theirs) == replan
            for row, action in zip(ours, theirs):
                # what reaches env.step: our float64 row; upstream's list of Python floats (.tolist())
                assert isinstance(row, np.ndarray) and row.dtype == np.float64 and row.shape == (7,)
                assert isinstance(action, list) and len(action) == 7 and all(type(v) is float for v in action)
                assert bits(row).tobytes() == bits(action).tobytes(), (row, action)
                compared += 7
    assert compared >= 7 * 11 * (1 + 5)  # the chunks of replan_steps 1 and 5, and of the full horizon


def test_a_chunk_shorter_than_replan_steps_executes_nothing_as_upstream(plugins, served):
    # upstream asserts len(chunk) >= replan_steps and the episode ends (main.py:145-147, :160-162): no action of it
    # reaches env.step; ours must not execute the short chunk either
    state, policies = served
    policy = policies["pi05", 5]
    observation = observation_of(*synthetic_observations()[1])
    frame = reply_frame(np.full((3, 7), 0.25, dtype=np.float32))
    with pytest.raises(AssertionError):
        upstream.executed(upstream.decode(frame), replan_steps=5)
    state["replies"].append(frame)
    (raw,) = ask_policy(policy, [observation], batched=True)
    decided = reply_for(plugins, policy.name, item_for(policy.name), observation, raw)
    assert not isinstance(decided, Actions), decided
    assert "fewer than model.replan_steps" in decided.reason


# -- IN: LIBERO observation -> what the server receives -----------------------------------------------------------


def our_request_frame(policy, state, observation) -> bytes:
    state["replies"].append(reply_frame(np.zeros((HORIZONS[policy.name], 7), dtype=np.float32)))
    (raw,) = ask_policy(policy, [observation], batched=True)
    assert not isinstance(raw, Exception), raw
    return state["requests"][-1]


@pytest.mark.parametrize("name", list(HORIZONS))
def test_the_request_is_upstreams_to_the_byte_but_the_noise_seed(name, served):
    state, policies = served
    policy = policies[name, 5]
    cases = [real_observation(), *synthetic_observations()]
    for raw, instruction in cases:
        observation = observation_of(raw, instruction, step=3)
        ours = our_request_frame(policy, state, observation)
        theirs_element = upstream.request({key: np.copy(value) for key, value in raw.items()}, instruction)
        theirs = upstream.encode(theirs_element)
        # the same map, ours with one more pair at its end: the noise seed (openpi's LiberoInputs drops it)
        seed_pair = msgpack.packb("conflictbench/noise_seed") + msgpack.packb(sampling_seed(observation) % 2**63)
        assert (theirs[0], ours[0]) == (0x84, 0x85)  # fixmap of 4 and of 5 pairs
        assert ours[1:] == theirs[1:] + seed_pair
        # and as upstream's server decodes it: each value's dtype, shape and bytes
        decoded = upstream.decode(ours)
        assert list(decoded) == [*upstream.REQUEST_KEYS, "conflictbench/noise_seed"]
        for key in upstream.REQUEST_KEYS:
            value, expected = decoded[key], theirs_element[key]
            if isinstance(expected, np.ndarray):
                assert (value.dtype, value.shape) == (expected.dtype, expected.shape), key
                assert value.tobytes() == np.ascontiguousarray(expected).tobytes(), key
            else:
                assert type(value) is type(expected) and value == expected, key


def test_the_state_and_images_of_a_real_libero_observation(served):
    # the real observation on its own, so that a failure names what differs
    state, policies = served
    raw, instruction = real_observation()
    decoded = upstream.decode(our_request_frame(policies["pi05", 5], state, observation_of(raw, instruction)))
    expected = upstream.request({key: np.copy(value) for key, value in raw.items()}, instruction)
    assert decoded["observation/state"].dtype == np.float64
    assert bits(decoded["observation/state"]).tobytes() == bits(expected["observation/state"]).tobytes()
    for key in ("observation/image", "observation/wrist_image"):
        assert decoded[key].dtype == np.uint8 and decoded[key].shape == (224, 224, 3)
        assert int(np.count_nonzero(decoded[key] != expected[key])) == 0, key
    assert decoded["prompt"] == instruction


# -- the episode's constants --------------------------------------------------------------------------------------


def test_the_episode_constants_are_upstreams():
    from conflictbench.core import PolicyTraits
    from conflictbench.sim.worker import NOOP_ACTION

    traits = PolicyTraits(pi_client.PiPolicy)
    assert traits.warmup_steps == upstream.NUM_STEPS_WAIT
    assert traits.image_size == upstream.ENV_RESOLUTION
    assert PiConfig().replan_steps == upstream.REPLAN_STEPS
    # the four suites conflictbench plays (libero_90, 400 upstream, is not one of them)
    assert traits.max_steps == {suite: upstream.MAX_STEPS[suite] for suite in traits.max_steps}
    assert set(traits.max_steps) == set(upstream.MAX_STEPS) - {"libero_90"}
    assert bits(NOOP_ACTION).tobytes() == bits(upstream.DUMMY_ACTION).tobytes()


# -- env.step itself (a real LIBERO env) --------------------------------------------------------------------------


@pytest.mark.sim
@pytest.mark.slow  # builds a LIBERO env and plays 2 x 30 steps (about 10 s): CI's marked lane runs it
def test_libero_steps_our_rows_as_it_steps_upstreams_lists(plugins, served):
    from conflictbench.sim.libero_env import EnvSettings, configure_process, make_env
    from conflictbench.sim.worker import NOOP_ACTION
    from conflictbench.tasks.libero.base_tasks import base_task, load_init_states

    settings = EnvSettings(needs_images=False)
    configure_process(settings)
    state, policies = served
    policy = policies["pi05", 5]
    observation = observation_of(*synthetic_observations()[2])
    chunks = replies(10, np.float32, seeds=range(2))[-4:]
    ours, theirs = [], []
    for actions in chunks:
        frame = reply_frame(actions)
        ours += our_executed(plugins, policy, state, frame, observation)
        theirs += upstream.executed(upstream.decode(frame), replan_steps=5)
    task = base_task("libero_spatial", 0)
    env = make_env(task.bddl_path, settings)
    try:
        finals = []
        for noop, sequence in ((list(upstream.DUMMY_ACTION), theirs), (NOOP_ACTION, ours)):
            env.seed(7)
            env.reset()
            env.set_init_state(load_init_states("libero_spatial", 0)[0])
            for _ in range(upstream.NUM_STEPS_WAIT):
                env.step(noop)
            for action in sequence:
                env.step(action)
            data = env.sim.data
            finals.append(np.concatenate([data.qpos, data.qvel, data.qacc_warmstart, data.ctrl]).copy())
    finally:
        env.close()
    assert bits(finals[0]).tobytes() == bits(finals[1]).tobytes()
