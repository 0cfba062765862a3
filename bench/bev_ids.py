"""What a run's association costs, judged in 3D: its HOTA with perfect ids in BEV (an oracle, on
the labels).

    python bench/bev_ids.py RESULTS_DIR [RESULTS_DIR ...] [--class pedestrian] [--kitti-root ROOT]
    python bench/bev_ids.py --robustness OUT [--class pedestrian]

Each written row of the class is paired with the ground-truth objects of its frame by the
distance of their BEV centres (the KITTI files' camera x and z; Hungarian, within 1 m) and takes
its object's id; the other rows keep an id of their own that no label holds. Both versions are
scored with TrackEval's KITTI 2D protocol. The rows and their boxes are unchanged, so DetA moves
only where a relabelled id changes which of two overlapping image boxes a label is matched to;
the HOTA gained is what the run's association loses.

``bench/hota_ceiling.py``'s perfect ids pair rows and labels by 2D IoU instead, as TrackEval
does; for pedestrians, whose image boxes overlap in groups and whose written box is narrowed
from the projected cuboid, that pairing trades rows between neighbours the tracker kept apart,
so it does not tell the tracker's association from the image plane's.

``--robustness OUT``: every run of a ``mctrack robustness --out OUT`` folder
(``OUT/runs/<level>/<seed>``), as the mean over its seeds per level, with the change from clean.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.inputs import default_kitti_root  # noqa: E402
from tracker.eval.kitti import evaluate_kitti  # noqa: E402

#: a row takes the id of a ground-truth object whose BEV centre is this near (metres)
MATCH_M = 1.0
#: ids of the rows no label holds, above any label's id
UNMATCHED_ID0 = 1_000_000
#: the KITTI type of each class (label_02 and result files)
KITTI_TYPE = {"car": "Car", "pedestrian": "Pedestrian", "cyclist": "Cyclist"}
KEPT = ("HOTA", "DetA", "AssA", "IDSW")


def _bev_rows(text: str, kitti_type: str) -> dict[int, list[tuple[int, float, float]]]:
    """``{frame: [(id, x, z)]}`` of one file's rows of ``kitti_type`` (camera x and z, metres)."""
    rows: dict[int, list[tuple[int, float, float]]] = {}
    for line in text.splitlines():
        cols = line.split()
        if len(cols) >= 16 and cols[2] == kitti_type:
            row = (int(cols[1]), float(cols[13]), float(cols[15]))
            rows.setdefault(int(cols[0]), []).append(row)
    return rows


def bev_ids(result_text: str, label_text: str, cls: str) -> dict[tuple[int, int], int]:
    """``{(frame, result id): ground-truth id}`` of the result rows of ``cls`` within
    :data:`MATCH_M` of an object of their frame (Hungarian on the BEV centre distance)."""
    kitti_type = KITTI_TYPE[cls]
    labels, results = _bev_rows(label_text, kitti_type), _bev_rows(result_text, kitti_type)
    pairs: dict[tuple[int, int], int] = {}
    for frame, rows in results.items():
        objects = labels.get(frame)
        if not objects:
            continue
        r = np.array([(x, z) for _, x, z in rows])
        g = np.array([(x, z) for _, x, z in objects])
        d = np.linalg.norm(r[:, None] - g[None], axis=-1)
        ri, gi = linear_sum_assignment(np.where(d < MATCH_M, d, 1e9))
        for a, b in zip(ri, gi, strict=True):
            if d[a, b] < MATCH_M:
                pairs[frame, rows[a][0]] = objects[b][0]
    return pairs


def relabel(result_text: str, label_text: str, cls: str) -> str:
    """``result_text`` with each row of ``cls`` under the id :func:`bev_ids` gives it, or
    :data:`UNMATCHED_ID0` + its own id; other classes' rows unchanged."""
    ids = bev_ids(result_text, label_text, cls)
    out = []
    for line in result_text.splitlines():
        cols = line.split()
        if len(cols) >= 16 and cols[2] == KITTI_TYPE[cls]:
            key = (int(cols[0]), int(cols[1]))
            cols[1] = str(ids.get(key, UNMATCHED_ID0 + key[1]))
            line = " ".join(cols)
        if line.strip():
            out.append(line + "\n")
    return "".join(out)


