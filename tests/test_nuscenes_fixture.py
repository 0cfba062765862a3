"""A tiny synthetic nuScenes dataset in the official table schema (v1.0-mini layout), used by
tests/test_nuscenes.py and tests/test_nuscenes_cli.py.

Written by the tests (there is no nuScenes data in the repository): a few scenes named like the
official ``mini_val`` / ``mini_train`` scenes so the devkit's predefined splits apply, a moving
ego vehicle, LIDAR_TOP and the six cameras with realistic extrinsics and intrinsics, and
instances of every tracking class (plus a barrier) moving with known constant velocities.
Detections in the submission format are made from the ground truth with seeded noise.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

VERSION = "v1.0-mini"
SAMPLE_PERIOD_MICROS = 500_000

#: (channel, yaw of the optical axis in the ego frame (deg), x, y, z, fx, cx, cy)
CAMERAS = (
    ("CAM_FRONT", 0.0, 1.70, 0.02, 1.51, 1266.0, 816.0, 491.0),
    ("CAM_FRONT_RIGHT", -55.0, 1.55, -0.49, 1.50, 1260.0, 807.0, 495.0),
    ("CAM_FRONT_LEFT", 55.0, 1.52, 0.49, 1.51, 1272.0, 826.0, 479.0),
    ("CAM_BACK", 180.0, 0.03, 0.00, 1.57, 809.0, 829.0, 481.0),
    ("CAM_BACK_LEFT", 110.0, 1.04, 0.48, 1.49, 1256.0, 817.0, 451.0),
    ("CAM_BACK_RIGHT", -110.0, 1.04, -0.48, 1.49, 1259.0, 807.0, 501.0),
)
CAMERA_DELAY_MICROS = {name: 8_000 * (i + 1) for i, (name, *_rest) in enumerate(CAMERAS)}

#: nuScenes category, tracking class, size (w, l, h)
CLASSES = {
    "car": ("vehicle.car", (1.9, 4.5, 1.6)),
    "pedestrian": ("human.pedestrian.adult", (0.65, 0.7, 1.75)),
    "bicycle": ("vehicle.bicycle", (0.6, 1.8, 1.3)),
    "motorcycle": ("vehicle.motorcycle", (0.8, 2.1, 1.5)),
    "bus": ("vehicle.bus.rigid", (2.9, 11.5, 3.4)),
    "trailer": ("vehicle.trailer", (2.6, 10.0, 3.8)),
    "truck": ("vehicle.truck", (2.5, 7.0, 3.0)),
    "barrier": ("movable_object.barrier", (2.0, 0.5, 1.0)),
}

#: Objects of every scene: class, start (x forward, y left) in the ego frame at t = 0 (m),
#: velocity in the same axes (m/s). The ego drives forward at EGO_SPEED.
EGO_SPEED_MPS = 3.0
OBJECTS = (
    ("car", (12.0, 3.5), (5.0, 0.0)),
    ("car", (-10.0, -3.5), (4.0, 0.0)),
    ("car", (20.0, 7.0), (0.0, 0.0)),
    ("pedestrian", (8.0, 6.0), (0.0, -1.2)),
    ("pedestrian", (15.0, -6.0), (1.0, 0.3)),
    ("bicycle", (5.0, -5.5), (3.5, 0.0)),
    ("motorcycle", (-15.0, 3.0), (7.0, 0.0)),
    ("bus", (18.0, -10.0), (6.0, 0.0)),
    ("truck", (-20.0, -8.0), (3.0, 0.0)),
    ("trailer", (30.0, 11.0), (0.0, 0.0)),
    ("barrier", (10.0, -13.0), (0.0, 0.0)),
)

#: scene name -> (number of samples, ego heading in the world (rad), ego start xy)
SCENES = {
    "scene-0103": (16, 0.4, (600.0, 1600.0)),  # mini_val
    "scene-0916": (16, -2.2, (350.0, 900.0)),  # mini_val
    "scene-0061": (4, 1.0, (100.0, 100.0)),  # mini_train
}


def token(*parts: Any) -> str:
    return hashlib.md5("/".join(str(p) for p in parts).encode()).hexdigest()


def quaternion_wxyz(rotation: np.ndarray) -> list[float]:
    """Unit quaternion of a 3x3 rotation (Shepperd's method)."""
    m = rotation
    trace = np.trace(m)
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0] * 4
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q = np.array(q)
    q = q if q[0] >= 0 else -q
    return (q / np.linalg.norm(q)).tolist()


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_quaternion(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


#: ego axes (x forward, y left, z up) from camera axes (x right, y down, z forward)
EGO_FROM_CAMERA_AXES = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass
class SyntheticNuScenes:
    dataroot: Path
    version: str
    samples: dict[str, list[str]]  # scene -> sample tokens in order
    #: sample token -> list of GT dicts (class, translation, size, yaw, velocity, instance)
    gt: dict[str, list[dict[str, Any]]] = field(default_factory=dict)

    def split_samples(self, scenes: tuple[str, ...] = ("scene-0103", "scene-0916")) -> list[str]:
        return [t for s in scenes for t in self.samples[s]]


def write_synthetic_nuscenes(root: Path) -> SyntheticNuScenes:
    """Write the dataset under ``root`` (tables in ``root/v1.0-mini``) and describe it."""
    tables: dict[str, list[dict[str, Any]]] = {
        name: []
        for name in (
            "category",
            "attribute",
            "visibility",
            "instance",
            "sensor",
            "calibrated_sensor",
            "ego_pose",
            "log",
            "scene",
            "sample",
            "sample_data",
            "sample_annotation",
            "map",
        )
    }
    for name, (category, _size) in CLASSES.items():
        tables["category"].append(
            {"token": token("cat", name), "name": category, "description": ""}
        )
    tables["visibility"].append({"token": "4", "level": "v80-100", "description": "visible"})
    log_token = token("log")
    tables["log"].append(
        {
            "token": log_token,
            "logfile": "synthetic",
            "vehicle": "n015",
            "date_captured": "2018-08-01",
            "location": "singapore-onenorth",
        }
    )
    (root / "maps").mkdir(parents=True, exist_ok=True)
    from PIL import Image

    Image.new("L", (8, 8), 255).save(root / "maps" / "synthetic.png")
    tables["map"].append(
        {
            "token": token("map"),
            "log_tokens": [log_token],
            "category": "semantic_prior",
            "filename": "maps/synthetic.png",
        }
    )
    # sensors and one calibration per sensor
    lidar_sensor = token("sensor", "LIDAR_TOP")
    tables["sensor"].append({"token": lidar_sensor, "channel": "LIDAR_TOP", "modality": "lidar"})
    calib: dict[str, str] = {"LIDAR_TOP": token("calib", "LIDAR_TOP")}
    tables["calibrated_sensor"].append(
        {
            "token": calib["LIDAR_TOP"],
            "sensor_token": lidar_sensor,
            "translation": [0.94, 0.0, 1.84],
            "rotation": quaternion_wxyz(rot_z(-math.pi / 2)),
            "camera_intrinsic": [],
        }
    )
    for name, yaw_deg, x, y, z, fx, cx, cy in CAMERAS:
        sensor = token("sensor", name)
        tables["sensor"].append({"token": sensor, "channel": name, "modality": "camera"})
        calib[name] = token("calib", name)
        rotation = rot_z(math.radians(yaw_deg)) @ EGO_FROM_CAMERA_AXES
        tables["calibrated_sensor"].append(
            {
                "token": calib[name],
                "sensor_token": sensor,
                "translation": [x, y, z],
                "rotation": quaternion_wxyz(rotation),
                "camera_intrinsic": [[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]],
            }
        )

    data = SyntheticNuScenes(root, VERSION, {})
    first_ann: dict[str, str] = {}
    last_ann: dict[str, dict[str, Any]] = {}
    counts: dict[str, int] = {}
    inst_class: dict[str, str] = {}
    for scene_index, (scene, (n_samples, heading, start)) in enumerate(SCENES.items()):
        scene_token = token("scene", scene)
        t0 = 1_533_151_603_000_000 + scene_index * 100_000_000
        world_from_ego_rot = rot_z(heading)
        start_xy = np.array(start)
        forward = world_from_ego_rot[:2, 0]

        sample_tokens = [token("sample", scene, i) for i in range(n_samples)]
        data.samples[scene] = sample_tokens
        prev_sd: dict[str, dict[str, Any]] = {}
        for i, sample_token in enumerate(sample_tokens):
            t = t0 + i * SAMPLE_PERIOD_MICROS
            tables["sample"].append(
                {
                    "token": sample_token,
                    "timestamp": t,
                    "prev": sample_tokens[i - 1] if i else "",
                    "next": sample_tokens[i + 1] if i + 1 < n_samples else "",
                    "scene_token": scene_token,
                }
            )
            for channel in ("LIDAR_TOP", *(c[0] for c in CAMERAS)):
                t_sd = t + CAMERA_DELAY_MICROS.get(channel, 0)
                sd_token = token("sd", scene, i, channel)
                pose_token = token("ego", scene, i, channel)
                xy = start_xy + EGO_SPEED_MPS * (t_sd - t0) / 1e6 * forward
                tables["ego_pose"].append(
                    {
                        "token": pose_token,
                        "timestamp": t_sd,
                        "rotation": quaternion_wxyz(world_from_ego_rot),
                        "translation": [float(xy[0]), float(xy[1]), 0.0],
                    }
                )
                is_cam = channel != "LIDAR_TOP"
                record = {
                    "token": sd_token,
                    "sample_token": sample_token,
                    "ego_pose_token": pose_token,
                    "calibrated_sensor_token": calib[channel],
                    "timestamp": t_sd,
                    "fileformat": "jpg" if is_cam else "pcd",
                    "is_key_frame": True,
                    "height": 900 if is_cam else 0,
                    "width": 1600 if is_cam else 0,
                    "filename": f"samples/{channel}/{sd_token}.{'jpg' if is_cam else 'pcd.bin'}",
                    "prev": prev_sd[channel]["token"] if channel in prev_sd else "",
                    "next": "",
                }
                tables["sample_data"].append(record)
                if channel in prev_sd:
                    prev_sd[channel]["next"] = sd_token
                prev_sd[channel] = record
            # annotations
            data.gt[sample_token] = []
            for k, (cls, start_ego, vel_ego) in enumerate(OBJECTS):
                instance = token("instance", scene, k)
                inst_class[instance] = cls
                start_world = start_xy + world_from_ego_rot[:2, :2] @ np.array(start_ego)
                vel_world = world_from_ego_rot[:2, :2] @ np.array(vel_ego)
                secs = (t - t0) / 1e6
                xy = start_world + vel_world * secs
                speed = float(np.hypot(*vel_world))
                yaw = math.atan2(vel_world[1], vel_world[0]) if speed > 0 else heading + 0.3 * k
                size = CLASSES[cls][1]
                ann_token = token("ann", scene, i, k)
                ann = {
                    "token": ann_token,
                    "sample_token": sample_token,
                    "instance_token": instance,
                    "visibility_token": "4",
                    "attribute_tokens": [],
                    "translation": [float(xy[0]), float(xy[1]), size[2] / 2],
                    "size": list(size),
                    "rotation": yaw_quaternion(yaw),
                    "prev": last_ann[instance]["token"] if instance in last_ann else "",
                    "next": "",
                    "num_lidar_pts": 40,
                    "num_radar_pts": 2,
                }
                if instance in last_ann:
                    last_ann[instance]["next"] = ann_token
                else:
                    first_ann[instance] = ann_token
                last_ann[instance] = ann
                counts[instance] = counts.get(instance, 0) + 1
                tables["sample_annotation"].append(ann)
                data.gt[sample_token].append(
                    {
                        "class": cls,
                        "translation": ann["translation"],
                        "size": list(size),
                        "yaw": yaw,
                        "velocity": [float(vel_world[0]), float(vel_world[1])],
                        "instance": instance,
                    }
                )
        tables["scene"].append(
            {
                "token": scene_token,
                "log_token": log_token,
                "nbr_samples": n_samples,
                "first_sample_token": sample_tokens[0],
                "last_sample_token": sample_tokens[-1],
                "name": scene,
                "description": "synthetic",
            }
        )
    for instance, first in first_ann.items():
        tables["instance"].append(
            {
                "token": instance,
                "category_token": token("cat", inst_class[instance]),
                "nbr_annotations": counts[instance],
                "first_annotation_token": first,
                "last_annotation_token": last_ann[instance]["token"],
            }
        )
    table_dir = root / VERSION
    table_dir.mkdir(parents=True, exist_ok=True)
    for name, rows in tables.items():
        (table_dir / f"{name}.json").write_text(json.dumps(rows))
    return data


def make_detections(
    data: SyntheticNuScenes,
    *,
    seed: int,
    scenes: tuple[str, ...] = ("scene-0103", "scene-0916"),
    position_sigma_m: float = 0.0,
    velocity_sigma_mps: float = 0.0,
    yaw_sigma_rad: float = 0.0,
    dropout: float = 0.0,
    false_positives_per_sample: float = 0.0,
) -> dict[str, Any]:
    """A detection results file (submission format) from the GT, with seeded noise."""
    rng = np.random.default_rng(seed)
    results: dict[str, list[dict[str, Any]]] = {}
    for sample_token in data.split_samples(scenes):
        boxes = []
        for gt in data.gt[sample_token]:
            if rng.random() < dropout:
                continue
            xyz = np.array(gt["translation"]) + np.r_[rng.normal(0, position_sigma_m, 2), 0.0]
            vel = np.array(gt["velocity"]) + rng.normal(0, velocity_sigma_mps, 2)
            yaw = gt["yaw"] + rng.normal(0, yaw_sigma_rad)
            boxes.append(
                {
                    "sample_token": sample_token,
                    "translation": xyz.tolist(),
                    "size": gt["size"],
                    "rotation": yaw_quaternion(yaw),
                    "velocity": vel.tolist(),
                    "detection_name": gt["class"],
                    "detection_score": float(rng.uniform(0.5, 1.0)),
                    "attribute_name": "",
                }
            )
        for _ in range(rng.poisson(false_positives_per_sample)):
            anchor = data.gt[sample_token][int(rng.integers(len(data.gt[sample_token])))]
            xyz = np.array(anchor["translation"]) + np.r_[rng.uniform(-25, 25, 2), 0.0]
            boxes.append(
                {
                    "sample_token": sample_token,
                    "translation": xyz.tolist(),
                    "size": list(CLASSES["car"][1]),
                    "rotation": yaw_quaternion(float(rng.uniform(-math.pi, math.pi))),
                    "velocity": [0.0, 0.0],
                    "detection_name": "car",
                    "detection_score": float(rng.uniform(0.2, 0.45)),
                    "attribute_name": "",
                }
            )
        results[sample_token] = boxes
    return {
        "meta": {
            "use_camera": False,
            "use_lidar": True,
            "use_radar": False,
            "use_map": False,
            "use_external": False,
        },
        "results": results,
    }


def test_fixture_quaternions_are_rotations() -> None:
    for angle in (-2.5, -0.3, 0.0, 1.2, 3.0):
        rotation = rot_z(angle) @ EGO_FROM_CAMERA_AXES
        w, x, y, z = quaternion_wxyz(rotation)
        rebuilt = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        np.testing.assert_allclose(rebuilt, rotation, atol=1e-12)
