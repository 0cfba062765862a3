"""`mctrack eval TRACKS --gt GT`: evaluate a tracks file: static KITTI metrics (HOTA, CLEAR,
Identity) when label files are given, motion metrics (VAE, VNE, VAIE, VIR, VSE, VDE) with
``--motion``. Writes ``OUT/eval.json`` and ``OUT/eval.md`` (and the velocity-curve PNG)."""

from __future__ import annotations

import argparse
import json
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from tracker.baseversion import read_baseversion
from tracker.errors import InputError
from tracker.events import TrackOutput
from tracker.fileio import write_text_atomic
from tracker.frame import Frame

MOTION_PLOT = "motion_velocity.png"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("tracks", help="tracks file written by `mctrack track` / `mctrack kitti`")
    parser.add_argument("--gt", required=True, help="ground-truth BaseVersion file (track_id set)")
    parser.add_argument(
        "--detections",
        default=None,
        help="the tracker's input BaseVersion file (needed for the detection, difference and "
        "curve-fit velocity estimators)",
    )
    parser.add_argument("--classes", default="car,pedestrian", help="comma-separated classes")
    parser.add_argument(
        "--labels",
        default=None,
        help="KITTI label_02 folder: static metrics (TrackEval, KITTI 2D-box protocol)",
    )
    parser.add_argument("--motion", action="store_true", help="motion metrics")
    parser.add_argument("--out", default=None, help="output folder (default: the tracks folder)")


def run(args: argparse.Namespace) -> int:
    from tracker.writers import read_tracks_file

    classes = [c.strip() for c in args.classes.split(",") if c.strip()]
    out = Path(args.out) if args.out else Path(args.tracks).parent
    track_frames, outputs = read_tracks_file(args.tracks)
    gt = read_baseversion(args.gt)
    dets = read_baseversion(args.detections) if args.detections else None
    result = evaluate_tracks(
        track_frames,
        outputs,
        gt,
        dets,
        classes=classes,
        labels=Path(args.labels) if args.labels else None,
        motion=args.motion,
        out=out,
    )
    print(f"wrote {out / 'eval.json'} and {out / 'eval.md'}")
    if isinstance(result.get("static"), str):
        print(result["static"])
    return 0


def evaluate_tracks(
    track_frames: Mapping[str, Sequence[Frame]],
    outputs: Mapping[str, Sequence[TrackOutput]],
    gt: Mapping[str, Sequence[Frame]],
    dets: Mapping[str, Sequence[Frame]] | None,
    *,
    classes: Sequence[str],
    labels: Path | None,
    motion: bool,
    out: Path,
) -> dict[str, Any]:
    """Static and/or motion metrics of tracker output; writes ``out/eval.json`` and
    ``out/eval.md`` and returns the JSON content."""
    from tracker.motion_eval import evaluate_motion, motion_markdown

    result: dict[str, Any] = {"tracks_scenes": sorted(outputs), "classes": list(classes)}
    md = ["# Evaluation", ""]
    if labels is not None:
        result["static"] = _static_metrics(track_frames, outputs, gt, classes, labels)
    else:
        result["static"] = "skipped: static metrics need --labels (KITTI label_02 folder)"
    md += _static_markdown(result["static"])
    if motion:
        if any(len(o) for frames in outputs.values() for o in frames) and all(
            (o.det_row < 0).all() for frames in outputs.values() for o in frames
        ):
            raise InputError(
                "the tracks file has no det_row (written by an older version?): re-run "
                "`mctrack track` or `mctrack kitti` to evaluate motion"
            )
        result["motion"] = evaluate_motion(
            dets, gt, outputs, classes=classes, plot_path=out / MOTION_PLOT
        )
        md += [
            motion_markdown(result["motion"], heading_level=2),
            f"![velocity]({MOTION_PLOT})",
            "",
        ]
    out.mkdir(parents=True, exist_ok=True)
    (out / "eval.json").write_text(json.dumps(result, indent=2, allow_nan=False))
    write_text_atomic(out / "eval.md", ["\n".join(md) + "\n"])
    return result


def _static_metrics(
    track_frames: Mapping[str, Sequence[Frame]],
    outputs: Mapping[str, Sequence[TrackOutput]],
    gt: Mapping[str, Sequence[Frame]],
    classes: Sequence[str],
    labels: Path,
) -> dict[str, Any] | str:
    from tracker.kitti_eval import SUPPORTED_CLASSES, evaluate_kitti
    from tracker.writers import write_kitti_sequence

    missing = [s for s in outputs if not (labels / f"{s}.txt").is_file()]
    if missing:
        return f"skipped: no labels for {missing} in {labels}"
    static_classes = [c for c in classes if c in SUPPORTED_CLASSES]
    if not static_classes:
        return f"skipped: none of {list(classes)} is a KITTI class {SUPPORTED_CLASSES}"
    lengths = {
        s: 1
        + max(
            [f.frame_id for f in track_frames[s]] + [f.frame_id for f in gt.get(s, ())],
            default=-1,
        )
        for s in outputs
    }
    with tempfile.TemporaryDirectory(prefix="mctrack-eval-") as tmp:
        for scene, scene_outputs in outputs.items():
            write_kitti_sequence(Path(tmp) / f"{scene}.txt", scene_outputs, track_frames[scene])
        return evaluate_kitti(
            label_dir=labels, result_dir=Path(tmp), seq_lengths=lengths, classes=static_classes
        )


def _static_markdown(static: dict[str, Any] | str) -> list[str]:
    if isinstance(static, str):
        return ["## Static metrics", "", static, ""]
    cols = ["HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW", "FP", "FN", "Frag"]
    lines = [
        "## Static metrics (TrackEval, KITTI 2D-box protocol)",
        "",
        "| class | " + " | ".join(cols) + " |",
        "|---|" + "---:|" * len(cols),
    ]
    lines += [f"| {c} | " + " | ".join(str(m[k]) for k in cols) + " |" for c, m in static.items()]
    return [*lines, ""]
