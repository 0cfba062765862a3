"""Where a run's false negatives are, and whether the detector saw them (an oracle, on the labels).

    python bench/fn_anatomy.py RESULTS_DIR --detector NAME [--kitti-root ROOT] [--class car]

RESULTS_DIR holds KITTI result files, or is a `mctrack kitti --out` folder (they are in its data/).
A ground-truth row that TrackEval keeps after its KITTI preprocessing and that the frame's
Hungarian matching (2D IoU >= 0.5) leaves unpaired is a false negative. It is classed twice:

- *seen*: some box of the detector's, of the class and at any score, overlaps it at IoU >= 0.5
  (the detections written as a result file, one id per box, through the same preprocessing).
  An unseen row can only come back by interpolating or extrapolating a track;
- where it sits in its object's history: before the object's first matched frame, after its
  last, in between, or an object the run never matches.

It also reports the false-positive rows before a track's first true positive and after its last
(bench/fp_anatomy.py) whose object, the one the track matches first (last), has no label at all
in that frame: the detector and the tracker found an object the annotators had not labelled yet,
or no longer.
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from fp_anatomy import KINDS, classify, id_inputs, matched_ids, results_dir, sequence_length

from app.inputs import default_kitti_root
from tracker.io.fileio import work_folder

PLACES = ("before", "inside", "after", "never matched")


def classify_misses(
    label_file: Path, result_file: Path, detection_file: Path, cls: str, *, run: Any = None
) -> Counter[tuple[str, bool]]:
    """Count one sequence's false negatives by ``(place, seen)`` (see the module docstring).
    ``detection_file``: the detector's boxes in the KITTI result format, one id per box; ``run``:
    the result file's ``fp_anatomy.id_inputs``, when already computed."""
    n = sequence_length(label_file, result_file, detection_file)
    if run is None:
        run = id_inputs(result_file, label_file, n, cls)
    dets = id_inputs(detection_file, label_file, n, cls)
    matched = [matched_ids(*(x[t] for x in run)) for t in range(len(run[0]))]
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    for t, pairs in enumerate(matched):
        for gid in pairs:
            first.setdefault(gid, t)
            last[gid] = t
    counts: Counter[tuple[str, bool]] = Counter()
    for t, gt_ids in enumerate(run[0]):
        det_gt, _, sim = (x[t] for x in dets)
        covered = sim.max(axis=1) >= 0.5 - np.finfo(float).eps if sim.size else []
        seen = set(det_gt[covered].tolist()) if sim.size else set()
        for gid in gt_ids.tolist():
            if gid in matched[t]:
                continue
            if gid not in first:
                place = PLACES[3]
            else:
                place = PLACES[0] if t < first[gid] else PLACES[2] if t > last[gid] else PLACES[1]
            counts[place, gid in seen] += 1
    return counts


def unlabelled_end_rows(
    label_file: Path, result_file: Path, cls: str, *, run: Any = None
) -> dict[str, tuple[int, int]]:
    """``{kind: (rows, unlabelled)}`` for the false-positive rows before their track's first true
    positive (``fp_anatomy.KINDS[1]``) and after its last (``KINDS[2]``): how many, and how many
    of them whose object, the ground truth the track matches first (last), has no row in the
    label file that frame. ``run``: the result file's ``fp_anatomy.id_inputs``, when already
    computed."""
    n = sequence_length(label_file, result_file)
    if run is None:
        run = id_inputs(result_file, label_file, n, cls)
    kinds = classify(result_file, label_file, n, cls, inputs=run)
    first: dict[int, int] = {}  # track id -> the ground-truth id it matches first
    last: dict[int, int] = {}  # ... and last
    for t in range(len(run[0])):
        for gid, tid in matched_ids(*(x[t] for x in run)).items():
            first.setdefault(tid, gid)
            last[tid] = gid
    labelled = {
        (int(c[0]), int(c[1]))
        for c in (line.split() for line in label_file.read_text().splitlines())
        if len(c) > 1
    }
    out = {}
    for kind, object_of in ((KINDS[1], first), (KINDS[2], last)):
        rows = [key for key, k in kinds.items() if k == kind]
        out[kind] = (len(rows), sum((t, object_of[tid]) not in labelled for t, tid in rows))
    return out


