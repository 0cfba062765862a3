"""Where a run's false-positive rows are, and what each kind costs (an oracle, on the labels).

    python bench/fp_anatomy.py RESULTS_DIR [RESULTS_DIR ...] [--kitti-root ROOT] [--class car]
        [--trim-p 0.8] [--trim-hidden 0.7]

RESULTS_DIR holds KITTI result files, or is a `mctrack kitti --out` folder (they are in its data/).
Each row that TrackEval keeps after its KITTI preprocessing (distractors, occluded and truncated
ground truth, small boxes and DontCare regions removed, as for the metrics) is a true positive when
the frame's Hungarian matching on 2D IoU >= 0.5 pairs it with a ground-truth box, else a false
positive. A false positive is classed by where it sits in its track: a track with no true positive
at all, the rows before its first true positive, after its last, or in between. The oracle figure
is the HOTA change with that kind of row deleted from the files (which no tracker can do without
labels): what that kind costs. The last two columns are label-free rules for comparison: each
track's rows before its first row of calibrated score >= --trim-p deleted, and each track's rows
before its first row that nearer written boxes hide less than --trim-hidden of (the part of its 2D
box inside the union of the frame's boxes at least 1 m nearer the camera) deleted. A last line per
run counts the rows at least --trim-hidden hidden, by kind.
"""

from __future__ import annotations

import argparse
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from app.inputs import default_kitti_root
from tracker.eval.kitti import evaluate_kitti, evaluate_kitti_sequence
from tracker.io.fileio import work_folder

KINDS = ("whole track", "before first TP", "after last TP", "inside")
#: The label-free trimming rules' defaults: the calibrated score, the hidden fraction.
TRIM_P = 0.8
TRIM_HIDDEN = 0.7


def sequence_length(*files: Path) -> int:
    """A sequence's length: its last labelled, tracked or detected frame + 1."""
    frames = [
        int(line.split(maxsplit=1)[0])
        for f in files
        if f.is_file()
        for line in f.read_text().splitlines()
        if line.strip()
    ]
    return max(frames, default=-1) + 1


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
    lengths = {f.stem: sequence_length(f, label_dir / f.name) for f in files}
    kinds = {f.stem: classify(f, label_dir / f.name, lengths[f.stem], cls) for f in files}
    base = evaluate_kitti(
        label_dir=label_dir, result_dir=result_dir, seq_lengths=lengths, classes=[cls]
    )[cls]
    counts = Counter(k for per in kinds.values() for k in per.values())
    oracle = {}
    with work_folder("fpanatomy") as tmp:
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


def anatomy_row(
    result_dir: Path,
    *,
    label_dir: Path,
    cls: str,
    trim_p: float = TRIM_P,
    trim_hidden: float = TRIM_HIDDEN,
) -> str:
    """A results-table row's cells (markdown, after the run's name): HOTA, FP, each kind's rows
    (the HOTA change without them), and the HOTA changes of :func:`trim_leading` at ``trim_p``
    and of :func:`trim_hidden_leading` at ``trim_hidden``."""
    a = anatomy(result_dir, label_dir, cls)
    m, counts, oracle = a["metrics"], a["counts"], a["oracle_hota"]
    changes = []
    for trim, arg in ((trim_leading, trim_p), (trim_hidden_leading, trim_hidden)):
        with work_folder("fptrim") as tmp:
            trim(result_dir, Path(tmp), arg)
            trimmed = evaluate_kitti(
                label_dir=label_dir, result_dir=Path(tmp), seq_lengths=a["lengths"], classes=[cls]
            )[cls]
        changes.append(f"{round(trimmed['HOTA'] - m['HOTA'], 2) + 0.0:+.2f}")
    cells = [f"{counts[k]} ({oracle[k] - m['HOTA']:+.2f})" if k in oracle else "0" for k in KINDS]
    return f"{m['HOTA']:.2f} | {m['FP']} | {' | '.join(cells)} | {' | '.join(changes)}"


def hidden_fraction(xyxy: np.ndarray, depth: np.ndarray, margin: float = 1.0) -> np.ndarray:
    """(N,) the part of each 2D box (N, 4) inside the union of the boxes whose depth is at least
    ``margin`` smaller (nearer the camera): exact, on the grid of the boxes' own edges."""
    out = np.zeros(len(xyxy))
    for i, box in enumerate(xyxy):
        near = xyxy[depth < depth[i] - margin]
        area = (box[2] - box[0]) * (box[3] - box[1])
        if not len(near) or area <= 0:
            continue
        near = np.column_stack(  # clipped to box i
            [np.maximum(near[:, :2], box[:2]), np.minimum(near[:, 2:], box[2:])]
        )
        near = near[(near[:, 2] > near[:, 0]) & (near[:, 3] > near[:, 1])]
        if not len(near):
            continue
        xs, ys = np.unique(near[:, [0, 2]]), np.unique(near[:, [1, 3]])
        cx, cy = (xs[:-1] + xs[1:]) / 2, (ys[:-1] + ys[1:]) / 2  # cell centres
        inside_x = (near[:, 0, None] <= cx) & (cx <= near[:, 2, None])  # (M, cells in x)
        inside_y = (near[:, 1, None] <= cy) & (cy <= near[:, 3, None])
        covered = (inside_y[:, :, None] & inside_x[:, None, :]).any(axis=0)
        out[i] = (covered * np.outer(np.diff(ys), np.diff(xs))).sum() / area
    return out


