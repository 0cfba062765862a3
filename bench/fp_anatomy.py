"""Where a run's false-positive rows are, and what each kind costs (an oracle, on the labels).

    python bench/fp_anatomy.py RESULTS_DIR [RESULTS_DIR ...] [--kitti-root ROOT] [--class car]
        [--trim-p 0.8]

RESULTS_DIR holds KITTI result files (`mctrack kitti --out DIR` writes them to DIR/data). Each
row that TrackEval keeps after its KITTI preprocessing (distractors, occluded and truncated
ground truth, small boxes and DontCare regions removed, as for the metrics) is a true positive
when the frame's Hungarian matching on 2D IoU >= 0.5 pairs it with a ground-truth box, else a
false positive. A false positive is classed by where it sits in its track: a track with no true
positive at all, the rows before its first true positive, after its last, or in between. The
oracle figure is the HOTA change with that kind of row deleted from the files (which no tracker
can do without labels): what that kind costs. The last column is a label-free rule for comparison:
each track's rows before its first row of calibrated score >= --trim-p deleted.
"""

from __future__ import annotations

import argparse
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from app.inputs import default_kitti_root
from tracker.eval.kitti import evaluate_kitti, evaluate_kitti_sequence

KINDS = ("whole track", "before first TP", "after last TP", "inside")


def id_inputs(result_file: Path, label_file: Path, length: int, cls: str) -> Any:
    """TrackEval's preprocessed ``(gt ids, result ids, similarities)`` per frame of a sequence,
    under the files' own ids."""
    return evaluate_kitti_sequence(
        label_file=label_file, result_file=result_file, num_timesteps=length,
        classes=[cls], keep_id_inputs=True,
    ).id_inputs[cls]  # fmt: skip


