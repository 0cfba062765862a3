"""How much HOTA is left for a tracker to win on a detector's boxes (an oracle, on the labels).

    python bench/hota_ceiling.py --detector NAME [RESULTS_DIR ...] [--kitti-root ROOT]
        [--class car] [--max-gap 30]

Each RESULTS_DIR holds KITTI result files of the detector, or is a `mctrack kitti --out` folder
(they are in its data/). Every figure is TrackEval's KITTI 2D evaluation, and a true positive is a
row that its preprocessing keeps and the frame's Hungarian matching (2D IoU >= 0.5) pairs with a
ground-truth row. Rows, best last:

- each run as it is;
- the run with perfect ids: each true positive under its ground truth's id, every other row
  under an id of its own track no label holds. What the run's association leaves;
- the detector's oracle: the detector's boxes (any score) that are true positives, under their
  ground truth's id, and nothing else. Perfect association and no false positive, on the
  detector's boxes as they are;
- the same, with each object's gaps of up to --max-gap frames between two of its true positives
  filled by the linear interpolation of its 2D box (offline interpolation at its best).

The oracle is a reference, not a strict bound: a tracker may also write boxes that overlap their
object below IoU 0.5 (HOTA counts them at its lower thresholds), smooth a box closer to the
label, or write frames beyond an object's first and last detection.
"""

from __future__ import annotations

import argparse
from itertools import pairwise
from pathlib import Path
from typing import Any

from fn_anatomy import write_detections
from fp_anatomy import id_inputs, matched_ids, results_dir, sequence_length

from app.inputs import default_kitti_root
from tracker.eval.kitti import evaluate_kitti
from tracker.io.fileio import work_folder

# ids of rows no label holds, above any label's id
UNMATCHED_ID0 = 1_000_000


def true_positive_ids(inputs: Any) -> dict[tuple[int, int], int]:
    """``{(frame, result id): ground-truth id}`` of one sequence's true positives, from its
    ``fp_anatomy.id_inputs``."""
    return {
        (t, k): g
        for t, frame in enumerate(zip(*inputs, strict=True))
        for g, k in matched_ids(*frame).items()
    }


def relabel(result_file: Path, tp_ids: dict[tuple[int, int], int], *, keep_others: bool) -> str:
    """The result file with each true positive under its ground truth's id (``tp_ids`` from
    :func:`true_positive_ids`); every other row under ``UNMATCHED_ID0`` + its own id, or dropped."""
    out = []
    for line in result_file.read_text().splitlines():
        cols = line.split()
        if not cols:
            continue
        gid = tp_ids.get((int(cols[0]), int(cols[1])))
        if gid is None and not keep_others:
            continue
        cols[1] = str(gid if gid is not None else UNMATCHED_ID0 + int(cols[1]))
        out.append(" ".join(cols) + "\n")
    return "".join(out)


def interpolate(text: str, max_gap: int) -> str:
    """``text`` (KITTI result rows) with each id's gaps of 1..``max_gap`` frames between two of
    its rows filled: the 2D box (columns 6-9) linear in the frame, the other columns the earlier
    row's. Rows sorted by frame, then id."""
    rows = [line.split() for line in text.splitlines() if line.strip()]
    by_id: dict[int, list[list[str]]] = {}
    for cols in rows:
        by_id.setdefault(int(cols[1]), []).append(cols)
    filled = list(rows)
    for track in by_id.values():
        track.sort(key=lambda c: int(c[0]))
        for a, b in pairwise(track):
            t0, t1 = int(a[0]), int(b[0])
            if not 1 < t1 - t0 <= max_gap + 1:
                continue
            for t in range(t0 + 1, t1):
                w = (t - t0) / (t1 - t0)
                box = [(1 - w) * float(a[i]) + w * float(b[i]) for i in range(6, 10)]
                filled.append([str(t), a[1], *a[2:6], *(f"{v:.2f}" for v in box), *a[10:]])
    filled.sort(key=lambda c: (int(c[0]), int(c[1])))
    return "".join(" ".join(c) + "\n" for c in filled)


