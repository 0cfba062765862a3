"""Frames and cameras: what the tracker sees at one instant."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tracker.boxes import Boxes, FloatArray


@dataclass(frozen=True, slots=True, eq=False)
class Camera:
    """A pinhole camera at one frame.

    ``image_from_camera`` is the 3x4 projection (KITTI ``P2``; ``[K | 0]`` elsewhere) and
    ``camera_from_world`` the 4x4 rigid transform. Camera axes: x right, y down, z forward.
    """

    name: str
    image_from_camera: FloatArray
    camera_from_world: FloatArray
    width_px: int
    height_px: int

    def __post_init__(self) -> None:
        if self.image_from_camera.shape != (3, 4):
            raise ValueError(f"Camera {self.name}: image_from_camera must be 3x4")
        if self.camera_from_world.shape != (4, 4):
            raise ValueError(f"Camera {self.name}: camera_from_world must be 4x4")

    @property
    def image_from_world(self) -> FloatArray:
        return self.image_from_camera @ self.camera_from_world


@dataclass(frozen=True, slots=True, eq=False)
class Frame:
    """One time step of one scene.

    ``timestamp_secs`` is real time in seconds (monotonic within a scene). ``boxes`` are the
    detections (or ground truth) in the world frame; ``boxes.camera`` indexes ``cameras``.
    ``world_from_ego`` is the 4x4 ego pose when known (NaN-filled otherwise).
    ``ignore_xyxy_image`` (K, 4) are image regions to ignore in evaluation (KITTI DontCare), in
    camera ``ignore_camera`` (K,). ``transform_matrix`` keeps the original BaseVersion transform
    object for lossless round trips.
    """

    scene: str
    frame_id: int
    timestamp_secs: float
    boxes: Boxes
    cameras: tuple[Camera, ...] = ()
    world_from_ego: FloatArray = field(default_factory=lambda: np.full((4, 4), np.nan))
    sample_token: str | None = None
    transform_matrix: dict[str, Any] | None = None
    ignore_xyxy_image: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))
    ignore_camera: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def camera_index(self, name: str) -> int:
        for i, cam in enumerate(self.cameras):
            if cam.name == name:
                return i
        return -1
