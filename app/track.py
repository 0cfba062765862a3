"""`mctrack track INPUT.json`: run the tracker on any BaseVersion file (the official project's
files included) and write the tracks file (BaseVersion + filtered velocity/acceleration)."""

from __future__ import annotations

import argparse
import json
import logging
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app import scenes
from app.common import (
    NO_PROFILE,
    SELF_PROFILE,
    log_self_profile,
    outputs_removed_on_failure,
    refuse_inputs_among_outputs,
    remove_earlier_outputs,
)
from app.inputs import add_mode_argument
from app.outputs import holds_a_run, outputs_at_stake, outputs_of, outputs_replaced_by
from app.scenes import SceneRecord
from tracker.calibration import (
    ScoreProfile,
    calibrate_frames,
    looks_like_probability,
    profile_by_path_or_name,
    profile_toml,
    raw_scored_per_class,
    warn_classes_without_map,
)
from tracker.categories import CATEGORIES, category_index
from tracker.config import (
    ScoreSource,
    TrackerConfig,
    config_for_mode,
    config_to_dict,
    load_config,
)
from tracker.errors import InputError
from tracker.eval.fates import FateCounter, combine_fates, format_fates
from tracker.frame import Frame
from tracker.io.baseversion import LoadReport, read_baseversion
from tracker.io.fileio import (
    check_output_folder,
    output_manifest,
    path_in,
    refuse_case_collisions,
    write_bytes_atomic,
    write_text_atomic,
)
from tracker.io.writers import tracks_scene_json, write_kitti_sequence
from tracker.pipeline import run_scene

LOG = logging.getLogger("mctrack.track")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="BaseVersion detections JSON")
    parser.add_argument("--config", default="kitti", help="kitti, nuscenes, waymo or a TOML path")
    add_mode_argument(parser)
    add_profile_argument(parser, "OUT/self_profile.toml")
    parser.add_argument("--scenes", default=None, help="comma-separated scene names (default all)")
    parser.add_argument(
        "--frames",
        default=None,
        help="frame index range A:B within each scene (0-based, B excluded; A or B may be "
        "left out; a B past a scene's end stops at its end)",
    )
    parser.add_argument(
        "--kitti-results",
        action="store_true",
        help="also write KITTI label_02-style files to OUT/data/<scene>.txt",
    )
    parser.add_argument("--out", required=True, help="output folder")
    scenes.add_arguments(parser)


def add_profile_argument(parser: argparse.ArgumentParser, self_saved: str | None) -> None:
    """``--profile``, as :func:`calibrate_scenes` applies it (``track`` and ``view``: one
    option, so the two track a file alike); ``self_saved``: where ``self``'s profile goes."""
    saved = f" ({self_saved})" if self_saved else " (not saved: `mctrack track` writes it)"
    parser.add_argument(
        "--profile",
        default=None,
        help="score calibration profile (a TOML file from `mctrack calibrate`, or a shipped "
        "profile's name: pointrcnn, second_iou, virconv) applied to each box's "
        "detection_score_raw, which every box of a tracked class must have; 'self': fitted "
        f"without labels on the file's own detections{saved}; 'none': detection_score as "
        "given (the default, which warns where the config's thresholds expect calibrated "
        "scores)",
    )


def parse_frame_range(text: str | None) -> slice:
    """``--frames A:B`` as a slice of each scene's frames. Negative indices (Python's "from the
    end") and an empty range are refused: they selected nothing, and the run then failed on
    something else or wrote an empty result."""
    if not text:
        return slice(None)
    try:
        start, _, stop = text.partition(":")
        window = slice(int(start) if start else None, int(stop) if stop else None)
    except ValueError:
        raise InputError(f"--frames: expected A:B, got {text!r}") from None
    if (window.start or 0) < 0 or (window.stop is not None and window.stop < 0):
        raise InputError(f"--frames {text}: frame indices start at 0 (A:B, 0 <= A < B)")
    if window.stop is not None and (window.start or 0) >= window.stop:
        raise InputError(f"--frames {text}: selects no frame (A:B needs A < B)")
    return window


