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

import json_numpy
import numpy as np
import pytest
import upstream_openvla as upstream
import upstream_openvla_oft as upstream_oft
from openvla_upstream_inputs import (
    ACTION_STATS,
    GOLDEN,
    INSTRUCTIONS,
    PROPRIO_STATS,
    REAL_STATES,
    as_received,
    bits,
    check_same_steps,
    deploy_body,
    deploy_like,
    observation_of,
    oft_chunks,
    oft_policy,
    openvla_replies,
    ours_executed,
    raw_observations,
    same_payload,
    small_observation,
    synthetic_states,
    tf_image_functions,
)

import conflictbench
import conflictbench_openvla.client as openvla_client
from conflictbench.hosting import openvla_family as family
from conflictbench_openvla import backend, processing
from conflictbench_openvla.client import OpenVlaConfig, load


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


@pytest.fixture(scope="module")
def tf_images():
    return tf_image_functions()


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
