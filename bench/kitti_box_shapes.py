"""How well a KITTI object's 3D box, projected, matches its own annotated 2D box (labels only).

    python bench/kitti_box_shapes.py [--kitti-root ROOT] [--seqs 0001,0006,...]

KITTI's tracking benchmark scores 2D image boxes; a 3D tracker writes the projection of its 3D
box. This measures, on the ground truth itself (fully visible objects: truncated 0, occluded
<= 1, at least 2 m ahead), the ratio of the projected cuboid's width to the annotated 2D box's
width, and their IoU, per class and per sequence. Cars and cyclists: the two agree (IoU ~0.97);
pedestrians: the annotated box is much narrower than the cuboid (their 3D boxes include the
swing of arms and legs), so even a perfect 3D track scores a poor 2D box. This is the measurement
behind the per-class ``image_width_scale`` of the config (its value is chosen by `mctrack tune`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.inputs import default_kitti_root  # noqa: E402
from tracker.camera import project_boxes  # noqa: E402
from tracker.frame import Camera  # noqa: E402
from tracker.io.convert.kitti import (  # noqa: E402
    VALIDATION_SEQS,
    WORLD_FROM_CAMERA_AXES,
    KittiCalib,
    KittiObjects,
    boxes_rect_to_world,
    image_size_px,
    read_kitti_calib,
    read_kitti_labels,
)

CLASSES = ("Car", "Pedestrian", "Cyclist")


def projected_cuboids(
    objects: KittiObjects, calib: KittiCalib, *, clip_to_image: bool = False
) -> np.ndarray:
    """(N, 4) image boxes of KITTI cuboids, projected as the result writer does (upright in
    camera axes: world = the camera's own axes, z up); unclipped unless ``clip_to_image``."""
    world_from_rect = np.broadcast_to(WORLD_FROM_CAMERA_AXES, (objects.frame.max() + 1, 4, 4))
    xyz, lwh, yaw = boxes_rect_to_world(objects, world_from_rect)
    width, height = image_size_px(calib)
    camera = Camera("P2", calib.image_from_rect, np.linalg.inv(WORLD_FROM_CAMERA_AXES), width,
                    height)  # fmt: skip
    return project_boxes((xyz, lwh, yaw), camera, clip_to_image=clip_to_image)[0]


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    wx = np.clip(np.minimum(a[:, 2], b[:, 2]) - np.maximum(a[:, 0], b[:, 0]), 0, None)
    wy = np.clip(np.minimum(a[:, 3], b[:, 3]) - np.maximum(a[:, 1], b[:, 1]), 0, None)
    inter = wx * wy
    area = lambda r: (r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])  # noqa: E731
    return inter / (area(a) + area(b) - inter)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kitti-root", type=Path, default=None)
    parser.add_argument("--seqs", default=",".join(VALIDATION_SEQS))
    args = parser.parse_args(argv)
    root = args.kitti_root or default_kitti_root()
    per: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {c: {} for c in CLASSES}
    for seq in args.seqs.split(","):
        calib = read_kitti_calib(root / "training" / "calib" / f"{seq}.txt")
        lab = read_kitti_labels(root / "training" / "label_02" / f"{seq}.txt")
        ok = (lab.truncated == 0) & (lab.occluded <= 1) & (lab.xyz_bottom_rect[:, 2] > 2.0)
        for cls in CLASSES:
            sel = lab.select(ok & (lab.type_name == cls))
            if not len(sel):
                continue
            proj = projected_cuboids(sel, calib)
            ratio = (proj[:, 2] - proj[:, 0]) / (sel.xyxy_image[:, 2] - sel.xyxy_image[:, 0])
            per[cls][seq] = (ratio, iou(proj, sel.xyxy_image))
    print("| class | boxes | projected / annotated width (median) | IoU (mean) |"
          " median ratio per sequence (20+ boxes) |")  # fmt: skip
    print("|---|---:|---:|---:|---|")
    for cls, seqs in per.items():
        if not seqs:
            continue
        ratio = np.concatenate([r for r, _ in seqs.values()])
        ious = np.concatenate([i for _, i in seqs.values()])
        by_seq = ", ".join(
            f"{s} {np.median(r):.2f}" for s, (r, _) in sorted(seqs.items()) if len(r) >= 20
        )
        print(f"| {cls} | {len(ratio)} | {np.median(ratio):.3f} | {ious.mean():.3f} | {by_seq} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