def ceiling_rows(
    runs: list[Path], detections: Path, label_dir: Path, cls: str, max_gap: int
) -> list[tuple[str, dict[str, float]]]:
    """``(name, metrics)`` of each row of the module docstring's table. ``detections``: a folder
    of the detector's boxes as result files, one id per box (``fn_anatomy.write_detections``)."""
    seqs = sorted(f.stem for f in detections.glob("*.txt"))
    folders = [*runs, detections]  # (the last one: the detector's)
    lengths = {
        s: sequence_length(label_dir / f"{s}.txt", *(d / f"{s}.txt" for d in folders)) for s in seqs
    }
    variants: dict[str, dict[str, str]] = {}
    for folder in folders:
        name = str(folder)
        for s in seqs:
            f, label = folder / f"{s}.txt", label_dir / f"{s}.txt"
            if not f.is_file():
                raise SystemExit(f"{f}: missing (the detector's sequences are {', '.join(seqs)})")
            tp = true_positive_ids(id_inputs(f, label, lengths[s], cls))
            if folder is detections:
                oracle = relabel(f, tp, keep_others=False)
                variants.setdefault("oracle", {})[s] = oracle
                variants.setdefault("oracle interpolated", {})[s] = interpolate(oracle, max_gap)
            else:
                variants.setdefault(name, {})[s] = f.read_text()
                variants.setdefault(f"{name} perfect ids", {})[s] = relabel(f, tp, keep_others=True)
    rows = []
    with work_folder("hotaceiling") as tmp:
        for i, (name, files) in enumerate(variants.items()):
            out = Path(tmp) / str(i)
            out.mkdir()
            for s, text in files.items():
                (out / f"{s}.txt").write_text(text)
            metrics = evaluate_kitti(
                label_dir=label_dir, result_dir=out, seq_lengths=lengths, classes=[cls]
            )[cls]
            rows.append((name, metrics))
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="*", type=Path, help="result folders of the detector")
    parser.add_argument("--detector", required=True, help="the detections folder name")
    parser.add_argument("--kitti-root", type=Path, default=None)
    # (not pedestrians: a raw detection's 2D box is the wide projection the writer narrows)
    parser.add_argument("--class", dest="cls", default="car", choices=["car", "cyclist"])
    parser.add_argument("--max-gap", type=int, default=30, help="longest gap interpolated")
    parser.add_argument("--seqs", default=None, help="comma-separated; default: the runs' or all")
    args = parser.parse_args()
    root = args.kitti_root or default_kitti_root()
    label_dir = root / "training" / "label_02"
    args.results = [results_dir(d) for d in args.results]
    if args.seqs:
        seqs = sorted(args.seqs.split(","))
    elif args.results:
        seqs = sorted(f.stem for f in args.results[0].glob("*.txt"))
    else:
        seqs = sorted(f.stem for f in label_dir.glob("*.txt"))
    if not seqs:
        raise SystemExit(f"{args.results[0] if args.results else label_dir}: no <seq>.txt files")
    unlabelled = [s for s in seqs if not (label_dir / f"{s}.txt").is_file()]
    if unlabelled:
        raise SystemExit(f"{label_dir}: no labels for {', '.join(unlabelled)}")
    with work_folder("hotaceiling") as tmp:
        try:
            write_detections(root, args.detector, seqs, args.cls, Path(tmp))
        except (OSError, ValueError) as err:  # (InputError is a ValueError)
            raise SystemExit(f"--detector {args.detector}: {err}") from None
        rows = ceiling_rows(args.results, Path(tmp), label_dir, args.cls, args.max_gap)
    print("| rows | HOTA | DetA | AssA | IDSW | FP | FN |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, m in rows:
        print(
            f"| {name} | {m['HOTA']:.2f} | {m['DetA']:.2f} | {m['AssA']:.2f} | {m['IDSW']:.0f}"
            f" | {m['FP']:.0f} | {m['FN']:.0f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
