"""`mctrack nuscenes`: convert, track, write the nuScenes tracking submission, evaluate it with
the official devkit (AMOTA, AMOTP, MOTA, IDS, recall), and summarise. docs/nuscenes_waymo.md"""

from __future__ import annotations

import argparse
import gc
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app import scenes
from app.common import (
    outputs_removed_on_failure,
    peak_rss_mb,
    print_motion,
    refuse_inputs_among_outputs,
    remove_earlier_outputs,
    write_motion_metrics,
)
from app.inputs import add_mode_argument, unit_interval
from app.outputs import holds_a_run, outputs_at_stake, outputs_of, outputs_replaced_by
from app.scenes import SceneRecord
from tracker.config import TrackerConfig, TrackingMode, config_to_dict, load_config
from tracker.errors import InputError
from tracker.eval.fates import combine_fates
from tracker.events import TrackOutput
from tracker.frame import Frame
from tracker.io.fileio import (
    check_output_folder,
    compact_json,
    write_bytes_atomic,
    write_text_atomic,
)

#: Folders the devkit's evaluation makes in --out (empty: mctrack never renders its plots)
DEVKIT_FOLDERS = ("eval/plots",)


@dataclass(frozen=True, slots=True)
class NuscenesSceneJob:
    """One nuScenes scene as a task: track its frames (converted once, by the caller, from the
    shared tables), write its parts of the submission and of the tracks file."""

    config: TrackerConfig
    out: Path
    coasting_score: float | None
    record: bool
    keep: bool  # send the outputs back (the motion metrics need them)

    def process(
        self, index: int, scene: str, data: tuple[list[Frame], list[Frame] | None] | None
    ) -> SceneRecord:
        """``data``: the scene's detection frames and (for the recording) ground truth."""
        from tracker.io.nuscenes_writer import nuscenes_results
        from tracker.io.writers import tracks_scene_json

        if data is None:
            raise ValueError("NuscenesSceneJob needs the scene's frames")
        frames, gt_frames = data
        info: dict[str, Any] = {}
        result = scenes.track_or_record(frames, gt_frames, self.config, self.out, scene,
                                        record=self.record, info=info)  # fmt: skip
        outputs = result.outputs
        per_sample = nuscenes_results(
            {scene: (frames, outputs)}, coasting_score=self.coasting_score
        )
        info["boxes"] = sum(len(v) for v in per_sample.values())
        write_bytes_atomic(scenes.part_path(self.out, index, "nusc.json"), compact_json(per_sample))
        write_bytes_atomic(
            scenes.part_path(self.out, index, "json"), tracks_scene_json(scene, frames, outputs)
        )
        return SceneRecord(
            index,
            scene,
            frames=len(frames),
            tracker_seconds=result.tracker_seconds,
            info=info,
            kept=outputs if self.keep else None,
        )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataroot", required=True, help="nuScenes root (holds <version>/)")
    parser.add_argument("--version", default="v1.0-trainval", help="v1.0-trainval/-mini/-test")
    parser.add_argument("--split", default="val", help="val, mini_val, test or a custom split")
    parser.add_argument("--detections", required=True, help="detection results JSON")
    parser.add_argument("--config", default="nuscenes", help="nuscenes or a TOML path")
    add_mode_argument(parser)
    parser.add_argument(
        "--scenes",
        default=None,
        help="comma-separated scene names (default: the whole split; a subset is not evaluated, "
        "the official evaluation needs every sample of the split)",
    )
    parser.add_argument(
        "--score-min",
        type=unit_interval,
        default=0.0,
        help="drop detections scoring below this at conversion, in [0, 1], counted "
        "(default: 0: keep all)",
    )
    parser.add_argument("--no-eval", action="store_true", help="skip the official evaluation")
    parser.add_argument(
        "--motion", action="store_true", help="also the motion metrics (needs the annotations)"
    )
    parser.add_argument(
        "--record",
        action="store_true",
        help="write a Rerun debug recording per scene to OUT/recordings/<scene>.rrd "
        "(viz.record.record_scene; needs rerun-sdk)",
    )
    parser.add_argument("--out", required=True, help="output folder")
    scenes.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    check_output_folder(args.out)  # before any work
    summary = run_nuscenes(
        dataroot=Path(args.dataroot),
        version=args.version,
        split=args.split,
        detections=Path(args.detections),
        config_name=args.config,
        mode=args.mode,
        scene_names=[s.strip() for s in args.scenes.split(",") if s.strip()]
        if args.scenes
        else None,
        score_min=args.score_min,
        evaluate=not args.no_eval,
        motion=args.motion,
        record=args.record,
        out=Path(args.out),
        parallel=scenes.from_args(args),
    )
    _print_summary(summary)
    return scenes.print_failures("nuscenes", summary["failed"])


