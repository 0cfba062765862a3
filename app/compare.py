"""`mctrack compare RUN_A RUN_B --out DIR`: what changed from run A to run B.

RUN_A and RUN_B are two `mctrack kitti --out` folders (or two tracks.json files with the same
ground truth, ``--gt``). The ID switches and fragmentations of the two runs are matched (same
sequence, kind, class and GT id, frames within ``--tolerance``) into fixed (A only), introduced
(B only) and kept (both), with their causes where the runs were recorded (``--record``); the
metrics are compared per class and per sequence. Writes ``DIR/compare.json`` and
``DIR/compare.md``; with ``--record`` also ``DIR/recordings/<seq>.rrd``, each with both runs
side by side and the fixed and introduced events at their frames.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any

from app.runs import Run, load_run, run_names
from tracker.errors import InputError
from tracker.eval.compare import DEFAULT_TOLERANCE, compare_markdown, compare_runs
from tracker.io.fileio import check_output_folder, path_in, write_text_atomic


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_a", metavar="RUN_A", help="baseline: a `mctrack kitti` folder")
    parser.add_argument("run_b", metavar="RUN_B", help="the changed run, same kind as RUN_A")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument(
        "--labels",
        default=None,
        metavar="DIR",
        help="KITTI label_02 folder (default: the one in the runs' summary.json)",
    )
    parser.add_argument(
        "--gt", default=None, metavar="GT", help="ground truth (BaseVersion) for tracks.json runs"
    )
    parser.add_argument(
        "--tolerance",
        type=int,
        default=DEFAULT_TOLERANCE,
        help="frames two runs' events may differ by and still be the same event",
    )
    parser.add_argument(
        "--record",
        action="store_true",
        help="also one recording per sequence with both runs side by side (DIR/recordings/)",
    )


def load_pair(args: argparse.Namespace) -> tuple[Run, Run]:
    a, b = Path(args.run_a), Path(args.run_b)
    labels = Path(args.labels) if args.labels else None
    gt = Path(args.gt) if args.gt else None
    na, nb = run_names(a, b)
    run_a = load_run(a, labels=labels, gt=gt, name=na)
    run_b = load_run(b, labels=labels, gt=gt, name=nb)
    if run_a.kind != run_b.kind:
        raise InputError(f"{b}: a {run_b.kind} run; {a} is a {run_a.kind} run: compare like runs")
    return run_a, run_b


def run(args: argparse.Namespace) -> int:
    if args.tolerance < 0:
        raise InputError(f"--tolerance {args.tolerance}: must be >= 0")
    out = check_output_folder(args.out)
    run_a, run_b = load_pair(args)
    command = "mctrack compare " + " ".join(
        shlex.quote(x) for x in [args.run_a, args.run_b, "--out", args.out]
    )
    result = compare(run_a, run_b, out, tolerance=args.tolerance, command=command)
    if args.record:
        result["recordings"] = record(run_a, run_b, result, out)
        write_text_atomic(out / "compare.json", [json.dumps(result, indent=1)])
    _print(result, out)
    return 0


def compare(
    run_a: Run, run_b: Run, out: Path, *, tolerance: int, command: str | None = None
) -> dict[str, Any]:
    """Compare and write ``out/compare.json`` and ``out/compare.md``; returns the result."""
    result = compare_runs(
        run_a.summary,
        run_b.summary,
        run_a.events,
        run_b.events,
        tolerance=tolerance,
        names=(run_a.name, run_b.name),
    )
    if command:
        result["command"] = command
    write_text_atomic(out / "compare.json", [json.dumps(result, indent=1)])
    write_text_atomic(out / "compare.md", ["\n".join(compare_markdown(result, command=command))])
    return result


def record(run_a: Run, run_b: Run, result: dict[str, Any], out: Path) -> dict[str, str]:
    """One side-by-side recording per sequence of both runs; {sequence: path}."""
    from tracker.io.baseversion import read_baseversion
    from viz.compare_record import record_comparison

    if run_a.kind != "kitti":
        raise InputError(f"{run_a.path}: --record needs `mctrack kitti` run folders")
    tracks = []
    for r in (run_a, run_b):
        file = r.folder / "tracks.json"
        if not file.is_file():
            raise InputError(f"{file}: missing (--record draws each run's tracks from it)")
        tracks.append(read_baseversion(file))
    seqs = [s for s in run_a.summary["sequences"] if s in tracks[0] and s in tracks[1]]
    gt = _ground_truth(run_a, seqs)
    written: dict[str, str] = {}
    for seq in seqs:
        pairs = [p for p in result["events"] if (p["a"] or p["b"])["sequence"] == seq]
        lines = [
            f"# {seq}: {run_a.name} (A, blue) | {run_b.name} (B, orange)",
            "",
            "| status | kind | frame | class | GT | A tracks | B tracks | cause |",
            "|---|---|---:|---|---:|---|---|---|",
        ]
        for p in pairs:
            if p["status"] == "kept":
                continue
            e = p["a"] or p["b"]
            ta = f"T{e['old_track']}->T{e['new_track']}" if p["a"] else ""
            tb = f"T{e['old_track']}->T{e['new_track']}" if p["b"] else ""
            lines.append(
                f"| {p['status']} | {e['kind']} | {e['frame']} | {e['class']} | {e['gt_id']} "
                f"| {ta} | {tb} | {e.get('cause') or ''} |"
            )
        kept = sum(p["status"] == "kept" for p in pairs)
        lines += ["", f"Kept in both: {kept}."]
        path = record_comparison(
            path_in(out / "recordings", seq, ".rrd"),
            seq,
            tracks[0][seq],
            tracks[1][seq],
            gt.get(seq),
            pairs,
            names=(run_a.name, run_b.name),
            summary_markdown="\n".join(lines),
        )
        written[seq] = str(path)
    return written


def _ground_truth(run: Run, seqs: list[str]) -> dict[str, Any]:
    """GT frames per sequence from the KITTI kit (empty, with a note, when it is absent)."""
    from app.inputs import default_kitti_root
    from tracker.io.convert.kitti import convert_kitti

    root = Path(run.summary.get("kitti_root") or default_kitti_root())
    if not (root / "training" / "label_02").is_dir():
        print(f"compare: no KITTI kit at {root}: recordings without ground truth", file=sys.stderr)
        return {}
    _, gt = convert_kitti(
        root,
        seqs=seqs,
        detector=str(run.summary.get("detector") or "pointrcnn"),
        poses="orbslam3",
        classes=tuple(run.summary["classes"]),
        with_gt=True,
    )
    return gt or {}


def _print(result: dict[str, Any], out: Path) -> None:
    counts = result["counts"].get("total", {})
    for key, c in counts.items():
        print(
            f"{key:<20} fixed {c['fixed']:>3}  introduced {c['introduced']:>3}  kept {c['kept']:>3}"
        )
    for cls, m in result["metrics"].items():
        if "HOTA" in m and m["HOTA"]["delta"] is not None:
            print(
                f"{cls:<20} HOTA {m['HOTA']['a']} -> {m['HOTA']['b']} ({m['HOTA']['delta']:+.3f})"
            )
    print(f"wrote {out / 'compare.json'} and {out / 'compare.md'}")
    for seq, path in result.get("recordings", {}).items():
        print(f"recording {seq}: {path}")
