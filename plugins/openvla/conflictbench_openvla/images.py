"""Moved: the OpenVLA family's image steps, shared with UniVLA's client, are conflictbench's own,
:mod:`conflictbench.hosting.openvla_family` (kept importable here)."""

from conflictbench.hosting.openvla_family import (
    CROP_AREA,
    IMAGE_SIZE,
    JPEG_QUALITY,
    center_crop,
    jpeg_round_trip,
    lanczos_resize,
    lanczos_weights,
    policy_image,
    resize_for_policy,
    upright,
)

__all__ = [
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
]
