"""The learned subject: what it sees (features), that it reads nothing of its task, and that it reads the words."""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from testing_support import reference_spec

from conflictbench.core import EpisodeRecord, Observation, PolicyTraits, SceneState, UserError
from conflictbench.policies.subject.features import (
    ARM_NUMBERS,
    ENTITY_NUMBERS,
    UNKNOWN,
    Entities,
    Vocabulary,
    arm_numbers,
    entity_numbers,
)
from conflictbench.policies.subject.model import decode
from conflictbench.policies.subject.policy import SubjectConfig, SubjectPolicy, shipped_weights
from conflictbench.policies.subject.prepare import prepare
from conflictbench.policies.subject.record import FAILED, Recording, RecordingExpert


def test_words_are_lower_case_runs_and_unknown_words_share_one_id():
    vocabulary = Vocabulary.build(["Put the bowl on the plate", "akita black bowl 1"])
    assert vocabulary.words[:2] == ("<pad>", "<unknown>")
    ids = vocabulary.ids("put THE bowl, on the zebra!")
    assert [vocabulary.words[i] for i in ids] == ["put", "the", "bowl", "on", "the", "<unknown>"]
    assert list(vocabulary.ids("")) == [UNKNOWN]  # an empty instruction is one unknown word, not nothing


def test_entity_names_become_their_words_in_a_fixed_order_of_kinds():
    vocabulary = Vocabulary.build(["akita black bowl 1 main table plate region flat stove button"])
    entities = Entities(("akita_black_bowl_1",), ("main_table_plate_region",), ("flat_stove_1_button",))
    names = entities.name_ids(vocabulary)
    assert [vocabulary.words[i] for i in names[0] if i] == ["akita", "black", "bowl", "1"]
    assert [vocabulary.words[i] for i in names[1] if i] == ["main", "table", "plate", "region"]
    assert list(entities.kinds()) == [1, 2, 3]


