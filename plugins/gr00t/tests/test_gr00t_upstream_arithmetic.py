"""The gr00t client against GR00T N1.7's own LIBERO client, bit for bit (issue #43).

Upstream's side is ``upstream_gr00t.py`` (NVIDIA/Isaac-GR00T@23ace64, tag ``n1.7-release``: ``rollout_policy.py``,
``MultiStepWrapper``, ``LiberoEnv`` and gymnasium 0.29.1's vector env), restated from upstream's source by a separate
reader who never read this plugin. Our side is the code a run executes: the policy loaded as a run loads it
(``model.server=tcp://...``), its requests sent by our ZeroMQ transport to a server that frames as NVIDIA's
``PolicyServer`` does (msgpack, arrays as ``np.save`` bytes: ``nvidia_standin_server.to_bytes``/``from_bytes``), the
replies decoded by our transport and client, then the runner's ``ask_policy`` and ``reply_for`` (``as_action_chunk``
and the post-processing chain) and the pickling of the worker's pipe, giving the rows the worker passes to
``env.step``. robosuite's ``env.step`` reads an action only through ``np.clip`` against float64 bounds and
``np.sign`` (robosuite 1.4.0 controllers/base_controller.py:120, models/grippers/panda_gripper.py:55-56), i.e. as
float64: upstream passes a float32 array and we a float64 row, so both are compared after ``np.asarray(x,
np.float64)``, by bit pattern, and the marked test steps LIBERO itself with both.

OUT: float32 replies (NVIDIA's server casts every action to float32, gr00t_policy.py:419-422), (1, 16, 1) per key:
values at LIBERO's action bounds (+-1, +-0.9375, their neighbours), the gripper at, just below and just above the
[0, 1] midpoint 0.5 (``nextafter``), at 0, 1, -0.0, subnormals, out of [0, 1], float32's extremes, and many random
values over several seeds; ``model.action_steps`` 1, 8 (upstream's) and 16.
IN: one real LIBERO observation (``golden/libero_observation.npz``: libero_goal task 0, initial state 0, five steps of
a fixed action, LIBERO's OffScreenRenderEnv at 256 px) and synthetic ones with realistic content (smooth renders
with sensor noise, edges, saturated colours; quaternions at and past w = +-1; states halfway between two float32s);
the whole request's bytes are compared, not only the decoded values.
"""

from __future__ import annotations

import contextlib
import pickle
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import zmq

sys.path.insert(0, str(Path(__file__).parent))
import upstream_gr00t as upstream  # noqa: E402
from nvidia_standin_server import from_bytes, to_bytes  # noqa: E402

import conflictbench  # noqa: E402
import conflictbench_gr00t.client as gr00t_client  # noqa: E402
from conflictbench.core import PolicyTraits  # noqa: E402
from conflictbench.sim.deciding import ask_policy, reply_for  # noqa: E402
from conflictbench.sim.messages import Actions, EpisodeJob  # noqa: E402
from conflictbench.sim.plan import EpisodeSpec  # noqa: E402
from conflictbench.sim.slots import Item  # noqa: E402
from conflictbench.testing import EDGE_QUATERNION_W, edge_quaternion, worker_observation  # noqa: E402
from conflictbench_gr00t.client import Gr00tConfig, load  # noqa: E402

GOLDEN = Path(__file__).resolve().parent / "golden"
REAL_OBSERVATION = GOLDEN / "libero_observation.npz"
#: The chunk NVIDIA's server answers for LIBERO (upstream's ACTION_HORIZON: the libero_sim embodiment's 16).
HORIZON = upstream.ACTION_HORIZON
ACTION_STEPS = (1, upstream.N_ACTION_STEPS, HORIZON)
NOISE_SEED = "conflictbench/noise_seed"
INSTRUCTIONS = (
    "put the bowl on the plate",
    "Turn On the Stove and put the MOKA pot on it.",
    "  open the top drawer and put the bowl inside \n",
    "İstanbul: put the crème brûlée in the ΣΟΦΑ bowl",
    "",
)


# -- a server framing as NVIDIA's PolicyServer does ---------------------------------------------------------------


