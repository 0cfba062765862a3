"""`mctrack kitti`: convert, track, write KITTI results, evaluate with TrackEval, summarise."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app import scenes
from app.common import (
    NO_PROFILE,
    log_self_profile,
    outputs_removed_on_failure,
    peak_rss_mb,
    print_metrics,
    print_motion,
    profile_argument,
    refuse_inputs_among_outputs,
    remove_earlier_outputs,
    score_source,
    self_calibrated_note,
    warn_undetected_classes,
    write_motion_metrics,
)
from app.inputs import (
    IMAGE_DETECTOR_HELP,
    NO_POSES_NOTE,
    add_detector_argument,
    add_kitti_root_argument,
    add_mode_argument,
    check_image_detector,
    check_kitti_root,
    class_list,
    default_kitti_root,
    sequence_list,
)
from app.outputs import holds_a_run, outputs_at_stake, outputs_of, outputs_replaced_by
from app.scenes import SceneRecord
from tracker.calibration import (
    ScoreProfile,
    calibrate_frames,
    profile_toml,
    raw_outside_profile,
    warn_classes_without_map,
    warn_scores_outside,
)
from tracker.config import (
    ImageBoxes,
    TrackerConfig,
    config_for_mode,
    config_to_dict,
    load_config,
)
from tracker.errors import InputError
from tracker.eval.fates import FateCounter, combine_fates
from tracker.eval.kitti import (
    SUPPORTED_CLASSES,
    SequenceEvaluation,
    absent_class_notes,
    check_kitti_labels,
    combine_sequences,
    evaluate_kitti_sequence,
)
from tracker.events import TrackOutput
from tracker.frame import Frame
from tracker.io.convert.kitti import VALIDATION_SEQS, _normalise_seq
from tracker.io.fileio import check_output_folder, path_in, write_bytes_atomic, write_text_atomic
from tracker.io.writers import tracks_scene_json, write_kitti_sequence
from tracker.pipeline import run_scene

#: The per-sequence metrics kept in summary.json "per_sequence_metrics".
PER_SEQUENCE_METRICS = ("HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW", "Frag", "TP", "FN")

LOG = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_kitti_root_argument(parser)
    add_detector_argument(parser)
    parser.add_argument(
        "--image-detector",
        default=None,
        metavar="NAME",
        help=f"{IMAGE_DETECTOR_HELP}, and a matched track writes it (image_boxes = auto unless "
        "the config says detection)",
    )
    parser.add_argument(
        "--seqs",
        type=sequence_list,
        default=",".join(VALIDATION_SEQS),
        help="comma-separated sequences (default: the 11 validation sequences)",
    )
    parser.add_argument(
        "--labels",
        default=None,
        metavar="DIR",
        help="label_02 folder for evaluation (default: <root>/training/label_02)",
    )
    parser.add_argument(
        "--classes",
        type=class_list,
        default="car,pedestrian,cyclist",
        help="comma-separated classes to track and evaluate",
    )
    parser.add_argument(
        "--config", default="kitti", help="built-in config name (kitti, ...) or a TOML file"
    )
    add_mode_argument(parser)
    parser.add_argument(
        "--poses",
        default="orbslam3",
        help="ego poses: orbslam3 (<root>/training/pose_orbslam3), none (no ego motion: "
        "velocities relative to the ego vehicle) or a folder of <seq>.txt",
    )
    parser.add_argument(
        "--profile",
        default=None,
        help="score calibration profile (TOML from `mctrack calibrate`, or a shipped profile's "
        "name); default: the one shipped "
        "for --detector, else 'self'. 'self': fitted without labels on the run's own detections "
        "(self_profile.toml in --out); 'none': sigmoid(raw), or the raw score where every score is "
        "already in [0, 1] (configs with scores = 'as_given' "
        "use the scores as converted)",
    )
    parser.add_argument("--no-eval", action="store_true", help="skip the evaluation")
    parser.add_argument(
        "--motion",
        action="store_true",
        help="also compute the motion metrics (summary.json 'motion', motion.md, PNG)",
    )
    parser.add_argument(
        "--record",
        action="store_true",
        help="also write a Rerun recording per sequence to OUT/recordings/<seq>.rrd",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    scenes.add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    check_output_folder(args.out)  # before any work: a bad --out fails in a second, not at the end
    root = args.kitti_root or default_kitti_root()
    seqs = args.seqs
    if args.labels and not args.no_eval and not Path(args.labels).is_dir():
        raise InputError(f"{args.labels}: --labels folder not found (or pass --no-eval)")
    poses = None if args.poses == "none" else args.poses
    check_kitti_root(root, seqs=seqs, poses=poses, detector=args.detector)
    check_image_detector(root, args.image_detector, classes=args.classes, seqs=seqs)
    out = Path(args.out)
    profile = profile_argument(args.profile)
    # an input among the outputs would be deleted with an earlier run's, or by a failed run's
    # clean-up (--labels OUT/data: label files are <seq>.txt; --profile OUT/self_profile.toml)
    inputs = {
        "--labels": Path(args.labels) if args.labels else None,
        "--profile": profile if isinstance(profile, Path) else None,
        "--poses": Path(poses) if poses not in (None, "orbslam3") else None,
    }
    written = [_normalise_seq(s) for s in seqs]  # (data/<seq>.txt of its sequences alone)
    # (recordings/<seq>.rrd only with --record: without it a user's there stays)
    at_stake = outputs_at_stake("kitti", out, written, record=args.record)
    refuse_inputs_among_outputs(
        out, at_stake, inputs, outputs_of("kitti", written, record=args.record)
    )
    if poses is None:
        print(NO_POSES_NOTE, file=sys.stderr)
    summary = run_kitti(
        kitti_root=root,
        seqs=seqs,
        classes=args.classes,
        config_name=args.config,
        mode=args.mode,
        detector=args.detector,
        image_detector=args.image_detector,
        profile=profile,
        labels=Path(args.labels) if args.labels else None,
        poses=poses,
        evaluate=not args.no_eval,
        motion=args.motion,
        record=out / "recordings" if args.record else None,
        out=out,
        parallel=scenes.from_args(args),
    )
    _print_summary(summary)
    sys.stdout.flush()  # (the scenes' errors follow the summary, as it says)
    return scenes.print_failures("kitti", summary["failed"])


@dataclass(frozen=True, slots=True)
class KittiSceneJob:
    """One KITTI sequence as a task: convert it (by path), track it, write its files."""

    kitti_root: Path
    detector: str
    poses: str | None
    classes: tuple[str, ...]
    config: TrackerConfig
    out: Path
    label_dir: Path
    with_gt: bool
    keep: bool  # send the frames and outputs back (the motion metrics need them)
    record: Path | None
    calibrate: bool = False  # recompute the scores from the raw ones (score_source)
    profile: ScoreProfile | None = None
    evaluate: bool = False  # evaluate the sequence (TrackEval) in the task, when it has labels
    image_detector: str | None = None  # 2D boxes fused into the detections (convert_kitti)
    eval_classes: tuple[str, ...] = ()

    def process(self, index: int, scene: str, frames: list[Frame] | None) -> SceneRecord:
        from tracker.io.convert.kitti import SkippedRows, convert_kitti

        t0 = time.perf_counter()
        skipped = SkippedRows()
        detections, gt = convert_kitti(
            self.kitti_root,
            seqs=[scene],
            detector=self.detector,
            poses=self.poses,
            classes=self.classes,
            with_gt=self.with_gt,
            image_detector=self.image_detector,
            skipped=skipped,
            label_dir=self.label_dir,
        )
        convert_secs = time.perf_counter() - t0
        ((seq, frames),) = detections.items()  # the sequence's normalised name ("14" -> "0014")
        outside = None
        if self.calibrate:
            frames = calibrate_frames(frames, self.profile)
            if self.profile is not None:
                outside = raw_outside_profile(self.profile, frames)
        gt_frames = (gt or {}).get(seq)
        result_file = path_in(self.out / "data", seq, ".txt")
        write_secs = 0.0

        def write(outputs: list[TrackOutput]) -> None:
            nonlocal write_secs
            t1 = time.perf_counter()
            write_kitti_sequence(
                result_file,
                outputs,
                frames,
                **self.config.kitti_writer_options(),
            )
            write_bytes_atomic(
                scenes.part_path(self.out, index, "json"), tracks_scene_json(seq, frames, outputs)
            )
            write_secs += time.perf_counter() - t1

        label_file = path_in(self.label_dir, seq, ".txt")
        info: dict[str, Any] = {
            "convert_seconds": convert_secs,
            "skipped": {
                "unknown": dict(skipped.unknown),
                "not_tracked": dict(skipped.not_tracked),
                "duplicates": dict(skipped.duplicates),
            },
            "outside_profile": outside,
        }
        evaluation: SequenceEvaluation | None = None
        if self.record is not None:
            # tracked once, with the recording's observers; the recording's evaluation of the
            # result file is the run's too (combined by the caller)
            from app.kitti_record import record_sequence

            recorded, more = record_sequence(
                frames,
                gt_frames,
                self.config,
                self.record,
                self.kitti_root,
                self.label_dir,
                result_file,
                on_tracked=write,
            )
            outputs, tracker_secs = recorded.outputs, recorded.tracker_seconds
            fates, removed = recorded.fates, len(recorded.removed_offline)
            evaluation = recorded.evaluation
            info.update(more)
        else:
            counter = FateCounter(rv_gate_consumes=self.config.rv_reference)
            result = run_scene(frames, self.config, observer=counter)
            outputs, tracker_secs = result.outputs, result.tracker_seconds
            fates, removed = counter.summary(), len(result.removed_offline)
            write(outputs)
        if self.evaluate and label_file.is_file():
            if evaluation is None or evaluation.num_timesteps != len(frames):
                t1 = time.perf_counter()
                evaluation = evaluate_kitti_sequence(
                    label_file=label_file,
                    result_file=result_file,
                    num_timesteps=len(frames),
                    classes=self.eval_classes,
                    label_checked=True,  # (by run_kitti, before any sequence was tracked)
                )
                info["evaluate_seconds"] = time.perf_counter() - t1
            info["evaluation"] = evaluation
        info.update(write_seconds=write_secs, fates=fates, offline_removed_tracks=removed)
        return SceneRecord(
            index,
            seq,
            frames=len(frames),
            tracker_seconds=tracker_secs,
            info=info,
            kept=(frames, gt_frames, outputs) if self.keep else None,
        )


def run_kitti(
    *,
    kitti_root: Path,
    seqs: list[str],
    classes: list[str],
    config_name: str | Path = "kitti",
    mode: str | None = None,
    detector: str = "pointrcnn",
    image_detector: str | None = None,
    profile: Path | str | None = None,
    labels: Path | None = None,
    poses: str | None = "orbslam3",
    evaluate: bool = True,
    motion: bool = False,
    record: Path | None = None,
    out: Path,
    config_overrides: dict[str, Any] | None = None,
    quiet: bool = False,
    parallel: scenes.Parallelism = scenes.SEQUENTIAL,
) -> dict[str, Any]:
    """The end-to-end KITTI job; returns (and writes) ``out/summary.json``.

    Each sequence is one task (:mod:`app.scenes`: sequential, ``parallel.workers`` processes or
    Ray): it converts, tracks and writes ``out/data/<seq>.txt``; ``out/tracks.json`` is
    assembled from the tasks' parts in sequence order and the evaluation runs once at the end,
    when every sequence succeeded. A sequence whose input is bad fails alone
    (``summary["failed"]``).

    With ``motion`` the labels are converted too and the motion metrics
    (:func:`tracker.eval.motion_eval.evaluate_motion`) go to ``summary["motion"]``,
    ``out/motion.md`` and ``out/motion_velocity.png``.
    """
    if evaluate and not any(c in SUPPORTED_CLASSES for c in classes):
        # (was a run whose metrics table was its header alone, exit 0)
        raise InputError(
            f"--classes {','.join(classes)}: the KITTI protocol scores only "
            f"{', '.join(SUPPORTED_CLASSES)}; name one of them, or pass --no-eval to track "
            f"{', '.join(classes)} unscored"
        )
    overrides = dict(config_overrides or {})
    overrides["categories"] = classes
    config_name = config_for_mode(config_name, mode)  # (load_config applies the same rule)
    if mode:
        overrides["mode"] = mode
    config = load_config(config_name, overrides=overrides)
    if image_detector is not None and config.image_boxes is ImageBoxes.PROJECTION:
        # the image detector's boxes are what the run is for: written where a track has one
        config = load_config(config_name, overrides={**overrides, "image_boxes": "auto"})
    label_dir = labels or kitti_root / "training" / "label_02"
    if evaluate or motion:  # a bad label file stops the run here, not once every sequence is
        # tracked; the motion metrics follow every labelled object, the static ones the scored
        names = [_normalise_seq(s) for s in seqs]  # as the converter names them
        lengths = {seq: _pose_count(kitti_root, seq, poses) for seq in names}
        sources = {seq: f"the pose lines of {_pose_file(kitti_root, seq, poses)}" for seq in names}
        scored = [c for c in classes if c in SUPPORTED_CLASSES]
        check_kitti_labels(label_dir, lengths, sources, all_rows=motion, classes=scored)
    unscored = [c for c in classes if c not in SUPPORTED_CLASSES]
    if evaluate and unscored:
        LOG.warning(
            "%s: tracked, not scored (the KITTI protocol scores %s)",
            ", ".join(unscored),
            ", ".join(SUPPORTED_CLASSES),
        )
    calibrate, found, calibration = score_source(config, detector, profile)
    self_profile = None
    if calibrate and found is None and profile != NO_PROFILE:
        found = self_profile = self_calibrate(kitti_root, seqs, detector, poses, classes)
        calibration = (
            self_calibrated_note(profile, detector, self_profile) + ", see self_profile.toml"
        )
    # once the config, the profile and the labels are read: a refused run keeps the earlier one.
    # Only in a folder a run has written (data/*.txt alone could be anyone's); a sequence the
    # new run leaves out does not keep its old results, nor any command's file of the old run
    if holds_a_run(out):  # (of data/*.txt, the earlier run's files and this run's alone)
        written = [_normalise_seq(s) for s in seqs]
        replaced = outputs_replaced_by("kitti", out, written, record=record is not None)
        remove_earlier_outputs(out, replaced)
    # from here on the run writes: one that fails after the tracking (the motion metrics or
    # the recordings refuse, Ctrl-C) removes what it wrote, so OUT never holds data/*.txt and
    # tracks.json without the summary.json that marks a complete run
    with outputs_removed_on_failure(out, outputs_of("kitti")):
        job = KittiSceneJob(
            kitti_root=kitti_root,
            detector=detector,
            poses=poses,
            classes=tuple(classes),
            config=config,
            out=out,
            label_dir=label_dir,
            with_gt=motion or record is not None,
            keep=motion,
            record=record,
            calibrate=calibrate,
            profile=found,
            evaluate=evaluate,
            eval_classes=tuple(c for c in classes if c in SUPPORTED_CLASSES),
            image_detector=image_detector,
        )
        t0 = time.perf_counter()
        records = scenes.run_scenes(job, seqs, parallel=parallel, quiet=quiet)
        wall_secs = time.perf_counter() - t0
        ok = [r for r in records if r.error is None]
        scenes.write_tracks(out, ok)

        skipped: dict[str, Counter[str]] = {
            "unknown": Counter(), "not_tracked": Counter(), "duplicates": Counter()
        }  # fmt: skip
        for r in ok:
            for kind, counts in r.info["skipped"].items():
                skipped[kind].update(counts)
        if found is not None:  # scores beyond the profile's knots, over the whole run
            outside: dict[str, list[int]] = {}
            for r in ok:
                for name, (n_out, n) in (r.info["outside_profile"] or {}).items():
                    total = outside.setdefault(name, [0, 0])
                    total[0], total[1] = total[0] + n_out, total[1] + n
            warn_scores_outside(found, detector, outside)
        fed = Counter()  # detections the tracker was given, per class
        for r in ok:
            for per_class in r.info["fates"]["per_fate_and_class"].values():
                fed.update(per_class)
        if found is not None and self_profile is None:  # (the self-calibration logs its classes)
            warn_classes_without_map(found, detector, fed, str(profile or f"{detector} (shipped)"))
        if ok:
            warn_undetected_classes(detector, [c for c in classes if not fed[c]])
        born = Counter()
        for r in ok:
            born.update(r.info["fates"]["per_fate_and_class"].get("born", {}))
        for name in (c for c in classes if fed[c] and not born[c]):
            LOG.warning(
                "not one of the %d %s detections scored enough to start a track (%s): check the "
                "scores' calibration (--profile)",
                fed[name],
                name,
                calibration,
            )
        total_frames = sum(r.frames for r in ok)
        tracker_secs = sum(r.tracker_seconds for r in ok)
        summary: dict[str, Any] = {
            "command": "kitti",  # (marks its folder a run's: app.outputs.holds_a_run)
            "dataset": "kitti",
            "detector": detector,
            "image_detector": image_detector,
            "image_boxes": config.image_boxes.value,
            "config_name": str(config_name),
            # absolute: mctrack report / compare read the labels from here, from any directory
            "kitti_root": str(Path(kitti_root).absolute()),
            "labels": str(Path(label_dir).absolute()),
            "sequences": [r.scene for r in records],
            # (None: none; a folder of the user's, absolute: bench/motion_table.py reads them)
            "poses": poses if poses in (None, "orbslam3") else str(Path(poses).absolute()),
            "mode": config.mode.value,
            "classes": classes,
            "frames": total_frames,
            "tracker_seconds": round(tracker_secs, 4),
            "tracker_fps": round(total_frames / tracker_secs, 1) if tracker_secs > 0 else None,
            "tracker_timing": "tracker with the recording's observers (--record tracks once)"
            if record is not None
            else "tracker alone",
            "score_calibration": calibration,
            "convert_seconds": round(sum(r.info["convert_seconds"] for r in ok), 3),
            "write_seconds": round(sum(r.info["write_seconds"] for r in ok), 3),
            "evaluate_seconds": round(sum(r.info.get("evaluate_seconds", 0.0) for r in ok), 3),
            "peak_rss_mb": peak_rss_mb(),
            **scenes.summary_fields(records, parallel, wall_secs),
            "detection_fates": combine_fates([r.info["fates"] for r in ok], skipped["unknown"]),
            "skipped_at_load": {
                "unknown_classes": dict(sorted(skipped["unknown"].items())),
                "classes_not_tracked": dict(sorted(skipped["not_tracked"].items())),
                "duplicate_rows": dict(sorted(skipped["duplicates"].items())),
            },
            "offline_removed_tracks": sum(r.info["offline_removed_tracks"] for r in ok),
            "config": config_to_dict(config),
        }
        if evaluate:
            scored = [r for r in ok if "evaluation" in r.info]
            missing = [r.scene for r in ok if "evaluation" not in r.info]
            if summary["failed"]:
                # TrackEval scores a tracker with every sequence or refuses; scored without
                # the failed ones, the metrics would be another run's (other sequences)
                tracked = [r.scene for r in ok]
                summary["evaluation"] = (
                    f"not scored: the run failed on {', '.join(summary['failed'])}"
                    + (
                        f"; metrics over {', '.join(tracked)} alone would not be the run's "
                        f"(--seqs {','.join(tracked)} scores those)"
                        if tracked
                        else ""
                    )
                )
            elif not scored:
                summary["evaluation"] = f"skipped: no labels for {missing} in {label_dir}"
                LOG.warning("not evaluated: no labels for %s in %s", missing, label_dir)
            else:
                if missing:  # the labelled ones are scored; the run says which are not
                    summary["evaluation"] = (
                        f"scored on {[r.scene for r in scored]}; no labels for {missing} in "
                        f"{label_dir}"
                    )
                    LOG.warning("scored without %s: no labels for them in %s", missing, label_dir)
                summary["evaluated_sequences"] = [r.scene for r in scored]
                # each task evaluated its own sequence (TrackEval, once); combined here as
                # TrackEval's Evaluator combines them
                per_seq: dict[str, dict[str, dict[str, float]]] = {}
                metrics = combine_sequences(
                    [r.info["evaluation"] for r in scored], job.eval_classes, per_sequence=per_seq
                )
                absent = absent_class_notes(metrics)
                summary["metrics"] = {c: m for c, m in metrics.items() if c not in absent}
                if absent:
                    summary["metrics_absent"] = absent
                summary["evaluator"] = (
                    "trackeval 1.3.0, KITTI 2D box protocol (HOTA, CLEAR, Identity)"
                )
                summary["per_sequence"] = {
                    seq: {c: {k: m[k] for k in ("IDSW", "Frag")} for c, m in per.items()}
                    for seq, per in per_seq.items()
                }
                summary["per_sequence_metrics"] = {  # for mctrack compare / report
                    seq: {c: {k: m[k] for k in PER_SEQUENCE_METRICS} for c, m in per.items()}
                    for seq, per in per_seq.items()
                }
        if record is not None:
            from app.kitti_record import recording_summary

            summary.update(recording_summary(ok, config, record))
        if motion:
            detections = {r.scene: r.kept[0] for r in ok}
            gt = {r.scene: r.kept[1] for r in ok if r.kept[1] is not None}
            outputs = {r.scene: r.kept[2] for r in ok}
            summary["motion"] = _motion(detections, gt or None, outputs, classes, out)
        out.mkdir(parents=True, exist_ok=True)
        if self_profile is not None:
            write_text_atomic(out / "self_profile.toml", [profile_toml(self_profile)])
        write_text_atomic(out / "summary.json", [json.dumps(summary, indent=2)])
    return summary


def _pose_file(kitti_root: Path, seq: str, poses: str | None) -> Path | None:
    from tracker.io.convert.kitti import pose_folder

    folder = pose_folder(kitti_root / "training", poses)
    return None if folder is None else path_in(folder, seq, ".txt")


def _pose_count(kitti_root: Path, seq: str, poses: str | None) -> int | None:
    """A sequence's length as the converter takes it with poses: its poses, parsed as the
    converter parses them (None without poses, or no readable pose file: the sequence's task
    reports that). A malformed pose file is an InputError naming it: counted unparsed, a
    truncated one judged the sequence's labels, which were then blamed for its error."""
    from tracker.io.convert.kitti import read_kitti_poses

    path = _pose_file(kitti_root, seq, poses)
    try:
        return None if path is None else len(read_kitti_poses(path))
    except (OSError, UnicodeDecodeError):
        return None