def select_scenes(
    scenes: dict[str, list[Frame]],
    names: str | None,
    frames: slice,
    source: str | None = None,
) -> dict[str, list[Frame]]:
    """The ``--scenes`` named (all without), each cut to ``frames``. With ``source`` (the
    input's path), a range that leaves no frame of any scene is an error naming a span; scenes
    it leaves empty beside others are a warning."""
    if names:
        wanted = [s.strip() for s in names.split(",") if s.strip()]
        missing = [s for s in wanted if s not in scenes]
        if missing:
            raise InputError(f"--scenes: not in the input: {missing}")
        scenes = {s: scenes[s] for s in wanted}
    selected = {s: f[frames] for s, f in scenes.items()}
    empty = [s for s, f in selected.items() if not f]
    if source is None or not empty or frames == slice(None):
        return selected
    window = f"--frames {frames.start or 0}:{'' if frames.stop is None else frames.stop}"
    spans = ", ".join(f"{s!r} 0:{len(scenes[s])}" for s in empty[:4]) + (
        " ..." if len(empty) > 4 else ""
    )
    if len(empty) == len(selected):
        raise InputError(f"{source}: {window} selects no frame of any scene (frames: {spans})")
    LOG.warning("%s: %s selects no frame of %d scene(s): %s", source, window, len(empty), spans)
    return selected


def require_frames(
    scenes: dict[str, list[Frame]], source: str, verb: str, names: str | None = None
) -> None:
    """InputError naming ``source`` when no scene (of the ``--scenes`` ``names``) has a frame:
    the run would otherwise "succeed" on nothing, without a word (``verb``: "track", ...)."""
    if any(scenes.values()):
        return
    if not scenes:
        raise InputError(f"{source}: no scene to {verb} (the file holds none)")
    which = f"--scenes {names}" if names else f"{len(scenes)} scene(s)"
    raise InputError(f"{source}: no frames to {verb} ({which}, all empty)")


@dataclass(frozen=True, slots=True)
class TrackSceneJob:
    """One scene of a BaseVersion file as a task: track it (its frames are given), write its
    part of the tracks file and, when asked, its KITTI result file."""

    config: TrackerConfig
    out: Path
    kitti_results: bool

    def process(self, index: int, scene: str, frames: list[Frame] | None) -> SceneRecord:
        if frames is None:
            raise ValueError("TrackSceneJob needs the scene's frames")
        fates = FateCounter(rv_gate_consumes=self.config.rv_reference)
        result = run_scene(frames, self.config, observer=fates)
        write_bytes_atomic(
            scenes.part_path(self.out, index, "json"),
            tracks_scene_json(scene, frames, result.outputs),
        )
        if self.kitti_results:
            # the scene name comes from the input: escaped, it cannot lead outside OUT/data
            write_kitti_sequence(
                path_in(self.out / "data", scene, ".txt"),
                result.outputs,
                frames,
                **self.config.kitti_writer_options(),
            )
        ids = {int(t) for o in result.outputs for t in o.boxes.track_id}
        return SceneRecord(
            index,
            scene,
            frames=len(frames),
            tracker_seconds=result.tracker_seconds,
            info={
                "tracks": len(ids),
                "fates": fates.summary(),
                "offline_removed": [(r.reason, r.detections) for r in result.removed_offline],
            },
        )


def check_camera_models(path: str, scenes: dict[str, list[Frame]], camera: str) -> None:
    """KITTI result files need each frame's camera model: refuse before tracking, not after."""
    for scene, frames in scenes.items():
        for frame in frames:
            if frame.camera_index(camera) < 0:
                raise InputError(
                    f"{path}: scene {scene!r}, frame_id {frame.frame_id}: --kitti-results needs "
                    f"a {camera} camera model (transform_matrix.cameras_transform_matrix)"
                )


