"""The scripted expert's geometry and control helpers, on hand-made inputs (no simulator)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conflictbench.core import Observation, SiteInfo
from conflictbench.policies.scripted.control import nearest_theta, servo
from conflictbench.policies.scripted.grasp import collisions, gripper_points
from conflictbench.policies.scripted.policy import order
from conflictbench.policies.scripted.scene import Boxes, Scene, finger_frame, quat_xyzw_to_mat, rotvec


def test_rotvec_inverts_scipy_rotations_including_half_turns():
    rng = np.random.default_rng(0)
    vectors = [rng.normal(size=3) for _ in range(20)] + [
        np.array([0.0, 0.0, math.pi]),
        np.array([math.pi, 0.0, 0.0]) * 0.9999999,
    ]
    for v in vectors:
        v = v / np.linalg.norm(v) * min(np.linalg.norm(v), math.pi)
        got = rotvec(Rotation.from_rotvec(v).as_matrix())
        # a half turn about v equals one about -v
        assert np.allclose(got, v, atol=1e-5) or np.allclose(got, -v, atol=1e-5), (v, got)
    assert np.all(rotvec(np.eye(3)) == 0.0)


def test_finger_frame_points_down_with_fingers_along_theta():
    for theta in (-math.pi / 2, 0.0, 0.7, 2.5):
        frame = finger_frame(theta)
        assert np.allclose(frame @ frame.T, np.eye(3)) and np.linalg.det(frame) == pytest.approx(1.0)
        assert np.allclose(frame[:, 2], [0, 0, -1])
        assert np.allclose(frame[:2, 1], [math.cos(theta), math.sin(theta)])


def test_quaternion_convention_is_xyzw_as_robosuite_reports_it():
    q = Rotation.from_euler("z", 0.3).as_quat()  # scipy: x, y, z, w
    assert np.allclose(quat_xyzw_to_mat(q), Rotation.from_euler("z", 0.3).as_matrix())


def test_nearest_theta_uses_the_fingers_symmetry():
    assert nearest_theta(math.pi, 0.1) == pytest.approx(0.0, abs=1e-12)
    assert nearest_theta(0.5, 0.4) == pytest.approx(0.5)
    assert nearest_theta(0.5 + math.pi, 0.4) == pytest.approx(0.5)


class _FakeScene:
    eef = np.array([0.0, 0.0, 1.0])
    rot = finger_frame(-math.pi / 2)


def test_servo_saturates_far_away_and_is_proportional_close_by():
    far = servo(_FakeScene, np.array([1.0, 0.0, 1.0]), -math.pi / 2, -1.0)
    assert far[0] == 1.0 and np.all(far[1:6] == 0.0) and far[6] == -1.0
    near = servo(_FakeScene, np.array([0.01, 0.0, 1.0]), -math.pi / 2, 1.0, gain=20.0)
    assert near[0] == pytest.approx(0.2) and near[6] == 1.0
    slow = servo(_FakeScene, np.array([1.0, 0.0, 1.0]), -math.pi / 2, -1.0, speed=0.4)
    assert slow[0] == pytest.approx(0.4)
    turn = servo(_FakeScene, _FakeScene.eef, 0.0, -1.0)  # a quarter turn about z: rotation only
    assert np.all(turn[:3] == 0.0) and abs(turn[5]) == pytest.approx(1.0) and turn[3:5] == pytest.approx([0, 0])


def test_boxes_contains_matches_the_definition_for_rotated_boxes():
    rng = np.random.default_rng(1)
    centers = rng.normal(size=(30, 3))
    rots = Rotation.random(30, random_state=2).as_matrix()
    halves = rng.uniform(0.05, 0.6, size=(30, 3))
    points = rng.normal(size=(400, 3))
    local = np.einsum("pbi,bij->pbj", points[:, None, :] - centers[None], rots)
    expected = np.all(np.abs(local) < halves[None] + 0.01, axis=-1)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(Boxes(centers, rots, halves).contains(points, margin=0.01), expected)


def test_gripper_collides_with_a_box_under_it_and_not_with_one_beside_it():
    table_top = Boxes(np.array([[0.0, 0.0, 0.0]]), np.eye(3)[None], np.array([[0.3, 0.3, 0.02]]))
    assert collisions(gripper_points(np.array([0.0, 0.0, 0.025]), 0.0), table_top) > 0
    assert collisions(gripper_points(np.array([0.0, 0.0, 0.2]), 0.0), table_top) == 0
    aside = Boxes(np.array([[0.5, 0.0, 0.0]]), np.eye(3)[None], np.array([[0.05, 0.05, 0.3]]))
    assert collisions(gripper_points(np.array([0.0, 0.0, 0.025]), 0.0), aside) == 0


def test_work_order_opens_first_places_next_closes_last():
    goal = (("close", "drawer"), ("on", "bowl", "plate"), ("turnon", "stove"), ("open", "microwave"))
    assert order(goal) == [2, 3, 1, 0]


def test_the_expert_refuses_observations_without_privileged_state():
    obs = Observation(
        step=0,
        instruction="x",
        eef_pos=np.zeros(3),
        eef_quat=np.array([0, 0, 0, 1.0]),
        gripper_qpos=np.zeros(2),
        state=np.zeros(8),
    )
    with pytest.raises(ValueError, match="privileged"):
        Scene(obs)


# A moka pot's collision boxes in its own frame, (n, 2, 3) as the simulator reports them: an
# 8 cm body, a lid knob on top, and a handle on the +y side (measured on libero_10 task 2).
MOKA_POT = np.array(
    [
        [[-0.025, -0.025, -0.066], [0.025, 0.025, 0.067]],  # body
        [[-0.041, -0.041, -0.066], [0.041, 0.041, 0.067]],  # body, outer faces
        [[-0.005, -0.007, 0.063], [0.005, 0.005, 0.086]],  # lid knob
        [[-0.007, 0.060, 0.039], [0.007, 0.091, 0.068]],  # handle, top
        [[-0.007, 0.054, 0.000], [0.007, 0.091, 0.056]],  # handle, grip
    ]
)


def test_clusters_group_touching_footprints_only():
    from conflictbench.policies.scripted.grasp import _clusters

    groups = sorted(sorted(g.tolist()) for g in _clusters(MOKA_POT))
    assert groups == [[0, 1, 2], [3, 4]]  # the knob stands on the body; the handle is apart
    assert len(_clusters(MOKA_POT[[2, 3]])) == 2


def test_band_grasps_take_separate_parts_not_the_box_around_them():
    from conflictbench.policies.scripted.grasp import _band_candidates

    cands = _band_candidates(MOKA_POT)
    # the body (8 cm, with the knob on it) is too wide; the handle, apart from it, is a part of its
    # own: every candidate is on the handle, none in the gap between knob and handle (y ~ 0.04)
    assert cands and all(sorted(idx.tolist()) == [3, 4] for _, _, _, idx in cands)
    assert all(np.allclose(p[:2], [0.0, 0.0725]) and p[2] < 0.068 for p, _, _, _ in cands)
    assert any(np.allclose(ax, [1.0, 0.0]) for _, ax, _, _ in cands)  # across the 1.4 cm plate
    # without the handle, the same object is grasped by the knob, the only narrow part on top
    knob = _band_candidates(MOKA_POT[:3])
    assert knob and all(np.allclose(p[:2], [0.0, -0.001]) for p, _, _, _ in knob)


# The yellow-and-white mug of libero_10 task 9 in its own frame: a 10.3 cm cup (wall boxes around
# (-0.018, 0), radius 0.053, plus its floor) and a 1.8 cm thin handle on the +x side (measured).
MUG = np.array(
    [
        [[-0.071, -0.053, 0.016], [-0.050, 0.053, 0.103]],  # wall, -x
        [[0.013, -0.053, 0.016], [0.034, 0.053, 0.103]],  # wall, +x
        [[-0.071, -0.053, 0.016], [0.034, -0.032, 0.103]],  # wall, -y
        [[-0.071, 0.032, 0.016], [0.034, 0.053, 0.103]],  # wall, +y
        [[-0.059, -0.041, 0.000], [0.022, 0.041, 0.021]],  # floor
        [[0.060, -0.009, 0.027], [0.068, 0.009, 0.085]],  # handle, outer bar
        [[0.015, -0.009, 0.017], [0.065, 0.009, 0.035]],  # handle, lower bar
        [[0.024, -0.009, 0.073], [0.068, 0.009, 0.086]],  # handle, upper bar
    ]
)


def test_handle_grasp_pinches_the_outer_bar_with_the_hand_above_the_rim():
    from conflictbench.policies.scripted.grasp import HAND_BOTTOM, _handle_candidates, handle_parts

    assert handle_parts(MUG).tolist() == [5, 6, 7]
    ((point, axis, kind, idx),) = _handle_candidates(MUG)
    assert kind == "handle" and idx.tolist() == [5, 6, 7]
    assert np.allclose(point[:2], [0.064, 0.0])  # the outermost bar, not the cup
    assert np.allclose(np.abs(axis), [0.0, 1.0])  # across the handle's thin side
    assert point[2] + HAND_BOTTOM > MUG[:, 1, 2].max()  # the hand's underside clears the rim
    assert point[2] < 0.086  # and the fingers still close on the handle
    assert _handle_candidates(MUG[:5]) == []  # a cup without a handle has none


class _BoxScene:
    """Just enough of a Scene for ``enclosed.opening``: one fixture made of axis-aligned boxes."""

    def __init__(self, boxes, region_pos, region_size=(0.12, 0.08, 0.08)):
        boxes = np.asarray(boxes, dtype=float)
        centers, halves = boxes.mean(axis=1), (boxes[:, 1] - boxes[:, 0]) / 2
        self._oven = Boxes(centers, np.repeat(np.eye(3)[None], len(boxes), axis=0), halves)
        self._site = SiteInfo(
            pos=np.asarray(region_pos, dtype=float),
            xmat=np.eye(3),
            size=np.asarray(region_size),
            joints=(),
            parent="oven",
        )

    def site(self, name):
        return self._site

    def objects(self):
        return ["oven"]

    def frames(self, name):
        return self._oven

    def solids(self, exclude=()):
        return self._oven if "oven" not in exclude else Boxes(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))


# A microwave-like box open toward -y: floor top 0.944, roof underside 1.088, walls at x -0.135 / 0.072,
# back wall from y 0.421 (the numbers of libero_10 task 9's microwave).
OVEN = [
    [[-0.164, 0.252, 0.920], [0.181, 0.452, 0.944]],  # floor
    [[-0.164, 0.252, 1.088], [0.181, 0.452, 1.107]],  # roof
    [[-0.164, 0.252, 0.920], [-0.135, 0.452, 1.107]],  # left wall
    [[0.072, 0.252, 0.920], [0.181, 0.452, 1.107]],  # right wall
    [[-0.135, 0.421, 0.920], [0.072, 0.452, 1.107]],  # back wall
]


def test_opening_finds_the_open_side_the_roof_edge_and_the_room_inside():
    from conflictbench.policies.scripted.enclosed import opening

    o = opening(_BoxScene(OVEN, (0.009, 0.35, 1.016)), "heating", height=0.103)
    assert np.allclose(o.inward, [0.0, 1.0]) and np.allclose(np.abs(o.lateral), [1.0, 0.0])
    assert o.floor == pytest.approx(0.944) and o.roof == pytest.approx(1.088)
    assert o.edge == pytest.approx(0.252) and o.back == pytest.approx(0.421, abs=0.005)
    assert float(o.middle * o.lateral[0]) == pytest.approx((-0.135 + 0.072) / 2, abs=0.005)
    # room enough above the object for a hand: the plain top-down way is fine
    assert opening(_BoxScene(OVEN, (0.009, 0.35, 1.016)), "heating", height=0.03) is None
    # closed on every side (a door across the front): no way in
    shut = OVEN + [[[-0.164, 0.230, 0.920], [0.181, 0.252, 1.107]]]
    assert opening(_BoxScene(shut, (0.009, 0.35, 1.016)), "heating", height=0.103) is None
