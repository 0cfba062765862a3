"""Which part of a run's written 3D box limits its 2D boxes' overlap with the labels (car).

    python bench/box_error_anatomy.py RESULTS_DIR [RESULTS_DIR ...] [--kitti-root ROOT]
        [--seqs 0001,0006,...]

KITTI scores 2D boxes, and HOTA averages its detection and association scores over IoU
thresholds 0.05-0.95: at 0.85 and 0.95 a box a few pixels off no longer counts. A written car box
is the projection of its tracked 3D box (for LiDAR detectors), so its 2D error comes from the
centre, the size and the heading. For each ground-truth car that HOTA scores (truncated 0,
occluded <= 2) and that a written row overlaps at 2D IoU >= 0.5 (the frame's Hungarian matching),
this prints the mean IoU with the annotated 2D box and the share above 0.85 and 0.95 of: the
written box; the projection of the ground truth's own 3D box (what a perfect 3D box scores: the
annotated 2D boxes are those projections, clipped); the ground truth's box with one component
replaced by the run's (centre x, y, z in the camera frame, size, heading): how much that
component's error alone costs; and the run's box with one component replaced by the ground
truth's. Then the error of each component, split into its mean per track (a bias a smoother
cannot see) and what varies within the track.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.inputs import default_kitti_root  # noqa: E402
from bench.kitti_box_shapes import iou, projected_cuboids  # noqa: E402
from tracker.io.convert.kitti import (  # noqa: E402
    VALIDATION_SEQS,
    KittiObjects,
    read_kitti_calib,
    read_kitti_labels,
)

#: The 3D box's parts, as KittiObjects fields and columns: (name, field, column or None).
PARTS = (
    ("centre x", "xyz_bottom_rect", 0),
    ("centre y (height)", "xyz_bottom_rect", 1),
    ("centre z (depth)", "xyz_bottom_rect", 2),
    ("size", "hwl", None),
    ("heading", "rotation_y", None),
)


def with_part(base: KittiObjects, other: KittiObjects, field: str, column: int | None):
    """``base`` with one part taken from ``other`` (row for row)."""
    value = getattr(base, field).copy()
    if column is None:
        value = getattr(other, field).copy()
    else:
        value[:, column] = getattr(other, field)[:, column]
    return dataclasses.replace(base, **{field: value})


def matched_pairs(labels: KittiObjects, rows: KittiObjects) -> tuple[np.ndarray, np.ndarray]:
    """Indices of (label, row) pairs: per frame, Hungarian on 2D IoU, pairs at >= 0.5."""
    scored = (labels.type_name == "Car") & (labels.truncated <= 0) & (labels.occluded <= 2)
    cars = rows.type_name == "Car"
    gi_all, ri_all = [], []
    for frame in np.unique(labels.frame[scored]):
        gi = np.flatnonzero(scored & (labels.frame == frame))
        ri = np.flatnonzero(cars & (rows.frame == frame))
        if not len(ri):
            continue
        a = np.repeat(gi, len(ri))
        b = np.tile(ri, len(gi))
        sim = iou(labels.xyxy_image[a], rows.xyxy_image[b]).reshape(len(gi), len(ri))
        g, r = linear_sum_assignment(-sim)
        keep = sim[g, r] >= 0.5
        gi_all.append(gi[g[keep]])
        ri_all.append(ri[r[keep]])
    if not gi_all:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(gi_all), np.concatenate(ri_all)


def anatomy(results: Path, root: Path, seqs: list[str]) -> tuple[dict, dict]:
    """Per variant the IoUs with the annotated boxes; per part the errors and their track keys."""
    ious: dict[str, list[np.ndarray]] = {}
    errors: dict[str, list[np.ndarray]] = {name: [] for name, _, _ in PARTS}
    keys: list[np.ndarray] = []
    for seq in seqs:
        calib = read_kitti_calib(root / "training" / "calib" / f"{seq}.txt")
        projected = functools.partial(projected_cuboids, calib=calib, clip_to_image=True)
        labels = read_kitti_labels(root / "training" / "label_02" / f"{seq}.txt")
        rows = read_kitti_labels(results / f"{seq}.txt")
        g, r = matched_pairs(labels, rows)
        if not len(g):
            continue
        gt, run = _rows(labels, g), _rows(rows, r)  # (pair by pair)
        annotated = gt.xyxy_image
        variants = {
            "written 2D box": run.xyxy_image,
            "ground truth's 3D box": projected(gt),
        }
        for name, field, column in PARTS:
            variants[f"ground truth, run's {name}"] = projected(with_part(gt, run, field, column))
        for name, field, column in PARTS:
            variants[f"run, ground truth's {name}"] = projected(with_part(run, gt, field, column))
        for name, boxes in variants.items():
            ious.setdefault(name, []).append(iou(boxes, annotated))
        for name, field, column in PARTS:
            diff = getattr(run, field) - getattr(gt, field)
            if field == "rotation_y":  # (a box's axis: modulo pi)
                diff = np.mod(diff + np.pi / 2, np.pi) - np.pi / 2
            elif column is not None:
                diff = diff[:, column]
            else:
                diff = diff[:, 0]  # (size: height, the part the table shows costs most)
            errors[name].append(diff)
        keys.append(int(seq) * 1_000_000 + run.track_id)
    return {k: np.concatenate(v) for k, v in ious.items()}, {
        "errors": {k: np.concatenate(v) for k, v in errors.items()},
        "keys": np.concatenate(keys) if keys else np.zeros(0, np.int64),
    }


def _rows(objects: KittiObjects, index: np.ndarray) -> KittiObjects:
    """``objects``' rows ``index``, in that order."""
    values = {
        f.name: None if getattr(objects, f.name) is None else getattr(objects, f.name)[index]
        for f in dataclasses.fields(objects)
        if f.name != "paths"
    }
    return KittiObjects(**values, paths=objects.paths)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", nargs="+", type=Path)
    parser.add_argument("--kitti-root", type=Path, default=None)
    parser.add_argument("--seqs", default=",".join(VALIDATION_SEQS))
    args = parser.parse_args(argv)
    root = args.kitti_root or default_kitti_root()
    seqs = args.seqs.split(",")
    for results in args.results:
        folder = results / "data" if (results / "data").is_dir() else results
        ious, err = anatomy(folder, root, seqs)
        n = len(ious.get("written 2D box", []))
        print(f"## {results} ({n} matched ground-truth cars)")
        print("| 3D box projected | mean IoU | IoU >= 0.85 | IoU >= 0.95 |")
        print("|---|---:|---:|---:|")
        for name, v in ious.items():
            print(
                f"| {name} | {v.mean():.4f} | {np.mean(v >= 0.85):.3f} | {np.mean(v >= 0.95):.3f} |"
            )
        print()
        print(
            "| error (run - ground truth) | mean | std | std of the per-track means "
            "| std within tracks |"
        )
        print("|---|---:|---:|---:|---:|")
        _, track = np.unique(err["keys"], return_inverse=True)
        counts = np.bincount(track)
        for name, v in err["errors"].items():
            means = np.bincount(track, v) / counts
            unit = "rad" if name == "heading" else "m"
            label = "size (height)" if name == "size" else name
            print(
                f"| {label}, {unit} | {v.mean():+.3f} | {v.std():.3f} | {means[track].std():.3f} | "
                f"{(v - means[track]).std():.3f} |"
            )
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