def test_entity_numbers_hold_positions_relative_positions_orientation_and_joints():
    poses = np.array([[0.1, 0.2, 0.9, 1.0, 0.0, 0.0, 0.0], [0.3, -0.1, 0.95, 0.0, 0.0, 0.0, 1.0]])
    regions = np.array([[0.0, 0.0, 0.9]])
    joints = np.array([0.07])
    eef = np.array([0.12, 0.2, 1.0])
    out = entity_numbers(poses, regions, joints, eef)
    assert out.shape == (4, ENTITY_NUMBERS)
    np.testing.assert_allclose(out[0, :3], poses[0, :3], atol=1e-6)
    np.testing.assert_allclose(out[0, 3:6], poses[0, :3] - eef, atol=1e-6)
    np.testing.assert_allclose(out[0, 6:9], [-0.2, 0.0, -1.0], atol=1e-6)  # within 10 cm at 10x, clipped beyond
    np.testing.assert_allclose(out[1, 9:13], [0, 0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(out[2, 3:6], regions[0] - eef, atol=1e-6)
    assert out[2, 9:13].tolist() == [0, 0, 0, 0]  # a region has no orientation
    assert out[3, 13] == pytest.approx(0.07) and not out[3, :13].any()  # a joint is its position alone
    frames = entity_numbers(np.stack([poses] * 3), np.stack([regions] * 3), np.stack([joints] * 3), np.stack([eef] * 3))
    np.testing.assert_array_equal(frames[1], out)  # a whole episode at once, frame by frame the same


def test_arm_numbers_rotation_is_the_quaternions_matrix():
    quat = Rotation.from_euler("xyz", [3.0, 0.2, -1.1]).as_quat()  # x, y, z, w: robosuite's order
    out = arm_numbers(np.array([0.1, 0.2, 1.1]), quat, np.array([0.03, -0.03]))
    assert out.shape == (ARM_NUMBERS,)
    np.testing.assert_allclose(out[3:12], Rotation.from_quat(quat).as_matrix().reshape(9), atol=1e-6)
    np.testing.assert_allclose(out[[0, 1, 2, 12, 13]], [0.1, 0.2, 1.1, 0.03, -0.03], atol=1e-6)


class Untouchable:
    """Any read of it fails the test: what the subject must never look at."""

    def __getattr__(self, name):
        raise AssertionError(f"the subject read privileged.{name}")


def observation(instruction: str, *, privileged=None, step: int = 0) -> Observation:
    scene = SceneState(
        body_poses={
            "akita_black_bowl_1": np.array([0.0, 0.1, 0.9, 1, 0, 0, 0]),
            "plate_1": np.array([0.1, -0.1, 0.9, 1, 0, 0, 0]),
        },
        site_positions={"main_table_plate_region": np.array([0.1, -0.1, 0.9])},
        joint_positions={"flat_stove_1_button": 0.0},
    )
    return Observation(
        step=step,
        instruction=instruction,
        eef_pos=np.array([-0.1, 0.0, 1.1]),
        eef_quat=np.array([1.0, 0.0, 0.0, 0.0]),
        gripper_qpos=np.array([0.04, -0.04]),
        state=np.zeros(8),
        privileged=privileged,
        scene=scene,
        episode_id="e",
        suite="libero_goal",
    )


@pytest.fixture(scope="module")
def subject() -> SubjectPolicy:
    return SubjectPolicy()


def test_the_subject_declares_the_scene_and_not_the_task(subject):
    traits = PolicyTraits(subject)
    assert traits.needs_scene_state and not traits.needs_privileged and not traits.needs_images
    digest = hashlib.sha256(shipped_weights().read_bytes()).hexdigest()[:16]
    assert subject.identity == {"weights_sha256": digest}  # a retrained subject's episodes get ids of their own


def test_act_reads_no_goal_case_or_expert_and_is_deterministic(subject):
    seen = observation("put the bowl on the plate", privileged=Untouchable())
    first = subject.act(seen)
    assert first.shape == (1, 7) and first[0, 6] in (-1.0, 1.0)
    np.testing.assert_array_equal(subject.act(seen), first)
    np.testing.assert_array_equal(subject.act(dataclasses.replace(seen, privileged=None)), first)


def test_a_batch_answers_each_observation_as_alone(subject):
    a = observation("put the bowl on the plate")
    b = dataclasses.replace(observation("turn on the stove"), episode_id="f")  # draws of its own
    b = dataclasses.replace(b, scene=dataclasses.replace(b.scene, joint_positions={}))  # fewer entities: padding
    together = subject.act_batch([a, b])
    np.testing.assert_array_equal(together[0], subject.act(a))  # bit for bit: batching never changes an action
    np.testing.assert_array_equal(together[1], subject.act(b))


def test_bad_settings_are_one_line(tmp_path):
    with pytest.raises(UserError, match="no subject weights"):
        SubjectPolicy(SubjectConfig(weights=str(tmp_path / "missing.npz")))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(UserError, match="is not a subject's weights file"):
        SubjectPolicy(SubjectConfig(weights=str(tmp_path / "junk.npz")))
    stored = dict(np.load(shipped_weights()))
    del stored["word.weight"]
    np.savez(tmp_path / "incomplete.npz", **stored)
    with pytest.raises(UserError, match="is not a subject's weights file: KeyError"):  # at loading, not in episodes
        SubjectPolicy(SubjectConfig(weights=str(tmp_path / "incomplete.npz")))
    with pytest.raises(UserError, match="model.execute must be between 1 and"):
        SubjectPolicy(SubjectConfig(execute=0))
    assert shipped_weights().is_file()


@pytest.mark.e2e
@pytest.mark.sim
def test_in_one_scene_the_words_decide_where_the_arm_goes(play, tmp_path):
    """libero_goal task 2 (the wine bottle on the cabinet) played with its own words and with task 6's (the cream
    cheese in the bowl): the first thing to reach differs, which the first 100 steps show."""
    own = reference_spec("libero_goal", 2, 0)
    other = dataclasses.replace(own, base_instruction=reference_spec("libero_goal", 6, 0).base_instruction)
    (_, store) = play("subject", [own, other], settings={"weights": None}, store_dir=tmp_path / "s", max_steps=100)
    paths = {r.instruction: r.eef_pos for r in store.records()}
    a, b = paths[own.instruction], paths[other.instruction]
    steps = min(len(a), len(b))
    assert steps > 50
    apart = np.linalg.norm(a[:steps] - b[:steps], axis=1)
    assert apart.max() > 0.05, apart.max()  # 5 cm apart somewhere (by step 10, 0.5 m in 100): the words moved it


def test_decoding_picks_one_mode_of_the_bins_never_their_mean():
    chunk, bins = 2, 5  # bins at -1, -0.5, 0, 0.5, 1
    raw = np.full((1, chunk, 6 * bins + 1), -10.0)
    logits = raw[..., : 6 * bins].reshape(1, chunk, 6, bins)
    logits[..., 4] = 0.0  # every value: +1 ...
    logits[0, 0, 0, 0] = 0.5  # ... but the first step's first value has a likelier mode at -1 (not 0, the mean)
    raw[..., : 6 * bins] = logits.reshape(1, chunk, 6 * bins)
    raw[0, :, -1] = [-2.0, 3.0]  # the gripper opens now, closes a step later
    out = decode(raw.reshape(1, -1), chunk, bins)
    assert out.shape == (1, chunk, 7)
    assert out[0, 0, 0] == pytest.approx(-1.0, abs=1e-3) and out[0, 1, 0] == pytest.approx(1.0, abs=1e-3)
    assert out[0, 0, 6] == -1.0 and out[0, 1, 6] == 1.0
    led = decode(raw.reshape(1, -1), chunk, bins, gripper_lead=1)
    assert led[0, 0, 6] == 1.0 and led[0, 1, 6] == 1.0  # a step early; the chunk's last is kept at its end
    raw[0, 0, 1 * bins + 2 : 1 * bins + 4] = [4.0, 4.0]  # two neighbouring bins equally likely: between them
    assert decode(raw.reshape(1, -1), chunk, bins)[0, 0, 1] == pytest.approx(0.25, abs=1e-3)


def test_decoding_an_edge_bin_weighs_it_once():
    chunk, bins = 1, 5
    raw = np.full((1, chunk, 6 * bins + 1), -30.0)
    raw[0, 0, 0:2] = [3.0, 3.0]  # the first value: bins -1 and -0.5 equally likely, the edge bin listed first
    assert decode(raw.reshape(1, -1), chunk, bins)[0, 0, 0] == pytest.approx(-0.75, abs=1e-6)  # not -0.83


def test_the_gripper_is_a_draw_from_its_probability():
    chunk, bins = 4, 5
    raw = np.zeros((1, chunk, 6 * bins + 1))
    raw[0, :, -1] = [0.0, 0.0, 2.0, 2.0]  # closed with probability 0.5, 0.5, 0.88, 0.88
    draws = np.array([[0.3, 0.7, 0.8, 0.95]])
    assert decode(raw.reshape(1, -1), chunk, bins, draws=draws)[0, :, 6].tolist() == [1.0, -1.0, 1.0, -1.0]
    assert decode(raw.reshape(1, -1), chunk, bins)[0, 2:, 6].tolist() == [1.0, 1.0]  # no draws: the likelier
    raw[0, :, -1] = [-200.0, -200.0, 200.0, 200.0]  # confident either way: no overflow, draws at the ends
    with np.errstate(all="raise"):
        out = decode(raw.reshape(1, -1), chunk, bins, draws=np.array([[0.0, 0.5, 0.5, 0.999]]))
    assert out[0, :, 6].tolist() == [1.0, -1.0, 1.0, 1.0]


def test_act_closes_or_opens_the_gripper_by_its_draws(subject, monkeypatch):
    seen = observation("put the bowl on the plate")
    monkeypatch.setattr(subject, "draws", lambda o: np.zeros((1, subject.network.chunk)))
    assert subject.act(seen)[0, 6] == 1.0  # a draw of 0: closed, however unlikely
    monkeypatch.setattr(subject, "draws", lambda o: np.ones((1, subject.network.chunk)))
    assert subject.act(seen)[0, 6] == -1.0  # a draw of 1: open, however likely closed


def test_the_gripper_draws_come_from_the_episode_and_step_never_call_order(subject):
    seen = observation("put the bowl on the plate")
    first = subject.draws(seen)
    assert first.shape == (1, subject.network.chunk) and ((0 <= first) & (first < 1)).all()
    subject.draws(observation("put the bowl on the plate", step=9))  # another decision in between
    np.testing.assert_array_equal(subject.draws(seen), first)
    assert not np.array_equal(subject.draws(observation("put the bowl on the plate", step=1)), first)
    assert not np.array_equal(subject.draws(dataclasses.replace(seen, episode_id="f")), first)
    with pytest.raises(UserError, match="names no episode"):
        subject.draws(dataclasses.replace(seen, episode_id=""))
    reseeded = SubjectPolicy(SubjectConfig(seed=1))
    assert not np.array_equal(reseeded.draws(seen), first)
    assert SubjectPolicy(SubjectConfig(sample_gripper=False)).draws(seen) is None


def test_training_frames_are_exactly_what_the_policy_computes_when_acting(subject):
    """A recorded episode through prepare() and the same frames as live observations through the policy."""
    rng = np.random.default_rng(0)
    frames = 4
    objects, regions, joints = ["plate_1", "akita_black_bowl_1"], ["main_table_plate_region"], ["flat_stove_1_button"]
    quat = rng.normal(size=(frames, 2, 4))
    episode = {
        "instruction": np.array("put the bowl on the plate"),
        "objects": np.array(sorted(objects)),
        "regions": np.array(regions),
        "joints": np.array(joints),
        "object_poses": np.concatenate(
            [rng.uniform(-0.3, 1, (frames, 2, 3)), quat / np.linalg.norm(quat, axis=-1, keepdims=True)], -1
        ),
        "region_positions": rng.uniform(-0.3, 1, (frames, 1, 3)),
        "joint_positions": rng.uniform(0, 0.1, (frames, 1)),
        "eef_pos": rng.uniform(-0.3, 1.2, (frames, 3)),
        "eef_quat": np.tile([0.0, 1.0, 0.0, 0.0], (frames, 1)),
        "gripper_qpos": np.tile([0.04, -0.04], (frames, 1)),
        "label": np.zeros((frames, 7)),
    }
    episode = {k: v.astype(np.float32) if v.dtype == np.float64 else v for k, v in episode.items()}  # as recorded
    prepared = prepare([episode], subject.vocabulary)
    names = [str(n) for n in episode["objects"]]
    for t in range(frames):
        scene = SceneState(
            body_poses={n: episode["object_poses"][t, i].astype(np.float64) for i, n in enumerate(names)},
            site_positions={regions[0]: episode["region_positions"][t, 0].astype(np.float64)},
            joint_positions={joints[0]: float(episode["joint_positions"][t, 0])},
        )
        seen = dataclasses.replace(
            observation("put the bowl on the plate"),
            scene=scene,
            eef_pos=episode["eef_pos"][t].astype(np.float64),
            eef_quat=episode["eef_quat"][t].astype(np.float64),
        )
        live = subject.inputs(seen)
        entities = live.kinds.shape[1]
        np.testing.assert_array_equal(live.entities[0], prepared["entities"][t, :entities])
        np.testing.assert_array_equal(live.names[0], prepared["names"][t, :entities])
        np.testing.assert_array_equal(live.kinds[0], prepared["kinds"][t, :entities])
        assert not prepared["kinds"][t, entities:].any()  # the rest is padding
        np.testing.assert_array_equal(live.arm[0], prepared["arm"][t])
        np.testing.assert_array_equal(live.text[0], prepared["text"][t, : live.text.shape[1]])


def test_a_demonstration_lands_whole_a_failure_is_listed_and_an_error_leaves_nothing(tmp_path):
    recorder = RecordingExpert(tmp_path, noise=0.2)

    def ended(episode_id: str, state: int, **outcome) -> EpisodeRecord:
        recording = Recording("turn on the stove", Entities(("flat_stove_1",), (), ("flat_stove_1_button",)))
        recording.add(label=np.ones(7), executed=np.zeros(7))
        recorder._recordings[episode_id] = recording
        record = EpisodeRecord(
            policy="expert-recording", suite="libero_goal", task_id=7, init_state=state, prompt="p0",
            instruction="turn on the stove",
            episode_id=episode_id, **outcome,
        )  # fmt: skip
        recorder.finish(record)
        return record

    ended("a", 12, success=True)
    ended("b", 13, success=False)
    ended("c", 14, success=True, error="worker lost")
    assert sorted(p.name for p in tmp_path.iterdir()) == [FAILED, "libero_goal-07-012.npz"]  # no partial file left
    assert (tmp_path / FAILED).read_text().split() == ["libero_goal-07-013"]
    with np.load(tmp_path / "libero_goal-07-012.npz") as demo:
        assert str(demo["instruction"]) == "turn on the stove" and demo["label"].shape == (1, 7)
        assert list(demo["joints"]) == ["flat_stove_1_button"]
