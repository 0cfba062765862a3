"""`mctrack compare RUN_A RUN_B --out DIR`: what changed from run A to run B.

RUN_A and RUN_B are two `mctrack kitti --out` folders (or two tracks.json files with the same
ground truth, ``--gt``). The ID switches and fragmentations of the two runs are matched (same
sequence, kind, class and GT id, frames within ``--tolerance``) into fixed (A only), introduced
(B only) and kept (both), with their causes where the runs were recorded (``--record``); the
metrics are compared per class and per sequence. Only the sequences both runs tracked and scored
are compared: any other (in one run only, failed or unlabelled in one) is left out, said in one
line, and a run whose metrics cover other sequences is scored again on the shared ones from its
result files (so a delta is never between different sets). Writes ``DIR/compare.json`` and
``DIR/compare.md``; with ``--record`` also ``DIR/recordings/<seq>.rrd``, each with both runs
side by side and the fixed and introduced events at their frames.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from app.common import command_line, refuse_inputs_among_outputs, remove_earlier_outputs
from app.inputs import refuse_unused_option
from app.outputs import compare_recordings, holds_a_run, outputs_of, run_recordings
from app.runs import Run, load_run, run_names, scored_sequences
from tracker.errors import InputError
from tracker.eval.compare import (
    DEFAULT_TOLERANCE,
    compare_markdown,
    compare_runs,
    left_out_note,
)
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
    # each option goes with one kind of run (the other kind's loading ignored it unsaid, and
    # compare.md's "Made by" line listed it)
    if a.is_file() and b.is_file():
        refuse_unused_option(
            "--labels", args.labels, "run folders (`mctrack kitti --out`: the KITTI labels their "
            "result files are scored against)", "tracks files are compared against --gt, by the "
            "CLEAR replay with BEV IoU",
        )  # fmt: skip
    if a.is_dir() and b.is_dir():
        refuse_unused_option(
            "--gt", args.gt, "tracks files (their ground truth)", "run folders are scored "
            "against their KITTI labels (their summary.json's, or --labels DIR)",
        )  # fmt: skip
    na, nb = run_names(a, b)
    run_a = load_run(a, labels=labels, gt=gt, name=na)
    run_b = load_run(b, labels=labels, gt=gt, name=nb)
    if run_a.kind != run_b.kind:
        raise InputError(f"{b}: a {run_b.kind} run; {a} is a {run_a.kind} run: compare like runs")
    return run_a, run_b


#: What a comparison's --record writes (in recordings/): refused as an input
COMPARE_RECORDINGS = tuple(p for p in outputs_of("compare") if p.startswith("recordings/"))


def run(args: argparse.Namespace) -> int:
    if args.tolerance < 0:
        raise InputError(f"--tolerance {args.tolerance}: must be >= 0")
    out = check_output_folder(args.out)
    if args.record:  # --out RUN_A: its own recordings/<seq>.rrd (which it reads) overwritten
        inputs = {"RUN_A": args.run_a, "RUN_B": args.run_b, "--labels": args.labels}
        refuse_inputs_among_outputs(
            out, COMPARE_RECORDINGS, {k: Path(v) if v else None for k, v in inputs.items()}
        )
        for name in ("RUN_A", "RUN_B"):  # (a run without recordings: later read as its own)
            if Path(inputs[name]).resolve() == out.resolve():
                raise InputError(
                    f"{out}: --out is {name}, a run folder: --record would write the comparison's"
                    " recordings into the run's own recordings/; give another --out"
                )
    run_a, run_b = load_pair(args)
    result = compare_result(run_a, run_b, tolerance=args.tolerance)
    tracks = record_tracks(run_a, run_b) if args.record else None
    if tracks is not None:
        _refuse_run_recordings(out, recorded_sequences(run_a, result, tracks))
    # once the inputs are accepted, in an earlier comparison's folder: its recordings of other
    # sequences or runs (or all of them, before a comparison without --record) would sit
    # beside this one's compare.json. Of recordings/, those its compare.json lists alone: a
    # user's recordings/mine.rrd stays
    if (out / "compare.json").is_file():
        earlier = compare_recordings(out)
        if holds_a_run(out):
            # (compare.json rewritten without them, they would be listed nowhere and outlive
            # the next run there; the run's own recordings stay)
            own = set(run_recordings(out))
            remove_earlier_outputs(out, [p for p in earlier if p not in own])
        else:
            remove_earlier_outputs(out, [*outputs_of("compare", []), *earlier])
    # every option that changes the result, quoted: the line repeats the comparison
    words = [args.run_a, args.run_b, "--out", args.out, "--tolerance", str(args.tolerance)]
    words += [
        *(["--labels", args.labels] if args.labels else []),
        *(["--gt", args.gt] if args.gt else []),
        *(["--record"] if args.record else []),
    ]
    command = command_line(["compare", *words])
    result["command"] = command
    if tracks is not None:  # first: a failed recording leaves no compare.json claiming it
        result["recordings"] = record(run_a, run_b, result, out, tracks)
    write_compare(result, out, command=command)
    _print(result, out)
    return 0


def compare_result(run_a: Run, run_b: Run, *, tolerance: int) -> dict[str, Any]:
    """The A/B comparison of two loaded runs (:func:`tracker.eval.compare.compare_runs`) on the
    sequences both tracked and scored (:func:`shared_sequences`)."""
    shared, left_out = shared_sequences(run_a, run_b)
    if left_out:
        run_a, run_b = _restricted(run_a, shared), _restricted(run_b, shared)
    # a class one run did not track has no events there to compare with: its events in the
    # other would all count as fixed or introduced
    classes = {r.name: set(r.summary.get("classes") or ()) for r in (run_a, run_b)}
    classes_left_out = {
        c: f"not tracked in {name}"
        for c in sorted(classes[run_a.name] ^ classes[run_b.name])
        for name in (run_a.name, run_b.name)
        if c not in classes[name]
    }
    if classes_left_out:
        run_a, run_b = (
            dataclasses.replace(
                r, events=[e for e in r.events if e["class"] not in classes_left_out]
            )
            for r in (run_a, run_b)
        )
    result = compare_runs(
        run_a.summary,
        run_b.summary,
        run_a.events,
        run_b.events,
        tolerance=tolerance,
        names=(run_a.name, run_b.name),
    )
    if classes_left_out:
        result["classes_left_out"] = classes_left_out
    if left_out:
        result["sequences_compared"] = shared
        result["sequences_left_out"] = left_out
        result["rescored"] = [r.name for r in (run_a, run_b) if r.summary.get("rescored")]
        tracked = [set(r.summary["sequences"]) - set(r.summary.get("failed") or {}) for r in
                   (run_a, run_b)]  # fmt: skip
        if isinstance(result["motion"], dict) and any(t != set(shared) for t in tracked):
            # (each run's covers all the sequences it tracked; not recomputed here)
            result["motion"] = "absent: the runs' motion metrics cover different sequences"
    return result


def shared_sequences(run_a: Run, run_b: Run) -> tuple[list[str], dict[str, str]]:
    """The sequences both runs tracked and scored (in A's order), and why each other sequence
    of either run is left out; InputError when they share none."""
    scored = {r.name: scored_sequences(r.summary) for r in (run_a, run_b)}
    shared = [s for s in scored[run_a.name] if s in scored[run_b.name]]
    left_out: dict[str, str] = {}
    for seq in dict.fromkeys([*run_a.summary["sequences"], *run_b.summary["sequences"]]):
        if seq in shared:
            continue
        why = []
        for r in (run_a, run_b):
            if seq in (r.summary.get("failed") or {}):
                why.append(f"failed in {r.name}")
            elif seq not in r.summary["sequences"]:
                why.append(f"not in {r.name}")
            elif seq not in scored[r.name]:
                why.append(f"not scored in {r.name}")
        left_out[seq] = ", ".join(why)
    if not shared:
        listed = "; ".join(f"{n}: {', '.join(s) or 'none'}" for n, s in scored.items())
        raise InputError(
            f"{run_b.path}: no sequence that both runs tracked and scored ({listed}): compare "
            "runs of the same sequences"
        )
    return shared, left_out


def _restricted(run: Run, seqs: list[str]) -> Run:
    """``run`` on ``seqs`` only: their events and per-sequence metrics, and metrics over them
    (the summary's if they are over exactly these, else scored again: ``summary["rescored"]``)."""
    summary = dict(run.summary)
    for key in ("per_sequence", "per_sequence_metrics"):
        if isinstance(summary.get(key), dict):
            summary[key] = {s: m for s, m in summary[key].items() if s in seqs}
    if not (summary.get("metrics") and set(scored_sequences(summary)) == set(seqs)):
        summary["metrics"] = _metrics_on(run, seqs, summary.get("per_sequence") or {})
        summary["rescored"] = True
    events = [e for e in run.events if e["sequence"] in seqs]
    return dataclasses.replace(run, summary=summary, events=events)


def _metrics_on(
    run: Run, seqs: list[str], per_sequence: dict[str, Any]
) -> dict[str, dict[str, Any]]:
    """A run's metrics over ``seqs``: a kitti run's by :func:`tracker.eval.kitti.evaluate_kitti`
    on its result files (as `mctrack kitti` combines its sequences), a tracks run's IDSW and
    Frag summed."""
    if run.kind != "kitti" or run.label_dir is None:
        totals: dict[str, dict[str, Any]] = {}
        for seq in seqs:
            for cls, c in (per_sequence.get(seq) or {}).items():
                t = totals.setdefault(cls, {"IDSW": 0, "Frag": 0})
                t["IDSW"] += c["IDSW"]
                t["Frag"] += c["Frag"]
        return totals
    from tracker.eval.id_switches import result_file_timesteps
    from tracker.eval.kitti import SUPPORTED_CLASSES, absent_classes, evaluate_kitti

    classes = [c for c in run.summary["classes"] if c in SUPPORTED_CLASSES]
    data = run.folder / "data"
    lengths = {  # (the run's frames are not at hand: as far as labels or results reach)
        seq: result_file_timesteps(path_in(data, seq, ".txt"), path_in(run.label_dir, seq, ".txt"))
        for seq in seqs
    }
    metrics = evaluate_kitti(
        label_dir=run.label_dir,
        result_dir=data,
        seq_lengths=lengths,
        classes=classes,
        name_refused_results=True,
    )
    absent = absent_classes(metrics)  # (no GT of the class: as `mctrack kitti` leaves them out)
    return {c: m for c, m in metrics.items() if c not in absent}


def write_compare(result: dict[str, Any], out: Path, *, command: str | None = None) -> None:
    """``out/compare.json`` and ``out/compare.md`` of a comparison."""
    write_text_atomic(out / "compare.json", [json.dumps(result, indent=1)])
    write_text_atomic(out / "compare.md", ["\n".join(compare_markdown(result, command=command))])


def record_tracks(run_a: Run, run_b: Run) -> list[dict[str, Any]]:
    """Both runs' tracks (their tracks.json), which --record draws (InputError if absent)."""
    from tracker.io.baseversion import read_baseversion

    if run_a.kind != "kitti":
        raise InputError(f"{run_a.path}: --record needs `mctrack kitti` run folders")
    tracks = []
    for r in (run_a, run_b):
        file = r.folder / "tracks.json"
        if not file.is_file():
            raise InputError(f"{file}: missing (--record draws each run's tracks from it)")
        tracks.append(read_baseversion(file))
    return tracks


def recorded_sequences(
    run_a: Run, result: Mapping[str, Any], tracks: Sequence[Mapping[str, Any]]
) -> list[str]:
    """The sequences :func:`record` writes a recording of: those compared that both runs'
    tracks (``tracks``: :func:`record_tracks`) hold."""
    compared = result.get("sequences_compared") or run_a.summary["sequences"]
    return [s for s in compared if s in tracks[0] and s in tracks[1]]


def _refuse_run_recordings(out: Path, seqs: Sequence[str]) -> None:
    """InputError when ``out`` holds a run (neither compared one: those are refused as --out
    with --record) whose summary.json lists a recording this comparison writes
    (recordings/<seq>.rrd): it would be overwritten with the comparison's and still be listed
    as the run's. Called before anything is written."""
    own = set(run_recordings(out))
    for seq in seqs:
        path = path_in(out / "recordings", seq, ".rrd")
        if path.relative_to(out).as_posix() in own:
            raise InputError(
                f"{path}: the run in {out} lists it as its own recording (its summary.json): "
                "--record would overwrite it with the comparison's; give another --out"
            )


def record(
    run_a: Run,
    run_b: Run,
    result: dict[str, Any],
    out: Path,
    tracks: Sequence[Mapping[str, Any]],
) -> dict[str, str]:
    """One side-by-side recording per sequence of both runs; {sequence: path}. ``tracks``:
    :func:`record_tracks`."""
    from viz.compare_record import record_comparison

    seqs = recorded_sequences(run_a, result, tracks)
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
    note = left_out_note(result)
    if note:
        print(note[0].upper() + note[1:])
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
