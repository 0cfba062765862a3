"""Seeded synthetic scenes: objects on straight or curved paths, noisy detections with dropouts.

Used by the speed benchmark (dense scenes), tests (known ground truth) and the recording
memory check (long sequences). Deterministic for a given seed.
"""

from __future__ import annotations

import numpy as np

from tracker.boxes import Boxes
from tracker.categories import category_index
from tracker.frame import Camera, Frame

CAR = category_index("car")
PEDESTRIAN = category_index("pedestrian")


def front_camera(width_px: int = 1242, height_px: int = 375) -> Camera:
    """A KITTI-like camera at the world origin looking along +x (z up world)."""
    image_from_camera = np.array(
        [[721.5, 0.0, 609.6, 0.0], [0.0, 721.5, 172.9, 0.0], [0.0, 0.0, 1.0, 0.0]]
    )
    # camera axes x right, y down, z forward  <-  world x forward, y left, z up
    camera_from_world = np.array(
        [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 1.65], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    )
    return Camera("CAM_FRONT", image_from_camera, camera_from_world, width_px, height_px)


def synthetic_scene(
    *,
    num_objects: int,
    num_frames: int,
    seed: int = 0,
    frame_rate_hz: float = 10.0,
    extent_m: float = 100.0,
    position_noise_m: float = 0.1,
    dropout: float = 0.05,
    scene: str = "synthetic",
    with_camera: bool = True,
) -> tuple[list[Frame], list[Frame]]:
    """(detections, ground truth) frames for ``num_objects`` objects alive the whole scene.

    Cars move at 5-15 m/s with a slow turn rate; a fifth of the objects are pedestrians at
    1-2 m/s. Detections are the truth plus Gaussian noise, each missed with ``dropout``.
    """
    rng = np.random.default_rng(seed)
    n = num_objects
    is_ped = rng.uniform(size=n) < 0.2
    category = np.where(is_ped, PEDESTRIAN, CAR)
    lwh = np.where(is_ped[:, None], [0.8, 0.7, 1.75], [4.2, 1.8, 1.6])
    xy = rng.uniform(0, extent_m, size=(n, 2)) + np.array([5.0, -extent_m / 2])
    heading = rng.uniform(-np.pi, np.pi, size=n)
    speed = np.where(is_ped, rng.uniform(1, 2, n), rng.uniform(5, 15, n))
    turn = rng.normal(0, 0.05, size=n)
    dt = 1.0 / frame_rate_hz
    cameras = (front_camera(),) if with_camera else ()
    dets, gts = [], []
    for f in range(num_frames):
        t = f * dt
        yaw = np.arctan2(np.sin(heading), np.cos(heading))
        vel = speed[:, None] * np.column_stack([np.cos(yaw), np.sin(yaw)])
        xyz = np.column_stack([xy, lwh[:, 2] / 2])
        gt = Boxes.create(
            xyz=xyz, lwh=lwh, yaw=yaw, category=category, velocity=vel, track_id=np.arange(n)
        )
        seen = rng.uniform(size=n) >= dropout
        noisy = xyz + rng.normal(0, position_noise_m, size=(n, 3)) * [1, 1, 0.2]
        det = Boxes.create(
            xyz=noisy[seen],
            lwh=lwh[seen] * rng.normal(1, 0.03, size=(int(seen.sum()), 3)),
            yaw=yaw[seen] + rng.normal(0, 0.05, size=int(seen.sum())),
            category=category[seen],
            score=rng.uniform(0.6, 1.0, size=int(seen.sum())),
        )
        dets.append(Frame(scene=scene, frame_id=f, timestamp_secs=t, boxes=det, cameras=cameras))
        gts.append(Frame(scene=scene, frame_id=f, timestamp_secs=t, boxes=gt, cameras=cameras))
        heading = heading + turn * dt
        xy = xy + vel * dt
    return dets, gts