def run_nuscenes(
    *,
    dataroot: Path,
    version: str,
    split: str,
    detections: Path,
    out: Path,
    config_name: str | Path = "nuscenes",
    mode: str | None = None,
    scene_names: list[str] | None = None,
    score_min: float = 0.0,
    evaluate: bool = True,
    motion: bool = False,
    record: bool = False,
    quiet: bool = False,
    parallel: scenes.Parallelism = scenes.SEQUENTIAL,
) -> dict[str, Any]:
    """The end-to-end nuScenes job; returns (and writes) ``out/summary.json``.

    Writes ``out/results.json`` (the tracking submission, checked with the devkit's loader),
    ``out/tracks.json`` (the tracks file, for ``mctrack eval`` / ``mctrack view``), with
    ``motion`` also ``out/gt.json``, ``out/motion.md`` and the velocity PNG, and with ``record``
    one ``.rrd`` per scene in ``out/recordings/``.
    """
    from tracker.eval.nuscenes import evaluate_nuscenes, load_results_with_devkit
    from tracker.io.convert.nuscenes import convert_nuscenes, load_nuscenes
    from tracker.io.nuscenes_writer import write_nuscenes_parts

    # its files per scene are recordings/<scene>.rrd (--record): of --scenes, else of the
    # split's scenes, known once converted (checked again then)
    early = (scene_names or []) if scene_names or not record else None
    refuse_inputs_among_outputs(
        out,
        outputs_at_stake("nuscenes", out, early, record=record),
        {"--detections": detections},
        outputs_of("nuscenes", early, record=record),
    )
    config = load_config(config_name, overrides={"mode": mode} if mode else None)
    has_gt = not version.endswith("test")
    want_gt = has_gt and (motion or record)
    t0 = time.perf_counter()
    nusc = load_nuscenes(dataroot, version)
    conv = convert_nuscenes(
        dataroot,
        version=version,
        detections=detections,
        split=split,
        with_gt=want_gt,
        score_min=score_min,
        # the evaluation reads the annotations unchecked: a bad one is named before tracking
        check_gt=has_gt and evaluate and not scene_names,
        nusc=nusc,
    )
    del nusc  # several GB on v1.0-trainval; the evaluation loads its own copy
    gc.collect()  # (the devkit's NuScenes and its explorer refer to each other)
    det_scenes = conv.detections
    if scene_names:
        missing = [s for s in scene_names if s not in det_scenes]
        if missing:
            raise InputError(f"--scenes: not in split {split!r}: {missing}")
        det_scenes = {s: det_scenes[s] for s in scene_names}
    convert_secs = time.perf_counter() - t0
    written = list(det_scenes)
    if early is None:  # (a cut-short run's recording of no scene of this split: refused)
        outputs_at_stake("nuscenes", out, written, record=record)
    if holds_a_run(out):  # a refused run keeps the earlier one; a run's files of any command go
        remove_earlier_outputs(out, outputs_replaced_by("nuscenes", out, written, record=record))

    # from here on the run writes: one that fails (the devkit refuses the submission, an
    # evaluation error, Ctrl-C) removes what it wrote, so OUT never holds a results.json
    # without the summary.json that marks a complete run
    with outputs_removed_on_failure(out, outputs_of("nuscenes"), folders=DEVKIT_FOLDERS):
        coasting_score = None if config.mode is TrackingMode.OFFLINE else 0.0
        job = NuscenesSceneJob(
            config,
            out,
            coasting_score=coasting_score,
            record=record,
            keep=motion,
        )
        t1 = time.perf_counter()
        gt_of = conv.gt if record and conv.gt else {}
        inputs = {s: (f, gt_of.get(s)) for s, f in det_scenes.items()}
        records = scenes.run_scenes(
            job, list(det_scenes), inputs=inputs, parallel=parallel, quiet=quiet
        )
        wall_secs = time.perf_counter() - t1
        ok = [r for r in records if r.error is None]
        out.mkdir(parents=True, exist_ok=True)
        results_path = out / "results.json"
        write_nuscenes_parts(
            results_path, [scenes.part_path(out, r.index, "nusc.json") for r in ok], meta=conv.meta
        )
        scenes.write_tracks(out, ok)
        load_results_with_devkit(results_path)  # the devkit's own format check
        n_boxes = sum(r.info["boxes"] for r in ok)
        tracker_secs = sum(r.tracker_seconds for r in ok)
        total_frames = sum(len(f) for f in det_scenes.values())
        recordings = [r.info["recording"] for r in ok if "recording" in r.info]

        summary: dict[str, Any] = {
            "command": "nuscenes",  # (marks its folder a run's: app.outputs.holds_a_run)
            "dataset": "nuscenes",
            "version": version,
            "split": split,
            "detections": str(detections),
            "scenes": list(det_scenes),
            "frames": total_frames,
            "boxes_written": n_boxes,
            "results": str(results_path),
            "mode": config.mode.value,
            "tracker_seconds": round(tracker_secs, 4),
            "tracker_fps": round(total_frames / tracker_secs, 1) if tracker_secs > 0 else None,
            "convert_seconds": round(convert_secs, 3),
            "peak_rss_mb": peak_rss_mb(),
            "skipped_detections": dict(sorted(conv.skipped_detections.items())),
            # (dropped too: names of no nuScenes class, likely misspelt; below --score-min)
            "unknown_detections": dict(sorted(conv.unknown_detections.items())),
            "below_score_min": conv.below_score_min,
            **scenes.summary_fields(records, parallel, wall_secs),
            "detection_fates": combine_fates([r.info["fates"] for r in records if r.error is None]),
            "config": config_to_dict(config),
        }
        if recordings:
            summary["recordings"] = recordings
        if not evaluate:
            summary["evaluation"] = "skipped (--no-eval)"
        elif not has_gt:
            summary["evaluation"] = "skipped: the test split has no public annotations (submit it)"
        elif scene_names:
            summary["evaluation"] = "skipped: --scenes selects part of the split"
        elif summary["failed"]:
            # (the benchmark scores every scene of the split, or nothing)
            summary["evaluation"] = f"not scored: the run failed on {', '.join(summary['failed'])}"
        else:
            metrics = evaluate_nuscenes(
                results_path,
                dataroot=dataroot,
                version=version,
                split=split,
                out_dir=out / "eval",
                boxes=n_boxes,
            )
            # (a run that wrote no box is a result, not an error: the devkit cannot score it)
            summary["metrics" if isinstance(metrics, dict) else "evaluation"] = metrics
        if motion:
            outputs = {r.scene: r.kept for r in ok}
            det_ok = {s: det_scenes[s] for s in outputs}
            summary["motion"] = _motion(det_ok, conv.gt, outputs, config.categories, out)
        write_text_atomic(out / "summary.json", [json.dumps(summary, indent=2, allow_nan=False)])
    return summary