def check_raw_scores(
    scenes: dict[str, list[Frame]], categories: list[str] | tuple[str, ...], source: str
) -> None:
    """InputError naming the first box of a tracked class without a raw score (absent or NaN)
    when others have one: a profile recalibrates only the boxes with one, so the rest would
    keep their score as given, on another scale, mixed silently with the calibrated ones."""
    tracked = [category_index(c) for c in categories]
    first: tuple[str, int, str] | None = None
    lacking = boxes = 0
    for scene, frames in scenes.items():
        for frame in frames:
            cat = frame.boxes.category
            of_tracked = np.isin(cat, tracked)
            without = of_tracked & ~np.isfinite(frame.boxes.score_raw)
            boxes += int(of_tracked.sum())
            lacking += int(without.sum())
            if first is None and without.any():
                first = (scene, frame.frame_id, CATEGORIES[int(cat[np.argmax(without)])])
    if first is not None:
        scene, frame_id, name = first
        raise InputError(
            f"{source}: scene {scene!r}, frame_id {frame_id}: a {name} box has no "
            f"detection_score_raw (absent or NaN; {lacking} of {boxes} boxes of the tracked "
            "classes): --profile calibrates raw scores only, and would mix calibrated scores "
            "with given ones; give every box its raw score, or run without --profile"
        )


def calibrate_scenes(
    scenes: dict[str, list[Frame]], config: TrackerConfig, profile: str | None, source: str
) -> tuple[dict[str, list[Frame]], ScoreProfile | None]:
    """Scores recomputed by ``profile`` from the raw scores; without one, as given (with a
    warning when the config's thresholds expect calibrated scores). With ``self`` the profile
    is fitted on the file's own detections (:func:`tracker.eval.calibrate.fit_self_profile`)
    and returned, to be written beside the tracks."""
    if profile in (None, NO_PROFILE):  # (none: the user's choice, so no warning)
        if profile is None and config.scores is ScoreSource.PROFILE:
            LOG.warning(
                "no --profile: detection_score is used as given; the %s config's thresholds "
                "expect calibrated probabilities (see `mctrack calibrate`, or --profile self)",
                config.source,
            )
        return scenes, None
    if not any(np.isfinite(f.boxes.score_raw).any() for fr in scenes.values() for f in fr):
        raise InputError(f"{source}: --profile maps detection_score_raw, but no box has one")
    check_raw_scores(scenes, config.categories, source)
    # a class the profile has no map for falls back alike in every scene of the file
    is_probability = looks_like_probability(
        np.concatenate([f.boxes.score_raw for fr in scenes.values() for f in fr])
    )
    name = Path(source).name.removesuffix(".gz").removesuffix(".json") or "detections"
    if profile != SELF_PROFILE:
        loaded = profile_by_path_or_name(profile)
        fitted = None
        counts = raw_scored_per_class([f for fr in scenes.values() for f in fr])
        tracked = {c: n for c, n in counts.items() if c in config.categories}
        warn_classes_without_map(loaded, name, tracked, str(profile))
    else:
        from tracker.eval.calibrate import fit_self_profile

        boxes = [f.boxes.category for fr in scenes.values() for f in fr]
        classes = [CATEGORIES[int(c)] for c in np.unique(np.concatenate(boxes))]
        loaded = fitted = fit_self_profile(name, scenes, classes)
        log_self_profile(fitted, classes)
    calibrated = {
        s: calibrate_frames(f, loaded, is_probability=is_probability) for s, f in scenes.items()
    }
    return calibrated, fitted