@contextlib.contextmanager
def nvidia_like():
    """NVIDIA's ``PolicyServer`` framing (Isaac-GR00T@23ace64 gr00t/policy/server_client.py:130-164): a REP socket,
    ``ping`` answered, an unknown endpoint (our metadata) answered ``{"error": ...}``, ``get_action`` answered with
    the next queued ``[action, info]``; each get_action request is kept as received (its bytes)."""
    state = {"requests": [], "replies": []}
    context = zmq.Context()
    socket = context.socket(zmq.REP)
    port = socket.bind_to_random_port("tcp://127.0.0.1")
    stop = threading.Event()

    def serve():
        while not stop.is_set():
            if not socket.poll(50):
                continue
            message = socket.recv()
            request = from_bytes(message)
            endpoint = request.get("endpoint", "get_action")
            if endpoint == "ping":
                socket.send(to_bytes({"status": "ok", "message": "Server is running"}))
            elif endpoint == "get_action":
                state["requests"].append(message)
                socket.send(to_bytes(state["replies"].pop(0)))
            else:
                socket.send(to_bytes({"error": f"Unknown endpoint: {endpoint}"}))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield state, f"tcp://127.0.0.1:{port}"
    finally:
        stop.set()
        thread.join(5)
        socket.close(linger=0)
        context.term()


@pytest.fixture(scope="module")
def plugins():
    """The plugins a run with this plugin alone has: the built-ins and this plugin (no action post-processor)."""
    return conflictbench.plugins(entry_points=False, extra=[gr00t_client])


@pytest.fixture(scope="module")
def served():
    with nvidia_like() as (state, url):
        policies = {}
        try:
            for steps in ACTION_STEPS:
                config = Gr00tConfig(server=url, checkpoint="nvidia-like", action_steps=steps, connect_retries=0)
                policies[steps] = load("gr00t", config)
            yield state, policies
        finally:
            for policy in policies.values():
                policy.close()


def item_for(instruction: str = INSTRUCTIONS[0]) -> Item:
    spec = EpisodeSpec("libero_goal", 0, 0, "p0", instruction)
    job = EpisodeJob("e", "libero_goal", 0, "x.bddl", 0, 7, instruction, (), (), 0, 720, False)
    return Item(spec, job)


# -- observations -------------------------------------------------------------------------------------------------


def real_observation() -> tuple[dict, str]:
    recorded = np.load(REAL_OBSERVATION)
    raw = {key: recorded[key] for key in recorded.files if key.startswith(("agentview", "robot0"))}
    return raw, str(recorded["language"])