def _motion(
    det_scenes: dict[str, list[Frame]],
    gt: dict[str, list[Frame]] | None,
    outputs: dict[str, list[TrackOutput]],
    classes: tuple[str, ...],
    out: Path,
) -> dict[str, Any] | str:
    from tracker.io.baseversion import write_baseversion

    if gt is None:
        return "skipped: no annotations (test split)"
    gt = {s: gt[s] for s in det_scenes}
    write_baseversion(out / "gt.json", gt)
    return write_motion_metrics(det_scenes, gt, outputs, classes, out)


def _print_summary(summary: dict[str, Any]) -> None:
    failed, names = summary.get("failed") or {}, summary["scenes"]
    head = scenes.tracked_head(failed, names, "scene")
    if head:
        print(
            f"{head}, {summary['frames']} frames, tracker "
            f"{summary['tracker_seconds']:.2f} s ({summary['tracker_fps'] or '-'} frames/s), "
            f"{summary['boxes_written']} boxes -> {summary['results']}"
        )
    if failed:  # plainly: the run is not a result
        note = summary.get("evaluation", "")
        note = "nothing was scored" if note.startswith("not scored") else note
        print(scenes.failed_run_line(failed, names, "scene", note))
    metrics = summary.get("metrics")
    if isinstance(metrics, dict):
        cols = ["amota", "amotp", "recall", "mota", "ids"]
        print(f"{'class':<12}" + "".join(f"{c.upper():>9}" for c in cols))
        rows = [("overall", metrics["overall"]), *metrics["per_class"].items()]
        for name, m in rows:
            cells = "".join(f"{'n/a':>9}" if m.get(c) is None else f"{m[c]:>9.3f}" for c in cols)
            print(f"{name:<12}{cells}")
    elif "evaluation" in summary and not failed:  # (a failed run's is said above)
        print(summary["evaluation"])
    print_motion(summary.get("motion"))  # (as `mctrack kitti`: the table; motion.md beside)
