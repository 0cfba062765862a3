"""What a run's association costs, judged in 3D: its HOTA with ids assigned in BEV (an oracle, on
the labels).

    python bench/bev_ids.py RESULTS_DIR [RESULTS_DIR ...] [--class pedestrian] [--kitti-root ROOT]
        [--match-m 1.0]
    python bench/bev_ids.py --robustness OUT [--class pedestrian] [--match-m 1.0]

Each written row of the class is paired with the ground-truth objects of its frame by the
distance of their BEV centres (the KITTI files' camera x and z; Hungarian, within --match-m,
default 1 m) and takes its object's id; the other rows keep an id of their own that no label
holds. Both versions are scored with TrackEval's KITTI 2D protocol. The rows and their boxes are
unchanged, so DetA moves only where a relabelled id changes which of two overlapping image boxes
a label is matched to; the HOTA gained is what the run's association loses (nearly: a row
farther than --match-m from every object keeps its own id, so the figure depends a little on
the distance).

``bench/hota_ceiling.py``'s perfect ids pair rows and labels by 2D IoU instead, as TrackEval
does; for pedestrians, whose image boxes overlap in groups and whose written box is narrowed
from the projected cuboid, that pairing trades rows between neighbours the tracker kept apart,
so it does not tell the tracker's association from the image plane's.

``--robustness OUT``: every run of a ``mctrack robustness --out OUT`` folder
(``OUT/runs/<level>/<seed>``), as the mean over its seeds per level, with the change from clean.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fp_anatomy import sequence_length  # noqa: E402

from app.inputs import default_kitti_root  # noqa: E402
from tracker.errors import InputError  # noqa: E402
from tracker.eval.kitti import evaluate_kitti  # noqa: E402
from tracker.io.convert.kitti import read_kitti_labels  # noqa: E402
from tracker.io.fileio import work_folder  # noqa: E402

#: a row takes the id of a ground-truth object whose BEV centre is this near (metres)
MATCH_M = 1.0
#: ids of the rows no label holds, above any label's id
UNMATCHED_ID0 = 1_000_000
#: the KITTI type of each class (label_02 and result files)
KITTI_TYPE = {"car": "Car", "pedestrian": "Pedestrian", "cyclist": "Cyclist"}
KEPT = ("HOTA", "DetA", "AssA", "IDSW")


def _bev_rows(path: Path, kitti_type: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame, id, camera x and z (K, 2)) of one label or result file's rows of ``kitti_type``,
    read by the project's KITTI reader (``InputError`` naming the file, line and field)."""
    objects = read_kitti_labels(path)
    mine = objects.type_name == kitti_type
    return objects.frame[mine], objects.track_id[mine], objects.xyz_bottom_rect[mine][:, [0, 2]]


def bev_ids(
    result: Path, label: Path, cls: str, match_m: float = MATCH_M
) -> dict[tuple[int, int], int]:
    """``{(frame, result id): ground-truth id}`` of the result rows of ``cls`` within ``match_m``
    of an object of their frame (Hungarian on the BEV centre distance)."""
    kitti_type = KITTI_TYPE[cls]
    r_frame, r_id, r_xz = _bev_rows(result, kitti_type)
    g_frame, g_id, g_xz = _bev_rows(label, kitti_type)
    pairs: dict[tuple[int, int], int] = {}
    for frame in np.unique(r_frame):
        rows, objects = np.flatnonzero(r_frame == frame), np.flatnonzero(g_frame == frame)
        if not len(objects):
            continue
        d = np.linalg.norm(r_xz[rows, None] - g_xz[None, objects], axis=-1)
        ri, gi = linear_sum_assignment(np.where(d < match_m, d, 1e9))
        for a, b in zip(ri, gi, strict=True):
            if d[a, b] < match_m:
                pairs[int(frame), int(r_id[rows[a]])] = int(g_id[objects[b]])
    return pairs


def relabel(result: Path, label: Path, cls: str, match_m: float = MATCH_M) -> str:
    """The result file's text with each row of ``cls`` under the id :func:`bev_ids` gives it,
    or :data:`UNMATCHED_ID0` + its own id; other classes' rows unchanged."""
    ids = bev_ids(result, label, cls, match_m)
    out = []
    for line in result.read_text().splitlines():
        cols = line.split()
        if not cols:
            continue
        if cols[2] == KITTI_TYPE[cls]:
            key = (int(cols[0]), int(cols[1]))
            cols[1] = str(ids.get(key, UNMATCHED_ID0 + key[1]))
        out.append(" ".join(cols) + "\n")
    return "".join(out)