def _lengths(label_dir: Path, results: Path) -> dict[str, int]:
    """Frames per sequence of ``results``: past the last frame of its labels and its rows."""
    lengths = {}
    for f in sorted(results.glob("*.txt")):
        label = label_dir / f.name
        if not label.is_file():
            raise SystemExit(f"{label}: missing (no labels for {f})")
        last = [int(line.split()[0]) for p in (label, f) for line in p.read_text().splitlines()]
        lengths[f.stem] = max(last, default=-1) + 1
    if not lengths:
        raise SystemExit(f"{results}: no <seq>.txt result files")
    return lengths


def score(results: Path, label_dir: Path, cls: str) -> tuple[dict[str, float], dict[str, float]]:
    """(as written, with BEV ids) metrics of one folder of KITTI result files."""
    lengths = _lengths(label_dir, results)
    with tempfile.TemporaryDirectory(prefix="bev-ids-") as tmp:
        for seq in lengths:
            text = (results / f"{seq}.txt").read_text()
            label = (label_dir / f"{seq}.txt").read_text()
            (Path(tmp) / f"{seq}.txt").write_text(relabel(text, label, cls))
        written, perfect = (
            evaluate_kitti(label_dir=label_dir, result_dir=d, seq_lengths=lengths, classes=[cls])
            for d in (results, Path(tmp))
        )
        return (
            {k: float(written[cls][k]) for k in KEPT},
            {k: float(perfect[cls][k]) for k in KEPT},
        )


def robustness_rows(out: Path, label_dir: Path, cls: str) -> list[tuple[str, int, float, float]]:
    """``(level, seeds, HOTA as written, HOTA with BEV ids)`` per level of a robustness folder,
    means over its seeds; clean first."""
    levels = sorted((out / "runs").glob("*"), key=lambda p: (p.name != "clean", p.name))
    rows = []
    for level in levels:
        runs = sorted(p for p in level.iterdir() if p.is_dir())
        if not runs:
            continue
        pairs = [score(run, label_dir, cls) for run in runs]
        rows.append(
            (
                level.name,
                len(runs),
                float(np.mean([a["HOTA"] for a, _ in pairs])),
                float(np.mean([b["HOTA"] for _, b in pairs])),
            )
        )
    if not rows:
        raise SystemExit(f"{out}: no runs/<level>/<seed>/ folders (a `mctrack robustness --out`)")
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", nargs="*", type=Path, help="folders of KITTI result files")
    parser.add_argument("--robustness", type=Path, default=None, help="a robustness --out folder")
    parser.add_argument("--class", dest="cls", default="pedestrian", choices=list(KITTI_TYPE))
    parser.add_argument("--kitti-root", type=Path, default=None)
    args = parser.parse_args()
    if not args.results and args.robustness is None:
        parser.error("give RESULTS_DIR folders or --robustness OUT")
    label_dir = (args.kitti_root or default_kitti_root()) / "training" / "label_02"
    if args.robustness is not None:
        rows = robustness_rows(args.robustness, label_dir, args.cls)
        clean = rows[0][2:] if rows[0][0] == "clean" else (np.nan, np.nan)
        print(f"| level | seeds | {args.cls} HOTA | Δ | with BEV ids | Δ |")
        print("|---|---:|---:|---:|---:|---:|")
        for name, n, a, b in rows:
            da, db = a - clean[0], b - clean[1]
            print(f"| {name} | {n} | {a:.2f} | {da:+.2f} | {b:.2f} | {db:+.2f} |")
    for folder in args.results:
        d = folder / "data" if (folder / "data").is_dir() else folder  # (a `mctrack kitti --out`)
        a, b = score(d, label_dir, args.cls)
        print(
            f"{folder}: HOTA {a['HOTA']:.2f} (DetA {a['DetA']:.2f}, AssA {a['AssA']:.2f});"
            f" with BEV ids {b['HOTA']:.2f} (DetA {b['DetA']:.2f}, AssA {b['AssA']:.2f})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