def self_calibrate(
    kitti_root: Path, seqs: list[str], detector: str, poses: str | None, classes: list[str]
) -> ScoreProfile:
    """A label-free profile fitted on the run's own detections
    (:func:`tracker.eval.calibrate.fit_self_profile`). A sequence that cannot be read is left
    out here; its own task reports the error."""
    from tracker.eval.calibrate import fit_self_profile
    from tracker.io.convert.kitti import convert_kitti

    frames: dict[str, list[Frame]] = {}
    converter = logging.getLogger("tracker.io.convert.kitti")
    level = converter.level
    converter.setLevel(logging.ERROR)  # each scene's task reports the same files' skips
    try:
        for seq in seqs:
            try:
                detections, _ = convert_kitti(
                    kitti_root, seqs=[seq], detector=detector, poses=poses, classes=classes,
                    with_gt=False,
                )  # fmt: skip
            except InputError:
                continue
            frames.update(detections)
    finally:
        converter.setLevel(level)
    profile = fit_self_profile(detector, frames, classes)
    log_self_profile(profile, classes)
    return profile


def _motion(
    detections: dict[str, Any],
    gt: dict[str, Any] | None,
    outputs: dict[str, list[TrackOutput]],
    classes: list[str],
    out: Path,
) -> dict[str, Any] | str:
    """Motion metrics of the run, and ``out/motion.md`` with the velocity-curve PNG."""
    missing = sorted(s for s in detections if gt is None or s not in gt)
    if gt is None or missing:
        return f"skipped: no labels for {missing}"
    return write_motion_metrics(detections, gt, outputs, classes, out)


