"""Whose detections a tracker's tracks hold, under the robustness benchmark's noise (an oracle,
on the labels).

    python bench/track_purity.py [--kitti-root ROOT] [--detector pointrcnn] [--class pedestrian]
        [--config kitti_offline] [--levels clean,noise,double] [--seed 0]

Each clean detection is labelled with the ground-truth object whose BEV centre is within 1 m of
it (Hungarian on the distance, per frame), before any noise; the benchmark's perturbation keeps
the label on the boxes it keeps (its false positives have none). The tracker then runs as
`mctrack robustness` runs it (calibrated scores, `follow`), and along each written track, every
two consecutive labelled detections of different objects count as one *object change*, classed
by how far apart the two objects were then. Unlike TrackEval's ID switches (2D boxes matched at
IoU 0.5), this counts the tracker's own association in 3D, whatever the written box.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.inputs import default_kitti_root  # noqa: E402
from tracker.calibration import calibrate_frames, resolve_profile  # noqa: E402
from tracker.categories import CATEGORIES  # noqa: E402
from tracker.config import load_config  # noqa: E402
from tracker.eval.perturb import NOISE_LEVELS, perturb_frames  # noqa: E402
from tracker.events import TrackOutput  # noqa: E402
from tracker.frame import Frame  # noqa: E402
from tracker.io.convert.kitti import VALIDATION_SEQS, convert_kitti  # noqa: E402
from tracker.pipeline import run_scene  # noqa: E402

#: a detection takes the label of a ground-truth object whose BEV centre is this near
LABEL_M = 1.0
#: the classes of the distance between the two objects of a change (metres)
SEPARATION_BINS = (0.5, 1.0, 2.0)
SEPARATION_NAMES = ("0-0.5 m", "0.5-1.0 m", "1.0-2.0 m", "2.0+ m")


def label_detections(frames: Sequence[Frame], truth: Sequence[Frame], category: int) -> list[Frame]:
    """``frames`` with each detection of ``category`` under the id of the ground-truth object
    (of that category, in ``truth``'s frame) within :data:`LABEL_M` of it, -1 for the rest."""
    out = []
    for frame, gt in zip(frames, truth, strict=True):
        objects = gt.boxes[gt.boxes.category == category]
        label = np.full(len(frame.boxes), -1, dtype=np.int64)
        mine = np.flatnonzero(frame.boxes.category == category)
        if len(mine) and len(objects):
            d = np.linalg.norm(frame.boxes.xyz[mine, None, :2] - objects.xyz[None, :, :2], axis=-1)
            r, c = linear_sum_assignment(np.where(d < LABEL_M, d, 1e9))
            ok = d[r, c] < LABEL_M
            label[mine[r[ok]]] = objects.track_id[c[ok]]
        out.append(dataclasses.replace(frame, boxes=frame.boxes.replace(track_id=label)))
    return out


def object_changes(
    outputs: Sequence[TrackOutput], frames: Sequence[Frame], truth: Sequence[Frame]
) -> Counter[str]:
    """Along each track of ``outputs``, the changes between consecutive labelled detections (the
    label in ``frames``' ``track_id``, from :func:`label_detections`), by the two objects'
    distance in the frame of the second (``truth``); also the number of changes and of
    (object, track) pairs."""
    where: dict[tuple[int, int], np.ndarray] = {}  # (frame, object) -> BEV centre
    for i, gt in enumerate(truth):
        for k, p in zip(gt.boxes.track_id.tolist(), gt.boxes.xyz[:, :2], strict=True):
            where[i, k] = p
    held: dict[int, list[tuple[int, int]]] = {}  # track -> [(frame, object)]
    for i, (out, frame) in enumerate(zip(outputs, frames, strict=True)):
        for tid, row in zip(out.boxes.track_id.tolist(), out.det_row.tolist(), strict=True):
            if row >= 0 and frame.boxes.track_id[row] >= 0:
                held.setdefault(tid, []).append((i, int(frame.boxes.track_id[row])))
    counts: Counter[str] = Counter()
    pairs = set()
    for tid, seq in held.items():
        pairs |= {(obj, tid) for _, obj in seq}
        for (_, a), (i, b) in itertools.pairwise(seq):
            if a == b:
                continue
            counts["changes"] += 1
            if (i, a) not in where:
                counts["first object gone"] += 1
                continue
            d = float(np.linalg.norm(where[i, a] - where[i, b]))
            counts[SEPARATION_NAMES[int(np.searchsorted(SEPARATION_BINS, d, side="right"))]] += 1
    counts["object-track pairs"] = len(pairs)
    counts["objects"] = len({obj for obj, _ in pairs})
    return counts


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kitti-root", type=Path, default=None)
    parser.add_argument("--detector", default="pointrcnn")
    parser.add_argument("--class", dest="cls", default="pedestrian", choices=list(CATEGORIES))
    parser.add_argument("--config", default="kitti_offline")
    parser.add_argument("--levels", default="clean,noise,double")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    levels = [s.strip() for s in args.levels.split(",")]
    unknown = [name for name in levels if name not in NOISE_LEVELS]
    if unknown:
        raise SystemExit(f"--levels: unknown {unknown}; known: {', '.join(NOISE_LEVELS)}")
    root = args.kitti_root or default_kitti_root()
    config = load_config(args.config, overrides={"categories": [args.cls]})
    try:
        detections, truth = convert_kitti(
            root, seqs=list(VALIDATION_SEQS), detector=args.detector, classes=[args.cls]
        )
    except (OSError, ValueError) as err:  # (InputError is a ValueError)
        raise SystemExit(f"--kitti-root {root}: {err}") from None
    if truth is None:
        raise SystemExit(f"{root}: no labels for the validation sequences")
    calibration = resolve_profile(args.detector, None)
    category = CATEGORIES.index(args.cls)
    labelled = {
        s: label_detections(calibrate_frames(f, calibration), truth[s], category)
        for s, f in detections.items()
    }
    for name in levels:
        counts: Counter[str] = Counter()
        for s, frames in labelled.items():
            if name != "clean":
                rescore = calibration.scores if calibration is not None else None
                frames = perturb_frames(
                    frames, NOISE_LEVELS[name], seed=args.seed, rescore=rescore,
                    image_boxes="follow",
                )  # fmt: skip
            counts += object_changes(run_scene(frames, config).outputs, frames, truth[s])
        print(f"{name}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