def rendered_like(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A render-like uint8 image: smooth shading, hard edges, saturated patches and sensor noise."""
    y, x = np.mgrid[0:size, 0:size] / size
    base = np.stack([120 + 100 * np.sin(3 * x + c) * np.cos(2 * y - c) for c in rng.uniform(0, 3, 3)], axis=-1)
    base[(x - rng.uniform()) ** 2 + (y - rng.uniform()) ** 2 < 0.03] = rng.integers(0, 256, 3)  # an object's edge
    base[: size // 8, : size // 8] = [255, 0, 0]  # saturated, in LIBERO's first rows: the upright view's bottom
    base += rng.normal(0, 6, base.shape)
    return np.clip(np.rint(base), 0, 255).astype(np.uint8)


def halfway(value: float) -> float:
    """The float64 exactly halfway between the float32 at ``value`` and the next one up: a float32 cast's tie."""
    low = np.float32(value)
    return (float(low) + float(np.nextafter(low, np.float32(np.inf)))) / 2


def synthetic_observations() -> list[tuple[dict, str]]:
    """LIBERO observation dicts (images upside down, as rendered): w at +-1, past +-1, next to 1, random; states
    halfway between two float32s (the cast's ties) and ordinary ones."""
    out = []
    for seed, w in enumerate([*EDGE_QUATERNION_W, *[None] * 5]):
        rng = np.random.default_rng(seed)
        quat = edge_quaternion(rng, w)
        position = rng.uniform([-0.3, -0.3, 0.8], [0.3, 0.3, 1.3])
        fingers = np.array([0.039 * seed / 9, -0.0387 * seed / 9])
        if seed % 2:
            position, fingers = np.array([halfway(v) for v in position]), np.array([halfway(v) for v in fingers])
        raw = {
            "agentview_image": rendered_like(rng),
            "robot0_eye_in_hand_image": rendered_like(rng),
            "robot0_eef_pos": position,
            "robot0_eef_quat": quat,
            "robot0_gripper_qpos": fingers,
            "robot0_joint_pos": rng.normal(size=7),
        }
        out.append((raw, INSTRUCTIONS[seed % len(INSTRUCTIONS)]))
    return out


def observation_of(raw: dict, instruction: str, step: int = 0):
    return worker_observation(raw, instruction, suite="libero_goal", step=step, sampling_key="gr00t-upstream")


# -- replies ------------------------------------------------------------------------------------------------------


def special_values() -> np.ndarray:
    """LIBERO's action bounds and their neighbours, zeros, subnormals, float32's extremes (float32)."""
    f = np.float32
    one, zero, bound = f(1.0), f(0.0), f(0.9375)
    return np.array(
        [one, -one, np.nextafter(one, zero), np.nextafter(one, f(2)), bound, -bound, np.nextafter(bound, one),
         zero, -zero, np.nextafter(zero, one), np.nextafter(zero, -one), f(1e-30), f(0.3), f(-0.7),
         np.finfo(f).max, -np.finfo(f).max],
        dtype=f,
    )  # fmt: skip


def gripper_values() -> np.ndarray:
    """The dataset's gripper in [0, 1] around the midpoint 0.5 that upstream's sign(2g - 1) splits (float32)."""
    f = np.float32
    half = f(0.5)
    return np.array(
        [half, np.nextafter(half, f(0)), np.nextafter(half, f(1)), f(0.0), f(1.0), -f(0.0),
         np.nextafter(f(0), f(1)), np.nextafter(f(0), f(-1)), f(0.25), f(0.75), f(-0.1), f(1.1),
         np.nextafter(np.nextafter(half, f(0)), f(0)), np.finfo(f).max, -np.finfo(f).max, f(0.5000001)],
        dtype=f,
    )  # fmt: skip


def replies(seeds=range(4)) -> list[dict]:
    """``[action, info]`` replies, (1, 16, 1) float32 per key: the special values cycling through every key, then
    random ones (arm deltas at several scales, the gripper spread over [0, 1] and past it)."""
    special, gripper = special_values(), gripper_values()
    chunks = []
    for k in range(len(upstream.ACTION_KEYS)):
        chunk = np.stack([np.roll(special, k + j) for j in range(6)] + [np.roll(gripper, k)], axis=1)
        chunks.append(chunk)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        chunk = rng.normal(0, 0.5, (HORIZON, 7)) * rng.choice([1e-8, 1e-3, 1.0, 10.0], (HORIZON, 1))
        chunk[:, 6] = rng.choice([0.0, 1.0, 0.5, rng.uniform(-0.2, 1.2)], HORIZON)
        chunks.append(chunk.astype(np.float32))
    return [
        [{key: np.ascontiguousarray(chunk[None, :, i : i + 1]) for i, key in enumerate(upstream.ACTION_KEYS)}, {}]
        for chunk in chunks
    ]


def our_executed(plugins, policy, state, reply, observation) -> list[np.ndarray]:
    """The rows our worker passes to env.step for ``reply`` (through the runner and the worker's pipe)."""
    state["replies"].append(reply)
    (raw,) = ask_policy(policy, [observation], batched=True)
    decided = pickle.loads(pickle.dumps(reply_for(plugins, policy.name, item_for(), observation, raw)))
    assert isinstance(decided, Actions), decided
    return list(decided.executed)


def bits(action) -> np.ndarray:
    return np.asarray(action, dtype=np.float64).view(np.uint64)


# -- OUT: reply -> env.step ---------------------------------------------------------------------------------------


# upstream's own arithmetic warns there: 2 * (g - 0.0) of float32's largest gripper value, stored back in float32
@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")
@pytest.mark.parametrize("steps", ACTION_STEPS)
def test_every_executed_action_is_upstreams_to_the_bit(steps, plugins, served):
    state, policies = served
    observation = observation_of(*synthetic_observations()[5])
    compared = 0
    for reply in replies():
        ours = our_executed(plugins, policies[steps], state, reply, observation)
        theirs = upstream.executed(from_bytes(to_bytes(reply)), n_action_steps=steps)
        assert len(ours) == len(theirs) == steps
        for i, (mine, its) in enumerate(zip(ours, theirs)):
            # what reaches env.step: upstream a float32 (7,) ndarray, ours a float64 row (shared as_action_chunk)
            assert its.dtype == np.float32 and its.shape == (7,)
            assert mine.dtype == np.float64 and mine.shape == (7,)
            assert bits(mine).tobytes() == bits(its).tobytes(), (i, mine, its)
            compared += mine.size
    assert compared == steps * 7 * len(replies())


def test_the_gripper_at_and_around_the_midpoint_is_upstreams(plugins, served):
    # the threshold on its own, so that a failure names it: 0.5 opens nothing and closes nothing (-0.0, upstream's
    # -sign(0)), its neighbours either side close (+1) and open (-1)
    state, policies = served
    observation = observation_of(*synthetic_observations()[0])
    half = np.float32(0.5)
    gripper = np.array([half, np.nextafter(half, np.float32(0)), np.nextafter(half, np.float32(1)), 0, 1, 0, 1, 0.5])
    reply = [{key: np.zeros((1, HORIZON, 1), np.float32) for key in upstream.ACTION_KEYS}, {}]
    reply[0]["action.gripper"][0, :8, 0] = gripper.astype(np.float32)
    ours = our_executed(plugins, policies[8], state, reply, observation)
    theirs = upstream.executed(reply)
    assert [bits(a)[6] for a in ours] == [bits(a)[6] for a in theirs]
    assert [float(a[6]) for a in ours] == [-0.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, -0.0]
    assert np.signbit(ours[0][6]) and np.signbit(theirs[0][6])


def test_a_chunk_shorter_than_the_steps_executed_is_refused_as_upstream_refuses_it(plugins, served):
    # upstream's MultiStepWrapper indexes value[step] for every step (IndexError past the chunk: the rollout stops
    # with none of it executed); ours refuses such a reply in one line: a client failure, never scored
    state, policies = served
    observation = observation_of(*synthetic_observations()[1])
    reply = [{key: np.zeros((1, 5, 1), np.float32) for key in upstream.ACTION_KEYS}, {}]
    with pytest.raises(IndexError):
        upstream.executed(reply, n_action_steps=8)
    state["replies"].append(reply)
    (raw,) = ask_policy(policies[8], [observation], batched=True)
    decided = reply_for(plugins, "gr00t", item_for(), observation, raw)
    assert not isinstance(decided, Actions) and decided.kind == "client", decided
    assert "5 actions, fewer than model.action_steps=8" in decided.reason


# -- IN: LIBERO's observation -> the request ----------------------------------------------------------------------


def our_request(policy, state, observation) -> bytes:
    """The bytes our client sends NVIDIA's server for ``observation`` (the reply is a dummy chunk)."""
    state["replies"].append([{key: np.zeros((1, HORIZON, 1), np.float32) for key in upstream.ACTION_KEYS}, {}])
    (raw,) = ask_policy(policy, [observation], batched=True)
    assert np.shape(raw) == (policy.action_steps, 7), raw
    return state["requests"][-1]


def check_request(sent: bytes, raw: dict, instruction: str) -> None:
    """``sent`` is upstream's request for ``raw`` to the byte, but for the noise seed in ``options``."""
    request = from_bytes(sent)
    observation, options = request["data"]["observation"], request["data"]["options"]
    expected = upstream.request({key: np.copy(value) for key, value in raw.items()}, instruction)
    assert list(observation) == list(expected)  # the key order gymnasium's spaces.Dict gives upstream's
    for key, value in expected.items():
        if isinstance(value, np.ndarray):
            got = observation[key]
            assert (got.dtype, got.shape) == (value.dtype, value.shape), key
            assert got.tobytes() == value.tobytes(), key
        else:
            assert list(observation[key]) == list(value), key
    assert set(options) == {NOISE_SEED} and isinstance(options[NOISE_SEED], int)  # our only addition
    assert sent == to_bytes(upstream.envelope(expected, options=options)), "the request's bytes"


def test_the_request_is_upstreams_to_the_byte_but_the_noise_seed(served):
    state, policies = served
    for raw, instruction in synthetic_observations():
        check_request(our_request(policies[8], state, observation_of(raw, instruction)), raw, instruction)


def test_a_real_libero_observation_is_sent_as_upstream_sends_it(served):
    state, policies = served
    raw, instruction = real_observation()
    check_request(our_request(policies[8], state, observation_of(raw, instruction)), raw, instruction)


# -- the episode's constants --------------------------------------------------------------------------------------


def test_the_episode_constants_are_upstreams(served):
    traits = PolicyTraits(served[1][upstream.N_ACTION_STEPS])  # as a run loads it, model.max_steps left at 0
    assert traits.warmup_steps == upstream.NUM_STEPS_WAIT
    assert traits.image_size == upstream.CAMERA_HEIGHT == upstream.CAMERA_WIDTH
    assert Gr00tConfig().action_steps == upstream.N_ACTION_STEPS
    assert traits.max_steps == {suite: upstream.MAX_EPISODE_STEPS_BY_SUITE[suite] for suite in traits.max_steps}
    assert set(traits.max_steps) == set(upstream.MAX_EPISODE_STEPS_BY_SUITE) - {"libero_90"}
    # A difference the README names: upstream resets LIBERO to a random placement, we to the suite's initial states.
    assert upstream.USES_BENCHMARK_INIT_STATES is False


# -- env.step itself (a real LIBERO env) --------------------------------------------------------------------------


@pytest.mark.sim
@pytest.mark.slow  # builds a LIBERO env and plays 2 x 48 steps (about 5 s here): CI's marked lane runs it
def test_libero_steps_our_float64_rows_as_it_steps_upstreams_float32_arrays(plugins, served):
    from conflictbench.sim.libero_env import EnvSettings, configure_process, make_env
    from conflictbench.tasks.libero.base_tasks import base_task, load_init_states

    settings = EnvSettings(needs_images=False)
    configure_process(settings)
    state, policies = served
    observation = observation_of(*synthetic_observations()[2])
    ours, theirs = [], []
    for reply in replies(seeds=range(3))[-6:]:
        ours += our_executed(plugins, policies[8], state, reply, observation)
        theirs += upstream.executed(from_bytes(to_bytes(reply)))
    assert {a.dtype for a in theirs} == {np.dtype(np.float32)} and {a.dtype for a in ours} == {np.dtype(np.float64)}
    task = base_task("libero_goal", 0)
    env = make_env(task.bddl_path, settings)
    try:
        finals = []
        for sequence in (theirs, ours):
            env.seed(7)
            env.reset()
            env.set_init_state(load_init_states("libero_goal", 0)[0])
            for action in sequence:
                env.step(action)
            data = env.sim.data
            finals.append(np.concatenate([data.qpos, data.qvel, data.qacc_warmstart, data.ctrl]).copy())
    finally:
        env.close()
    assert bits(finals[0]).tobytes() == bits(finals[1]).tobytes()


def record_real_observation(path: Path = REAL_OBSERVATION) -> None:
    """Write ``golden/libero_observation.npz``: libero_goal task 0, initial state 0, seed 7, LIBERO's
    OffScreenRenderEnv at 256 px, after five steps of a fixed action (the fingers and the arm moving).

        MUJOCO_GL=egl .venv/bin/python plugins/gr00t/tests/test_gr00t_upstream_arithmetic.py record
    """
    from conflictbench.sim.libero_env import prepare_libero_import
    from conflictbench.tasks.libero.base_tasks import base_task, load_init_states

    prepare_libero_import()
    from libero.libero.envs import OffScreenRenderEnv

    task = base_task("libero_goal", 0)
    env = OffScreenRenderEnv(bddl_file_name=task.bddl_path, camera_heights=256, camera_widths=256)
    try:
        env.seed(7)
        env.reset()
        raw = env.set_init_state(load_init_states("libero_goal", 0)[0])
        for _ in range(5):
            raw, *_ = env.step([0.2, -0.1, 0.3, 0.05, 0.0, -0.05, 1.0])
    finally:
        env.close()
    keys = ("agentview_image", "robot0_eye_in_hand_image", "robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos",
            "robot0_joint_pos")  # fmt: skip
    np.savez_compressed(path, language=np.array(task.language), **{key: raw[key] for key in keys})


if __name__ == "__main__" and sys.argv[1:] == ["record"]:
    record_real_observation()
