"""Deprecated (goes in conflictbench 0.4.0): the OpenVLA family's image steps, shared with UniVLA's client, moved to
conflictbench's own :mod:`conflictbench.hosting.openvla_family` in 0.3; reading a name here warns and gives that
module's."""

from conflictbench.core.deprecation import moved_names

MOVED = (
    "CROP_AREA",
    "IMAGE_SIZE",
    "JPEG_QUALITY",
    "center_crop",
    "jpeg_round_trip",
    "lanczos_resize",
    "lanczos_weights",
    "policy_image",
    "resize_for_policy",
    "upright",
)
__getattr__ = moved_names(__name__, {name: f"conflictbench.hosting.openvla_family:{name}" for name in MOVED})
__all__ = list(MOVED)  # 0.2's exports: a star import warns and works
