"""What the learned subject sees, as numbers: the instruction's words, one token per thing in the scene, the arm.

The same functions turn a recorded demonstration into training arrays and a live observation into the
model's input, so the two cannot drift apart. Nothing here reads a goal, a case or the expert.

- Words: lower-case runs of letters or digits; ids from the subject's vocabulary (0 padding, 1 unknown).
- Entities: every object, region and scene joint, named by the words of its name (``akita_black_bowl_1`` ->
  akita black bowl 1), with numbers: position, position relative to the gripper, orientation, joint position.
- Arm: gripper position, its rotation matrix, the two finger joints.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

PAD, UNKNOWN = 0, 1
NAME_WORDS = 8
"""Words kept of an entity's name (the longest region names have 7)."""
KIND = {"object": 1, "region": 2, "joint": 3}
ENTITY_NUMBERS = 14
"""position (3), position minus the gripper's (3), the same within 10 cm at 10x (3: fine resolution where a grasp
is decided), quaternion w, x, y, z (4), joint position (1)."""
NEAR = 0.1
ARM_NUMBERS = 14
"""gripper position (3), rotation matrix (9), finger joints (2)."""
_WORD = re.compile(r"[a-z]+|\d+")


def words(text: str) -> list[str]:
    return _WORD.findall(text.lower())


@dataclass(frozen=True)
class Vocabulary:
    """Word -> id; ids 0 and 1 are padding and unknown words."""

    words: tuple[str, ...]

    @classmethod
    def build(cls, texts: Iterable[str]) -> Vocabulary:
        seen = sorted({w for text in texts for w in words(text)})
        return cls(("<pad>", "<unknown>", *seen))

    def ids(self, text: str) -> np.ndarray:
        index = self._index
        return np.array([index.get(w, UNKNOWN) for w in words(text)] or [UNKNOWN], dtype=np.int64)

    @property
    def _index(self) -> dict[str, int]:
        cached = self.__dict__.get("_cached")
        if cached is None:
            cached = {w: i for i, w in enumerate(self.words)}
            object.__setattr__(self, "_cached", cached)
        return cached


def name_text(name: str) -> str:
    return name.replace("_", " ")


@dataclass(frozen=True)
class Entities:
    """The names of a scene's entities, in a fixed order (objects, regions, joints, each sorted)."""

    objects: tuple[str, ...]
    regions: tuple[str, ...]
    joints: tuple[str, ...]

    def name_ids(self, vocabulary: Vocabulary) -> np.ndarray:
        """(E, NAME_WORDS) word ids of each entity's name."""
        out = np.zeros((len(self), NAME_WORDS), dtype=np.int64)
        for i, name in enumerate((*self.objects, *self.regions, *self.joints)):
            ids = vocabulary.ids(name_text(name))[:NAME_WORDS]
            out[i, : len(ids)] = ids
        return out

    def kinds(self) -> np.ndarray:
        return np.array(
            [KIND["object"]] * len(self.objects)
            + [KIND["region"]] * len(self.regions)
            + [KIND["joint"]] * len(self.joints),
            dtype=np.int64,
        )

    def __len__(self) -> int:
        return len(self.objects) + len(self.regions) + len(self.joints)

    @classmethod
    def of(cls, scene) -> Entities:
        """A :class:`~conflictbench.core.SceneState`'s entities, each kind sorted by name."""
        return cls(*(tuple(sorted(m)) for m in (scene.body_poses, scene.site_positions, scene.joint_positions)))

    def arrays(self, scene, dtype=np.float64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(n, 7) object poses, (m, 3) region positions and (k,) joint positions of ``scene`` in this order: what
        the recorder stores and the policy reads, read the same way."""
        return (
            np.array([scene.body_poses[n] for n in self.objects], dtype=dtype).reshape(-1, 7),
            np.array([scene.site_positions[n] for n in self.regions], dtype=dtype).reshape(-1, 3),
            np.array([scene.joint_positions[n] for n in self.joints], dtype=dtype).reshape(-1),
        )


def entity_numbers(
    object_poses: np.ndarray, region_positions: np.ndarray, joint_positions: np.ndarray, eef_pos: np.ndarray
) -> np.ndarray:
    """(..., E, ENTITY_NUMBERS) from (..., n, 7) object poses, (..., m, 3) regions, (..., k) joints, (..., 3) eef."""
    lead = np.shape(eef_pos)[:-1]
    n, m, k = object_poses.shape[-2], region_positions.shape[-2], joint_positions.shape[-1]
    out = np.zeros((*lead, n + m + k, ENTITY_NUMBERS), dtype=np.float32)
    eef = np.asarray(eef_pos)[..., None, :]
    out[..., :n, 0:3] = object_poses[..., :3]
    out[..., :n, 3:6] = object_poses[..., :3] - eef
    out[..., :n, 9:13] = object_poses[..., 3:7]
    out[..., n : n + m, 0:3] = region_positions
    out[..., n : n + m, 3:6] = region_positions - eef
    out[..., : n + m, 6:9] = np.clip(out[..., : n + m, 3:6], -NEAR, NEAR) / NEAR
    out[..., n + m :, 13] = joint_positions
    return out


def arm_numbers(eef_pos: np.ndarray, eef_quat_xyzw: np.ndarray, gripper_qpos: np.ndarray) -> np.ndarray:
    """(..., ARM_NUMBERS) for frames of gripper position, orientation (x, y, z, w) and finger joints."""
    x, y, z, w = np.moveaxis(np.asarray(eef_quat_xyzw, dtype=np.float64), -1, 0)
    rot = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )  # fmt: skip
    return np.concatenate([eef_pos, rot, gripper_qpos], axis=-1).astype(np.float32)