def hidden_rows(result_file: Path) -> dict[tuple[int, int], float]:
    """``{(frame, track id): hidden fraction}`` of a result file's rows (:func:`hidden_fraction`
    among the rows of each frame; depth: the camera z of the 3D box)."""
    by_frame: dict[int, list[list[str]]] = {}
    for line in result_file.read_text().splitlines():
        cols = line.split()
        by_frame.setdefault(int(cols[0]), []).append(cols)
    hidden = {}
    for frame, rows in by_frame.items():
        xyxy = np.array([[float(v) for v in r[6:10]] for r in rows])
        fractions = hidden_fraction(xyxy, np.array([float(r[15]) for r in rows]))
        hidden.update({(frame, int(r[1])): h for r, h in zip(rows, fractions, strict=True)})
    return hidden


def trim_hidden_leading(result_dir: Path, out_dir: Path, hidden_max: float) -> None:
    """A label-free rule, for comparison: each track's rows before its first row that nearer
    written boxes hide less than ``hidden_max`` of (:func:`hidden_rows`) are deleted; a track
    never that visible is deleted whole."""
    _trim_before_first(
        result_dir, out_dir, lambda f: [k for k, h in hidden_rows(f).items() if h < hidden_max]
    )


def hidden_counts(result_dir: Path, label_dir: Path, cls: str, hidden_min: float) -> Counter:
    """Rows of class ``cls`` at least ``hidden_min`` hidden (by rows of any class), by kind: each
    false-positive kind, and "true positive or not evaluated" for the rest."""
    counts: Counter = Counter()
    for f in sorted(result_dir.glob("*.txt")):
        kinds = classify(f, label_dir / f.name, sequence_length(f, label_dir / f.name), cls)
        of_class = {
            (int(c[0]), int(c[1]))
            for c in map(str.split, f.read_text().splitlines())
            if c and c[2].lower() == cls
        }
        for key, h in hidden_rows(f).items():
            if h >= hidden_min and key in of_class:
                counts[kinds.get(key, "true positive or not evaluated")] += 1
    return counts


def trim_leading(result_dir: Path, out_dir: Path, p_min: float) -> None:
    """A label-free rule, for comparison: each track's rows before its first row whose score
    (the calibrated detection score the writer keeps) reaches ``p_min`` are deleted; a track
    that never reaches it is deleted whole."""

    def confident(f: Path) -> list[tuple[int, int]]:
        rows = map(str.split, f.read_text().splitlines())
        return [(int(c[0]), int(c[1])) for c in rows if float(c[17]) >= p_min]

    _trim_before_first(result_dir, out_dir, confident)


def _trim_before_first(
    result_dir: Path, out_dir: Path, rows_of: Callable[[Path], list[tuple[int, int]]]
) -> None:
    """Each result file of ``result_dir`` written to ``out_dir`` without each track's rows before
    its first ``(frame, track id)`` in ``rows_of(file)``; a track with none there is left out."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for f in sorted(result_dir.glob("*.txt")):
        first: dict[int, int] = {}  # track id -> its first qualifying frame
        for frame, tid in rows_of(f):
            first[tid] = min(frame, first.get(tid, frame))
        kept = [
            line for line in f.read_text().splitlines(keepends=True)
            if int(line.split()[1]) in first and int(line.split()[0]) >= first[int(line.split()[1])]
        ]  # fmt: skip
        (out_dir / f.name).write_text("".join(kept))


def table_head(first: str, trim_p: float = TRIM_P, trim_hidden: float = TRIM_HIDDEN) -> list[str]:
    """The header lines of a table of :func:`anatomy_row` rows, after the columns ``first``."""
    kinds = " | ".join(f"{k}: rows (HOTA)" for k in KINDS)
    n = first.count("|") + 1
    return [
        f"| {first} | HOTA | FP | {kinds} | first rows below p {trim_p:g} trimmed (HOTA) "
        f"| first rows hidden >= {trim_hidden:g} trimmed (HOTA) |",
        "|" + "---|" * n + "---:|---:|" + "---:|" * (len(KINDS) + 2),
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", type=Path)
    parser.add_argument("--kitti-root", type=Path, default=None)
    parser.add_argument("--class", dest="cls", default="car")
    parser.add_argument("--trim-p", type=float, default=TRIM_P, help="the trimming rule's score")
    parser.add_argument(
        "--trim-hidden", type=float, default=TRIM_HIDDEN,
        help="the occlusion trimming rule's fraction",
    )  # fmt: skip
    args = parser.parse_args()
    label_dir = (args.kitti_root or default_kitti_root()) / "training" / "label_02"
    dirs = [results_dir(d) for d in args.results]
    print("\n".join(table_head("run", args.trim_p, args.trim_hidden)))
    for d in dirs:
        row = anatomy_row(
            d, label_dir=label_dir, cls=args.cls, trim_p=args.trim_p, trim_hidden=args.trim_hidden
        )
        print(f"| {d} | {row} |", flush=True)
    for d in dirs:
        counts = hidden_counts(d, label_dir, args.cls, args.trim_hidden)
        parts = ", ".join(f"{k} {n}" for k, n in sorted(counts.items()))
        print(f"{d}: rows at least {args.trim_hidden:g} hidden by nearer rows: {parts}")
    return 0


def results_dir(path: Path) -> Path:
    """The folder of result files: ``path`` or its ``data/`` (a `mctrack kitti --out` folder);
    a folder with neither is an error naming it."""
    for d in (path, path / "data"):
        if any(d.glob("*.txt")):
            return d
    raise SystemExit(f"{path}: no KITTI result files (<seq>.txt) in it or in its data/ folder")


if __name__ == "__main__":
    raise SystemExit(main())