def write_detections(kitti_root: Path, detector: str, seqs: list[str], cls: str, out: Path) -> None:
    """The detector's boxes of ``cls`` (any layout the tracker reads) as KITTI result files, one
    id per box, so TrackEval's preprocessing treats them as it treats a run's rows."""
    from tracker.categories import category_index
    from tracker.io.convert.kitti import convert_kitti

    frames, _ = convert_kitti(kitti_root, seqs=seqs, detector=detector, classes=[cls])
    name = {"car": "Car", "pedestrian": "Pedestrian", "cyclist": "Cyclist"}[cls]
    out.mkdir(parents=True, exist_ok=True)
    for seq, scene in frames.items():
        lines, next_id = [], 0
        for t, frame in enumerate(scene):
            keep = frame.boxes.category == category_index(cls)
            for box in frame.boxes.xyxy_image[keep]:
                if np.isfinite(box).all():
                    coords = " ".join(f"{v:.2f}" for v in box)
                    lines.append(f"{t} {next_id} {name} 0 0 0 {coords} 1 1 1 0 0 10 0 1\n")
                    next_id += 1
        (out / f"{seq}.txt").write_text("".join(lines))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("--detector", required=True, help="the run's detections folder name")
    parser.add_argument("--kitti-root", type=Path, default=None)
    # (not pedestrians: their labelled 2D boxes are narrower than a LiDAR box's projection, which
    # the writer narrows and a raw detection's box is not, so "seen" would be undercounted)
    parser.add_argument("--class", dest="cls", default="car", choices=["car", "cyclist"])
    args = parser.parse_args()
    root = args.kitti_root or default_kitti_root()
    label_dir = root / "training" / "label_02"
    args.results = results_dir(args.results)
    seqs = sorted(f.stem for f in args.results.glob("*.txt"))
    unlabelled = [s for s in seqs if not (label_dir / f"{s}.txt").is_file()]
    if unlabelled:
        raise SystemExit(f"{label_dir}: no labels for {', '.join(unlabelled)}")
    counts: Counter[tuple[str, bool]] = Counter()
    ends: Counter[tuple[str, int]] = Counter()
    with work_folder("fnanatomy") as tmp:
        try:
            write_detections(root, args.detector, seqs, args.cls, Path(tmp))
        except (OSError, ValueError) as err:  # (InputError is a ValueError)
            raise SystemExit(f"--detector {args.detector}: {err}") from None
        for seq in seqs:
            label, result = label_dir / f"{seq}.txt", args.results / f"{seq}.txt"
            detections = Path(tmp) / f"{seq}.txt"
            run = id_inputs(result, label, sequence_length(label, result, detections), args.cls)
            counts += classify_misses(label, result, detections, args.cls, run=run)
            for kind, pair in unlabelled_end_rows(label, result, args.cls, run=run).items():
                ends[kind, 0] += pair[0]
                ends[kind, 1] += pair[1]
    print("| missed rows | " + " | ".join(PLACES) + " | all |")
    print("|---|" + "---:|" * (len(PLACES) + 1))
    for seen in (True, False):
        cells = [counts[p, seen] for p in PLACES]
        name = "a detection at IoU >= 0.5" if seen else "no detection at IoU >= 0.5"
        print(f"| {name} | " + " | ".join(map(str, cells)) + f" | {sum(cells)} |")
    ends_text = {KINDS[1]: "before their track's first", KINDS[2]: "after their track's last"}
    for kind, where in ends_text.items():
        print(
            f"false positives {where} true positive: {ends[kind, 0]}, of which their object has"
            f" no label in that frame: {ends[kind, 1]}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