def run(args: argparse.Namespace) -> int:
    out = check_output_folder(args.out)  # before any work: exists as a file, not writable
    overrides = {"mode": args.mode} if args.mode else None
    config = load_config(args.config, overrides=overrides)
    window = parse_frame_range(args.frames)
    report = LoadReport()
    scene_frames = read_baseversion(
        args.input, fallback_frame_rate_hz=config.frame_rate_hz, report=report
    )
    scene_frames = select_scenes(scene_frames, args.scenes, window, source=args.input)
    require_frames(scene_frames, args.input, "track", args.scenes)  # else an empty tracks.json
    if args.kitti_results:  # (a file per scene: data/<scene>.txt)
        refuse_case_collisions(scene_frames, args.input, suffix=".txt")
    # an earlier run's outputs go once the inputs are read: an input among them, or among the
    # files this run writes (data/<scene>.txt of its scenes alone), would be lost
    profile = None if args.profile in (None, SELF_PROFILE, NO_PROFILE) else Path(args.profile)
    written = list(scene_frames) if args.kitti_results else []
    refuse_inputs_among_outputs(
        out,
        outputs_at_stake("track", out, written),
        {"INPUT": Path(args.input), "--profile": profile},
        outputs_of("track", written),
    )
    empty = [s for s, frames in scene_frames.items() if not frames]
    # (kept in tracks.json, as scenes without tracks: said, not silent; with --frames,
    # select_scenes has already warned of them)
    if empty and window == slice(None):
        more = " ..." if len(empty) > 5 else ""
        print(f"{len(empty)} scene(s) without frames, written without tracks: "
              f"{', '.join(empty[:5])}{more}")  # fmt: skip
    scene_frames, self_profile = calibrate_scenes(scene_frames, config, args.profile, args.input)
    if args.kitti_results:
        check_camera_models(args.input, scene_frames, "CAM_FRONT")
    # the inputs are accepted (a refused run keeps the earlier run's outputs): the earlier run's
    # go, summary.json with them (written last: its absence marks a run cut short), and what
    # any command wrote beside them (a kitti run's recordings, an eval). Only in a folder a
    # run has written (data/*.txt alone could be anyone's)
    if holds_a_run(out):  # (of data/*.txt, the earlier run's files and this run's alone)
        remove_earlier_outputs(out, outputs_replaced_by("track", out, written))
    # from here on the run writes: one stopped (Ctrl-C, an error) removes what it wrote, so
    # OUT never holds data/*.txt or scene parts without the summary.json that marks a run
    with outputs_removed_on_failure(out, outputs_of("track")):
        summary_path = out / "summary.json"
        job = TrackSceneJob(config, out, args.kitti_results)
        parallel = scenes.from_args(args)
        records = scenes.run_scenes(job, list(scene_frames), inputs=scene_frames, parallel=parallel)
        ok = [r for r in records if r.error is None]
        scenes.write_tracks(out, ok)
        frames = sum(r.frames for r in ok)
        secs = sum(r.tracker_seconds for r in ok)
        fate_summary = combine_fates([r.info["fates"] for r in ok], report.skipped_categories)
        removed = [x for r in ok for x in r.info["offline_removed"]]
        written = [out / "tracks.json"]
        if self_profile is not None:
            write_text_atomic(out / "self_profile.toml", [profile_toml(self_profile)])
            written.append(out / "self_profile.toml")
        if args.kitti_results:
            written += [path_in(out / "data", r.scene, ".txt") for r in ok]
        failed = {r.scene: r.error for r in records if r.error}
        summary = {
            "command": "track",  # (marks its folder a run's: app.outputs.holds_a_run)
            "input": str(args.input),
            "config_name": str(config_for_mode(args.config, config.mode.value)),  # (that ran)
            # every setting, as `mctrack kitti` records them: `mctrack eval` of these tracks
            # reproduces the run from them (a config file named relative to the folder it ran
            # in, edited or gone since, would not)
            "config": config_to_dict(config),
            "mode": config.mode.value,
            "scenes": len(ok),
            "frames": frames,
            "tracks": sum(r.info["tracks"] for r in ok),
            "detection_fates": fate_summary,
            "offline_removed": {
                "tracks": len(removed),
                "detections": sum(n for _, n in removed),
                "per_reason": dict(sorted(Counter(reason for reason, _ in removed).items())),
            },
            "failed_scenes": failed,
            "outputs": output_manifest(out, written),
            "complete": not failed,
        }
        write_text_atomic(summary_path, [json.dumps(summary, indent=2, allow_nan=False)])
    print(
        f"{len(ok)} scenes, {frames} frames, {summary['tracks']} tracks, "
        f"{frames / secs if secs else 0:.0f} frames/s -> {out / 'tracks.json'}"
    )
    print(format_fates(fate_summary))
    if removed:
        print(
            f"offline post-processing removed {len(removed)} tracks "
            f"({summary['offline_removed']['detections']} detections)"
        )
    if report.boxes_skipped:
        print(
            f"skipped {report.boxes_skipped} boxes of unknown categories: "
            f"{dict(report.skipped_categories)}"
        )
    return scenes.print_failures("track", {r.scene: r.error for r in records if r.error})