def _print_summary(summary: dict[str, Any]) -> None:
    failed = summary.get("failed") or {}
    tracked = [s for s in summary["sequences"] if s not in failed]
    if tracked:  # (with none, a speed of 0 frames would say nothing)
        of = f"tracked {', '.join(tracked)} only: " if failed else ""
        print(
            f"{of}frames {summary['frames']}  tracker {summary['tracker_seconds']:.2f} s  "
            f"{summary['tracker_fps'] or '-'} frames/s  peak RSS {summary['peak_rss_mb']} MB"
        )
    if failed:  # plainly: the run is not a result, and why nothing was scored
        note = "not evaluated (--no-eval)"
        if "evaluation" in summary:
            note = "nothing was scored" + (
                f": metrics over {', '.join(tracked)} alone would not be the run's (--seqs "
                f"{','.join(tracked)} scores those)"
                if tracked
                else ""
            )
        print(scenes.failed_run_line(failed, summary["sequences"], "sequence", note))
    for kind, counts in summary.get("skipped_at_load", {}).items():
        if counts:
            print(f"detection rows skipped at load, {kind.replace('_', ' ')}: {counts}")
    metrics = summary.get("metrics")
    if isinstance(metrics, dict):
        print_metrics(metrics, summary.get("metrics_absent", {}))
    if "evaluation" in summary and not failed:  # (a failed run's is said above)
        print(summary["evaluation"])
    per_seq = summary.get("per_sequence")
    if per_seq:
        classes = list(next(iter(per_seq.values())))
        print(f"{'IDSW/Frag':<10}" + "".join(f"{c:>14}" for c in classes))
        for seq, per in per_seq.items():
            cells = [f"{per[c]['IDSW']}/{per[c]['Frag']}" for c in classes]
            print(f"{seq:<10}" + "".join(f"{x:>14}" for x in cells))
    for seq, path in summary.get("recordings", {}).items():
        print(f"recording {seq}: {path}")
    if "causes_markdown" in summary:
        print(f"causes of ID switches and fragmentations: {summary['causes_markdown']}")
    print_motion(summary.get("motion"))