def matched_columns(sim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One frame's true positives: (ground-truth rows, result columns) the Hungarian matching on
    2D IoU >= 0.5 pairs, as TrackEval's CLEAR matching."""
    if not sim.size:
        return np.zeros(0, int), np.zeros(0, int)
    score = np.where(sim >= 0.5 - np.finfo(float).eps, sim, 0.0)
    r, c = linear_sum_assignment(-score)
    ok = score[r, c] > 0
    return r[ok], c[ok]


def matched_ids(gt_ids: np.ndarray, trk_ids: np.ndarray, sim: np.ndarray) -> dict[int, int]:
    """``{ground-truth id: result id}`` of one frame's true positives (:func:`matched_columns`)."""
    r, c = matched_columns(sim)
    return dict(zip(gt_ids[r].tolist(), trk_ids[c].tolist(), strict=True))


def classify(
    result_file: Path, label_file: Path, length: int, cls: str, *, inputs: Any = None
) -> dict[tuple[int, int], str]:
    """``{(frame, track id): kind}`` of the false-positive rows of one sequence (``inputs``:
    its :func:`id_inputs`, when already computed)."""
    if inputs is None:
        inputs = id_inputs(result_file, label_file, length, cls)
    _, trk_ids, sims = inputs
    tp: dict[int, list[int]] = {}
    fp: list[tuple[int, int]] = []
    for frame, (ids, sim) in enumerate(zip(trk_ids, sims, strict=True)):
        hit = np.zeros(len(ids), bool)
        hit[matched_columns(sim)[1]] = True
        for tid, h in zip(ids.tolist(), hit, strict=True):
            if h:
                tp.setdefault(tid, []).append(frame)
            else:
                fp.append((frame, tid))
    kinds = {}
    for frame, tid in fp:
        frames = tp.get(tid)
        if not frames:
            kinds[frame, tid] = KINDS[0]
        elif frame < frames[0]:
            kinds[frame, tid] = KINDS[1]
        elif frame > frames[-1]:
            kinds[frame, tid] = KINDS[2]
        else:
            kinds[frame, tid] = KINDS[3]
    return kinds


def anatomy(result_dir: Path, label_dir: Path, cls: str) -> dict[str, Any]:
    """A run's metrics, its false-positive rows counted by kind, the HOTA with each kind
    deleted (an oracle) and the sequence lengths used."""
    files = sorted(result_dir.glob("*.txt"))
    lengths = {}
    for f in files:  # a sequence's length: its last labelled or tracked frame + 1
        text = f.read_text() + (label_dir / f.name).read_text()
        rows = [line.split(maxsplit=1)[0] for line in text.splitlines() if line.strip()]
        lengths[f.stem] = max(int(r) for r in rows) + 1
    kinds = {f.stem: classify(f, label_dir / f.name, lengths[f.stem], cls) for f in files}
    base = evaluate_kitti(
        label_dir=label_dir, result_dir=result_dir, seq_lengths=lengths, classes=[cls]
    )[cls]
    counts = Counter(k for per in kinds.values() for k in per.values())
    oracle = {}
    with tempfile.TemporaryDirectory(prefix="fp-anatomy-") as tmp:
        for kind in KINDS:
            if not counts[kind]:
                continue
            out = Path(tmp) / kind.replace(" ", "_")
            out.mkdir()
            for f in files:
                drop = {key for key, k in kinds[f.stem].items() if k == kind}
                kept = [
                    line for line in f.read_text().splitlines(keepends=True)
                    if (int(line.split()[0]), int(line.split()[1])) not in drop
                ]  # fmt: skip
                (out / f.name).write_text("".join(kept))
            oracle[kind] = evaluate_kitti(
                label_dir=label_dir, result_dir=out, seq_lengths=lengths, classes=[cls]
            )[cls]["HOTA"]
    return {"metrics": base, "counts": dict(counts), "oracle_hota": oracle, "lengths": lengths}


def anatomy_row(result_dir: Path, *, label_dir: Path, cls: str, trim_p: float) -> str:
    """A results-table row's cells (markdown, after the run's name): HOTA, FP, each kind's rows
    (the HOTA change without them), and the HOTA change of :func:`trim_leading` at ``trim_p``."""
    a = anatomy(result_dir, label_dir, cls)
    m, counts, oracle = a["metrics"], a["counts"], a["oracle_hota"]
    with tempfile.TemporaryDirectory(prefix="fp-trim-") as tmp:
        trim_leading(result_dir, Path(tmp), trim_p)
        trimmed = evaluate_kitti(
            label_dir=label_dir, result_dir=Path(tmp), seq_lengths=a["lengths"], classes=[cls]
        )[cls]
    cells = [f"{counts[k]} ({oracle[k] - m['HOTA']:+.2f})" if k in oracle else "0" for k in KINDS]
    trim = f"{round(trimmed['HOTA'] - m['HOTA'], 2) + 0.0:+.2f}"
    return f"{m['HOTA']:.2f} | {m['FP']} | {' | '.join(cells)} | {trim}"


def trim_leading(result_dir: Path, out_dir: Path, p_min: float) -> None:
    """A label-free rule, for comparison: each track's rows before its first row whose score
    (the calibrated detection score the writer keeps) reaches ``p_min`` are deleted; a track
    that never reaches it is deleted whole."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for f in sorted(result_dir.glob("*.txt")):
        lines = f.read_text().splitlines(keepends=True)
        first: dict[int, int] = {}  # track id -> its first frame scoring >= p_min
        for line in lines:
            cols = line.split()
            if float(cols[17]) >= p_min:
                tid, frame = int(cols[1]), int(cols[0])
                first[tid] = min(frame, first.get(tid, frame))
        kept = [
            line for line in lines
            if int(line.split()[1]) in first and int(line.split()[0]) >= first[int(line.split()[1])]
        ]  # fmt: skip
        (out_dir / f.name).write_text("".join(kept))


def table_head(first: str, trim_p: float) -> list[str]:
    """The header lines of a table of :func:`anatomy_row` rows, after the columns ``first``."""
    kinds = " | ".join(f"{k}: rows (HOTA)" for k in KINDS)
    n = first.count("|") + 1
    return [
        f"| {first} | HOTA | FP | {kinds} | first rows below p {trim_p:g} trimmed (HOTA) |",
        "|" + "---|" * n + "---:|---:|" + "---:|" * (len(KINDS) + 1),
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", type=Path)
    parser.add_argument("--kitti-root", type=Path, default=None)
    parser.add_argument("--class", dest="cls", default="car")
    parser.add_argument("--trim-p", type=float, default=0.8, help="the trimming rule's score")
    args = parser.parse_args()
    label_dir = (args.kitti_root or default_kitti_root()) / "training" / "label_02"
    print("\n".join(table_head("run", args.trim_p)))
    for d in args.results:
        row = anatomy_row(d, label_dir=label_dir, cls=args.cls, trim_p=args.trim_p)
        print(f"| {d} | {row} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