def score(
    results: Path, label_dir: Path, cls: str, match_m: float = MATCH_M
) -> tuple[dict[str, float], dict[str, float]]:
    """(as written, with BEV ids) metrics of one folder of KITTI result files; ``SystemExit``
    naming the file where one is missing or not KITTI rows."""
    files = sorted(results.glob("*.txt"))
    if not files:
        raise SystemExit(f"{results}: no <seq>.txt result files")
    lengths = {}
    with work_folder("bevids") as tmp:
        for f in files:
            label = label_dir / f.name
            if not label.is_file():
                raise SystemExit(f"{label}: missing (no labels for {f})")
            try:
                relabelled = relabel(f, label, cls, match_m)
            except InputError as err:
                raise SystemExit(str(err)) from None
            lengths[f.stem] = sequence_length(label, f)
            (Path(tmp) / f.name).write_text(relabelled)
        written, perfect = (
            evaluate_kitti(label_dir=label_dir, result_dir=d, seq_lengths=lengths, classes=[cls])
            for d in (results, Path(tmp))
        )
        return (
            {k: float(written[cls][k]) for k in KEPT},
            {k: float(perfect[cls][k]) for k in KEPT},
        )


def _levels(out: Path) -> list[Path]:
    """The level folders of a robustness folder: in its report's order where it has one
    (``robustness.json``), else clean first and the others by name."""
    found = {p.name: p for p in (out / "runs").glob("*") if p.is_dir()}
    order: list[str] = []
    report = out / "robustness.json"
    if report.is_file():
        try:
            order = [str(name) for name in json.loads(report.read_text()).get("levels", [])]
        except (ValueError, AttributeError):
            order = []  # (an unreadable report: the folders' own order)
    rest = sorted(set(found) - set(order), key=lambda n: (n != "clean", n))
    return [found[n] for n in [*order, *rest] if n in found]


def robustness_rows(
    out: Path, label_dir: Path, cls: str, match_m: float = MATCH_M
) -> list[tuple[str, int, float, float]]:
    """``(level, seeds, HOTA as written, HOTA with BEV ids)`` per level of a robustness folder
    (:func:`_levels`' order), means over its seeds."""
    rows = []
    for level in _levels(out):
        runs = sorted(p for p in level.iterdir() if p.is_dir())
        if not runs:
            continue
        pairs = [score(run, label_dir, cls, match_m) for run in runs]
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
    parser.add_argument(
        "--match-m", type=float, default=MATCH_M, help="a row's farthest object (BEV, metres)"
    )
    args = parser.parse_args()
    if not args.results and args.robustness is None:
        parser.error("give RESULTS_DIR folders or --robustness OUT")
    label_dir = (args.kitti_root or default_kitti_root()) / "training" / "label_02"
    if args.robustness is not None:
        rows = robustness_rows(args.robustness, label_dir, args.cls, args.match_m)
        clean = next((row[2:] for row in rows if row[0] == "clean"), None)
        if clean is None:
            raise SystemExit(f"{args.robustness}: no runs/clean/ (the Δ columns are from clean)")
        print(f"| level | seeds | {args.cls} HOTA | Δ | with BEV ids | Δ |")
        print("|---|---:|---:|---:|---:|---:|")
        for name, n, a, b in rows:
            da, db = a - clean[0], b - clean[1]
            print(f"| {name} | {n} | {a:.2f} | {da:+.2f} | {b:.2f} | {db:+.2f} |")
    for folder in args.results:
        d = folder / "data" if (folder / "data").is_dir() else folder  # (a `mctrack kitti --out`)
        a, b = score(d, label_dir, args.cls, args.match_m)
        print(
            f"{folder}: HOTA {a['HOTA']:.2f} (DetA {a['DetA']:.2f}, AssA {a['AssA']:.2f});"
            f" with BEV ids {b['HOTA']:.2f} (DetA {b['DetA']:.2f}, AssA {b['AssA']:.2f})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
