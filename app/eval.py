"""`mctrack eval TRACKS --gt GT`: evaluate a tracks file: static KITTI metrics (HOTA, CLEAR,
Identity) when label files are given, motion metrics (VAE, VNE, VAIE, VIR, VSE, VDE) with
``--motion``. Writes ``OUT/eval.json`` and ``OUT/eval.md`` (and the velocity-curve PNG).

``--dataset nuscenes``: the official nuScenes tracking metrics (devkit ``TrackingEval``, AMOTA,
AMOTP, MOTA, IDS, recall) of a tracks file (written as ``OUT/eval_results.json`` first) or
of a tracking submission ``results.json`` directly; ``--motion`` with ``--gt`` adds the motion
metrics of a tracks file."""

from __future__ import annotations

import argparse
import copy
import gc
import json
import logging
import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from app.common import outputs_removed_on_failure, print_metrics, print_motion
from app.inputs import class_list
from app.outputs import holds_a_run, outputs_of
from tracker.categories import CATEGORIES
from tracker.config import (
    BUILTIN,
    ImageBoxes,
    TrackerConfig,
    config_from_dict,
    load_config,
)
from tracker.errors import InputError
from tracker.events import TrackOutput
from tracker.frame import Frame
from tracker.io.baseversion import read_baseversion
from tracker.io.fileio import (
    check_output_folder,
    path_in,
    refuse_case_collisions,
    work_folder,
    write_text_atomic,
)

LOG = logging.getLogger(__name__)
#: The tracking submission of a tracks file, written in OUT and evaluated (not results.json: OUT
#: is by default the run's folder, and a run's results.json carries its detections' meta)
EVAL_SUBMISSION = "eval_results.json"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "tracks",
        help="tracks file written by `mctrack track` / `mctrack kitti` / `mctrack nuscenes` "
        "(with --dataset nuscenes also a tracking submission results.json)",
    )
    parser.add_argument(
        "--dataset",
        choices=["kitti", "nuscenes"],
        default="kitti",
        help="kitti: TrackEval KITTI protocol + motion metrics; nuscenes: the devkit's "
        "TrackingEval (needs the nuscenes extra, docs/nuscenes_waymo.md)",
    )
    parser.add_argument(
        "--gt",
        default=None,
        help="ground-truth BaseVersion file (track_id set); required for --dataset kitti",
    )
    parser.add_argument("--dataroot", default=None, help="nuScenes root (--dataset nuscenes)")
    parser.add_argument("--version", default="v1.0-trainval", help="nuScenes table version")
    parser.add_argument("--split", default="val", help="nuScenes split evaluated")
    parser.add_argument(
        "--detections",
        default=None,
        help="the tracker's input BaseVersion file (needed for the detection velocity "
        "estimator, for the difference and curve-fit ones where the tracks file does not carry "
        "them (offline runs, older files), and for the detections' own 2D boxes that the "
        "config's image_boxes writes)",
    )
    parser.add_argument(
        "--classes",
        type=class_list,
        default=None,
        help="comma-separated classes to evaluate (default: KITTI's scored classes "
        "car,pedestrian,cyclist, as `mctrack kitti`; with --dataset nuscenes, the nuscenes "
        "config's classes)",
    )
    parser.add_argument(
        "--labels",
        default=None,
        help="KITTI label_02 folder: static metrics (TrackEval, KITTI 2D-box protocol) of the "
        "sequences with a label file, on the frames the tracks file covers (a `mctrack track "
        "--frames A:B` file: frames A..B-1 alone); eval.json names what was scored",
    )
    parser.add_argument("--motion", action="store_true", help="motion metrics")
    parser.add_argument(
        "--config",
        default=None,
        help="the config the tracks were made with: it shapes the 2D boxes written for the KITTI "
        "2D-box protocol as the tracking run wrote them (image_width_scale per class; with "
        "--detections, image_boxes and the offline own-box smoothing) (default: the run's, "
        "from the summary.json beside a run's tracks.json; else kitti)",
    )
    parser.add_argument("--out", default=None, help="output folder (default: the tracks folder)")


def run(args: argparse.Namespace) -> int:
    from tracker.io.writers import read_tracks_file

    if args.dataset == "nuscenes":
        return _run_nuscenes(args)
    if args.gt is None:
        raise InputError("--gt is required for --dataset kitti")
    if args.labels is None and not args.motion:  # (it wrote an eval.json of nothing, exit 0)
        raise InputError(
            "nothing to evaluate: add --labels DIR (KITTI label_02: the static metrics) and/or "
            "--motion (the motion metrics)"
        )
    if args.labels is not None and not Path(args.labels).is_dir():
        raise InputError(f"{args.labels}: --labels folder not found (KITTI label_02)")
    from tracker.eval.kitti import SUPPORTED_CLASSES

    classes = args.classes or list(SUPPORTED_CLASSES)
    writer: dict[str, Any] | None = None
    config_name = config_note = None
    if args.labels is not None:  # (the config shapes the static metrics' 2D boxes alone)
        config, config_name, config_note = eval_config(Path(args.tracks), args.config)
        writer = config.kitti_writer_options()
        if args.detections is None and writer["image_boxes"] is not ImageBoxes.PROJECTION:
            # the tracks file keeps the tracked boxes, not the detections' own 2D boxes
            print(
                f"mctrack eval: {config_name}: image_boxes = {config.image_boxes.value!r} needs "
                "the detections' 2D boxes (--detections); without them the KITTI files are "
                "written with the tracked boxes' projections (the same for a LiDAR detector, "
                "whose 2D boxes are projections)",
                file=sys.stderr,
            )
    elif args.config is not None:
        load_config(args.config)  # (unused without --labels, but a bad one is said)
    out = Path(args.out) if args.out else Path(args.tracks).parent
    track_frames, outputs = read_tracks_file(args.tracks)
    if args.labels is not None:
        # a file per scene: its labels (--labels/<scene>.txt) and the KITTI file written for
        # TrackEval; on a case-insensitive filesystem scene a would be scored against A's
        # labels, its file over A's. Refused on every filesystem, as by the other commands.
        refuse_case_collisions(outputs, args.tracks, suffix=".txt")
    gt = read_baseversion(args.gt)
    if not _any_track_id(gt):  # (its objects' ids are what the motion metrics follow)
        raise InputError(
            f"{args.gt}: no box has a track_id: not ground truth (a detections file?); --gt "
            "takes the ground truth (`mctrack convert kitti` writes gt.json)"
        )
    if is_ground_truth(track_frames, gt):
        LOG.warning(
            "%s: the tracks file looks like the ground truth itself (--gt %s: the same boxes and"
            " track ids): it is scored as a (near-)perfect tracker",
            args.tracks,
            args.gt,
        )
    check_unique_track_ids(outputs, args.tracks)
    if args.motion:  # (the static metrics read the labels, checked as TrackEval checks them)
        check_unique_track_ids(gt, args.gt, "object")
    if not _any_track_id(outputs):
        raise InputError(
            f"{args.tracks}: no box has a track_id (a detections file? eval scores a tracker's"
            " output: `mctrack track` writes one)"
        )
    dets = read_baseversion(args.detections) if args.detections else None
    if dets is not None:
        check_detections_match(dets, outputs, args.detections)
    check_output_folder(out)  # before the evaluation: a bad --out fails now, not at the end
    if config_note is not None:
        print(config_note)
    result = evaluate_tracks(
        track_frames,
        outputs,
        gt,
        dets,
        classes=classes,
        labels=Path(args.labels) if args.labels else None,
        motion=args.motion,
        out=out,
        writer=writer,
        tracks_name=args.tracks,
        config_name=config_name,
    )
    # the metrics as `mctrack kitti` prints them
    if isinstance(result.get("static"), dict):
        print_metrics(result["static"], result.get("static_absent", {}))
    elif isinstance(result.get("static"), str):
        print(f"static: {result['static']}")
    if "motion" in result:
        print_motion(result["motion"])
    print(f"wrote {out / 'eval.json'} and {out / 'eval.md'}")
    return 0


def _any_track_id(frames: Mapping[str, Sequence[TrackOutput | Frame]]) -> bool:
    """Whether a box of ``frames`` has a track id (or there is no box): a detections file's
    boxes have none (-1)."""
    ids = [f.boxes.track_id for scene in frames.values() for f in scene]
    return not any(len(i) for i in ids) or any((i >= 0).any() for i in ids)


def eval_config(tracks: Path, given: str | None) -> tuple[TrackerConfig, str, str]:
    """The config whose KITTI writer options eval uses, its name, and the line saying which.
    ``given`` (--config) when set, with a warning where the run beside ``tracks`` was made with
    another (:func:`run_config`); else the run's, so the default scores what the run scored;
    else (not a run's tracks file) ``kitti``."""
    if given is None:
        found = run_config(tracks)
        if found is None:
            note = f"config kitti (the default: {tracks} is no run's tracks.json; --config C)"
            return load_config("kitti"), "kitti", note
        config, name, file = found
        return config, name, f"config {name} (the run's: {file})"
    config = load_config(given)
    try:
        found = run_config(tracks)
    except InputError:  # (the run's config unreadable or gone: nothing to compare with)
        found = None
    if found is not None and not _writes_alike(found[0], config):
        print(
            f"mctrack eval: --config {given} is not the config the tracks were made with "
            f"({found[1]}, {found[2]}): the KITTI 2D boxes are written as {given} writes them, "
            "not as the run did (leave --config out to use the run's)",
            file=sys.stderr,
        )
    return config, given, f"config {given}"


def _writes_alike(a: TrackerConfig, b: TrackerConfig) -> bool:
    """Whether two configs write a tracks file's KITTI 2D boxes alike (all eval takes from one:
    a run's other settings, its classes or gates, change nothing here)."""
    wa, wb = a.kitti_writer_options(), b.kitti_writer_options()
    return wa.keys() == wb.keys() and all(np.array_equal(wa[k], wb[k]) for k in wa)


def run_config(tracks: Path) -> tuple[TrackerConfig, str, Path] | None:
    """The config the run whose tracks.json ``tracks`` is was made with, its name and the run's
    summary.json; None when ``tracks`` is not a run's (no run's summary.json beside it,
    :func:`app.outputs.holds_a_run`). The config the summary recorded ("config": every setting,
    written by `mctrack kitti`, `nuscenes` and `waymo`), else the one it names (`mctrack track`:
    a built-in, or a file, refused when gone), with the run's mode."""
    file = tracks.parent / "summary.json"
    if tracks.name != "tracks.json" or not holds_a_run(tracks.parent) or not file.is_file():
        return None
    try:
        summary = json.loads(file.read_text(encoding="utf-8"))
    except (OSError, ValueError):  # (holds_a_run read it a moment ago)
        return None
    recorded = summary.get("config")
    name = summary.get("config_name")
    if isinstance(recorded, dict):
        source = f"{file}: field 'config'"
        config = config_from_dict(copy.deepcopy(recorded), source=source)
        return config, name if isinstance(name, str) else "the run's recorded config", file
    name = recorded if isinstance(recorded, str) else name
    if not isinstance(name, str):
        raise InputError(
            f"{file}: no field 'config' naming the config the run was made with: pass --config"
        )
    if name not in BUILTIN and not Path(name).is_file():
        raise InputError(
            f"{file}: field 'config': the run's config file {name} is gone (not found): pass "
            "--config, the config the tracks were made with"
        )
    mode = summary.get("mode")
    overrides = {"mode": mode} if mode in ("online", "offline") else None
    return load_config(name, overrides=overrides), name, file


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
    writer: Mapping[str, Any] | None = None,
    tracks_name: str = "the tracks file",
    config_name: str | None = None,
) -> dict[str, Any]:
    """Static and/or motion metrics of tracker output; writes ``out/eval.json`` and
    ``out/eval.md`` and returns the JSON content. ``writer``: the keywords of
    :func:`tracker.io.writers.write_kitti_sequence` (``TrackerConfig.kitti_writer_options()``;
    None: projections, full width); a mode other than projection takes its 2D boxes from
    ``dets`` (:func:`check_detections_match` them first), and without them writes projections.
    ``tracks_name``: what an error calls the tracks (TrackEval scores temporary KITTI files of
    them: an error names the tracks and the scene instead). ``config_name``: the config the
    writer's options are of (eval.json "config", with the static metrics)."""
    from tracker.eval.kitti import absent_class_notes
    from tracker.eval.motion_eval import MOTION_PLOT, evaluate_motion, motion_report_lines

    result: dict[str, Any] = {"tracks_scenes": sorted(outputs), "classes": list(classes)}
    md = ["# Evaluation", ""]
    if labels is not None:
        writer = dict(writer or {})
        if dets is None:  # a tracks file holds no detection 2D boxes
            writer["image_boxes"] = ImageBoxes.PROJECTION
        mode = ImageBoxes(writer.get("image_boxes", ImageBoxes.PROJECTION))
        frames = track_frames if mode is ImageBoxes.PROJECTION else dets
        static = _static_metrics(frames, outputs, gt, classes, labels, writer, result, tracks_name)
        if isinstance(static, dict):  # a class without ground truth is absent, as in kitti
            absent = absent_class_notes(static)
            static = {c: m for c, m in static.items() if c not in absent}
            if absent:
                result["static_absent"] = absent
        result["static"] = static
        if config_name is not None:
            result["config"] = config_name
    else:
        result["static"] = "skipped: static metrics need --labels (KITTI label_02 folder)"
    md += _static_markdown(result["static"], result.get("static_absent", {}))
    if "evaluation" in result:
        md += [result["evaluation"], ""]
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
        md += motion_report_lines(result["motion"])
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "eval.json", [json.dumps(result, indent=2, allow_nan=False)])
    write_text_atomic(out / "eval.md", ["\n".join(md) + "\n"])
    return result


def _static_metrics(
    frames: Mapping[str, Sequence[Frame]],  # the writer's: tracks' or detections' (own 2D boxes)
    outputs: Mapping[str, Sequence[TrackOutput]],
    gt: Mapping[str, Sequence[Frame]],
    classes: Sequence[str],
    labels: Path,
    writer: Mapping[str, Any],
    notes: dict[str, Any],
    tracks_name: str,
) -> dict[str, Any] | str:
    """The KITTI metrics of the labelled scenes, on the frames the tracks file covers. What was
    scored goes into ``notes`` (eval.json): ``evaluated_sequences``, and when some scenes or
    frames were left out, ``evaluated_frames`` and an ``evaluation`` line (also logged)."""
    from tracker.eval.kitti import SUPPORTED_CLASSES, check_label_file, evaluate_kitti
    from tracker.io.writers import write_kitti_sequence

    static_classes = [c for c in classes if c in SUPPORTED_CLASSES]
    if not static_classes:
        return f"skipped: none of {list(classes)} is a KITTI class {SUPPORTED_CLASSES}"
    missing = [s for s in outputs if not path_in(labels, s, ".txt").is_file()]
    empty = [s for s in outputs if s not in missing and not outputs[s]]
    scored = [s for s in outputs if s not in missing and s not in empty]
    if not scored:
        return f"skipped: no labels for {missing} in {labels}" if missing else "skipped: no frames"
    lengths: dict[str, int] = {}
    first_frames: dict[str, int] = {}
    windows: dict[str, list[int]] = {}
    for s in scored:  # every label file is read before the first is scored
        ids = [o.frame_id for o in outputs[s]]
        gt_ids = [f.frame_id for f in gt.get(s, ())]
        length = 1 + max(ids + gt_ids)
        # the ground truth says how long the sequence is: labels beyond it are another's
        labelled = check_label_file(
            path_in(labels, s, ".txt"), length if gt_ids else None, "the frames of --gt",
            classes=static_classes,
        )  # fmt: skip
        lo, hi = min(ids), max(ids)
        if lo > 0 or hi + 1 < max(length, labelled):  # (mctrack track --frames): score those
            first_frames[s], lengths[s], windows[s] = lo, hi - lo + 1, [lo, hi]
        else:
            lengths[s] = length
    notes["evaluated_sequences"] = scored
    said = []
    if missing or empty:
        why = [f"no labels for {missing} in {labels}"] if missing else []
        why += [f"no frames of {empty} in the tracks file"] if empty else []
        said.append(f"scored on {scored}; {'; '.join(why)}")
    if windows:  # scoring every labelled frame would count the frames never tracked as misses
        notes["evaluated_frames"] = windows
        spans = ", ".join(f"{s} {lo}-{hi}" for s, (lo, hi) in windows.items())
        said.append(f"scored on the frames the tracks file covers alone ({spans})")
    if said:
        notes["evaluation"] = "; ".join(said)
        LOG.warning("%s", notes["evaluation"])
    kept, others = _of_classes({s: outputs[s] for s in scored}, static_classes)
    if others:  # (a KITTI result file holds KITTI types alone: TrackEval refuses any other)
        LOG.warning(
            "%s: boxes of classes the KITTI metrics do not score, left out of them: %s",
            tracks_name,
            ", ".join(f"{n} {c}" for c, n in sorted(others.items())),
        )
        notes["left_out_of_static"] = dict(sorted(others.items()))
    with work_folder("eval") as tmp:
        for scene in scored:
            write_kitti_sequence(path_in(tmp, scene, ".txt"), kept[scene], frames[scene], **writer)
        return evaluate_kitti(
            label_dir=labels,
            result_dir=tmp,
            seq_lengths=lengths,
            classes=static_classes,
            first_frames=first_frames,
            # checked above, as strictly: with --gt against the same length, without it the
            # labels end within length unless the frames are windowed (then no length check)
            labels_checked=True,
            # a refused file is a temporary one: named by the tracks and scene it was written from
            name_refused_results={s: f"{tracks_name}: scene {s}" for s in lengths},
        )


def _of_classes(
    outputs: Mapping[str, Sequence[TrackOutput]], classes: Sequence[str]
) -> tuple[dict[str, list[TrackOutput]], dict[str, int]]:
    """The outputs with the boxes of ``classes`` alone, and the number of boxes left out per
    class that is not a KITTI scored class (a scored class not asked for is left out quietly)."""
    from tracker.eval.kitti import SUPPORTED_CLASSES

    wanted = np.isin(np.array(CATEGORIES), list(classes))
    kitti = np.isin(np.array(CATEGORIES), list(SUPPORTED_CLASSES))
    others: Counter[str] = Counter()
    kept: dict[str, list[TrackOutput]] = {}
    for scene, scene_outputs in outputs.items():
        kept[scene] = []
        for out in scene_outputs:
            keep = wanted[out.boxes.category]
            if keep.all():
                kept[scene].append(out)
                continue
            others.update(
                CATEGORIES[c] for c in out.boxes.category[~keep & ~kitti[out.boxes.category]]
            )
            kept[scene].append(out.select(keep))
    return kept, dict(others)


def is_ground_truth(
    track_frames: Mapping[str, Sequence[Frame]], gt: Mapping[str, Sequence[Frame]]
) -> bool:
    """Whether the tracks are the ground truth's boxes and ids (the --gt file given as the
    tracks file, or a copy): eval would score it without a word as a perfect tracker."""
    if not track_frames or track_frames.keys() != gt.keys():
        return False
    for scene, frames in track_frames.items():
        if len(frames) != len(gt[scene]):
            return False
        for a, b in zip(frames, gt[scene], strict=True):
            if a.frame_id != b.frame_id or not all(
                np.array_equal(getattr(a.boxes, k), getattr(b.boxes, k))
                for k in ("track_id", "category", "xyz", "lwh", "yaw")
            ):
                return False
    return True


def check_unique_track_ids(
    outputs: Mapping[str, Sequence[TrackOutput | Frame]], path: str, what: str = "track"
) -> None:
    """Raise :class:`InputError` naming the tracks (or ground-truth) file, scene, frame and id
    where one track id is on two boxes of a frame (the tracker numbers every class from one
    counter; ids below 0 are no tracks): TrackEval refuses it once scoring has begun, the motion
    metrics fail on it. ``what``: what an id is in the error (a track, an object)."""
    for scene, scene_outputs in outputs.items():
        for out in scene_outputs:
            ids = out.boxes.track_id[out.boxes.track_id >= 0]
            unique, counts = np.unique(ids, return_counts=True)
            if (counts > 1).any():
                k = int(np.argmax(counts > 1))
                raise InputError(
                    f"{path}: scene {scene} frame {out.frame_id}: track id {unique[k]} is on"
                    f" {counts[k]} boxes: one {what} twice in one frame"
                )


def check_detections_match(
    dets: Mapping[str, Sequence[Frame]], outputs: Mapping[str, Sequence[TrackOutput]], path: str
) -> None:
    """Raise :class:`InputError` unless ``dets`` holds every frame of the tracks and every
    matched detection row the tracks name (it is the file the tracks were made from)."""
    for scene, scene_outputs in outputs.items():
        sizes = {f.frame_id: len(f.boxes) for f in dets.get(scene, ())}
        for out in scene_outputs:
            rows = int(out.det_row.max(initial=-1))
            if out.frame_id not in sizes or rows >= sizes[out.frame_id]:
                raise InputError(
                    f"{path}: scene {scene} frame {out.frame_id}: not the detections the tracks"
                    f" were made from (the tracks match detection row {rows})"
                )


def _static_markdown(static: dict[str, Any] | str, absent: Mapping[str, str]) -> list[str]:
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
    lines += [f"| {c} | absent: {why} |" + " |" * (len(cols) - 1) for c, why in absent.items()]
    return [*lines, ""]


# ---------------------------------------------------------------------------------------------
# nuScenes


def _is_submission(path: Path) -> bool:
    """True for a nuScenes results file (``{"results": ..., "meta": ...}``), from its start."""
    import gzip
    import re

    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rb") as fh:
        head = fh.read(4096)
    return re.match(rb'\s*\{\s*"(meta|results)"', head) is not None


def _run_nuscenes(args: argparse.Namespace) -> int:
    if not args.dataroot:
        raise InputError("--dataset nuscenes needs --dataroot (the nuScenes tables)")
    if args.motion and args.gt is None:  # before the evaluation, not after it
        raise InputError("--motion needs --gt (the GT BaseVersion of `mctrack nuscenes`)")
    tracks = Path(args.tracks)
    if not tracks.is_file():
        raise InputError(f"{tracks}: file not found")
    out = Path(args.out) if args.out else tracks.parent
    _check_nuscenes_ground_truth(args)
    # a refused evaluation leaves no output of its own (a half-written nuscenes_eval/)
    with outputs_removed_on_failure(out, outputs_of("eval"), folders=("nuscenes_eval/plots",)):
        return _evaluate_nuscenes(args, tracks, out)


def _check_nuscenes_ground_truth(args: argparse.Namespace) -> None:
    """The devkit reads the split's annotations unchecked (a bad one was a devkit traceback, or
    blamed on the results file): check them as `mctrack nuscenes` does, before any output."""
    from tracker.eval.nuscenes import check_split_has_ground_truth
    from tracker.io.convert.nuscenes import check_ground_truth, load_nuscenes

    check_split_has_ground_truth(args.split)
    nusc = load_nuscenes(args.dataroot, args.version)
    check_ground_truth(nusc, args.split)
    del nusc  # several GB on v1.0-trainval; the evaluation loads its own copy
    gc.collect()  # (the devkit's NuScenes and its explorer refer to each other)


def _evaluate_nuscenes(args: argparse.Namespace, tracks: Path, out: Path) -> int:
    from tracker.eval.nuscenes import evaluate_nuscenes, nuscenes_markdown

    out.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"tracks": str(tracks), "dataset": "nuscenes"}
    md = ["# Evaluation", ""]
    motion_inputs = None
    if _is_submission(tracks):
        results_path = tracks
        if args.motion:
            raise InputError("--motion needs a tracks file, not a submission results.json")
    else:
        from tracker.io.nuscenes_writer import write_nuscenes_results
        from tracker.io.writers import read_tracks_file

        track_frames, outputs = read_tracks_file(tracks)
        results_path = out / EVAL_SUBMISSION
        write_nuscenes_results(results_path, {s: (track_frames[s], outputs[s]) for s in outputs})
        motion_inputs = outputs
    result["results"] = str(results_path)
    result["static"] = evaluate_nuscenes(
        results_path,
        dataroot=args.dataroot,
        version=args.version,
        split=args.split,
        out_dir=out / "nuscenes_eval",
    )
    static = result["static"]
    md.append(nuscenes_markdown(static) if isinstance(static, dict) else f"{static}\n")
    if args.motion and motion_inputs is not None:
        from tracker.eval.motion_eval import MOTION_PLOT, evaluate_motion, motion_report_lines

        classes = args.classes or list(load_config("nuscenes").categories)
        gt = read_baseversion(args.gt)
        dets = read_baseversion(args.detections) if args.detections else None
        result["motion"] = evaluate_motion(
            dets, gt, motion_inputs, classes=classes, plot_path=out / MOTION_PLOT
        )
        md += motion_report_lines(result["motion"])
    write_text_atomic(out / "eval.json", [json.dumps(result, indent=2, allow_nan=False)])
    write_text_atomic(out / "eval.md", ["\n".join(md) + "\n"])
    if isinstance(static, dict):
        overall = static["overall"]
        print(
            "AMOTA {amota:.3f}  AMOTP {amotp:.3f}  recall {recall:.3f}  MOTA {mota:.3f}  "
            "IDS {ids:.0f}".format(**{k: overall.get(k) or 0.0 for k in overall})
        )
    else:  # (no box to evaluate)
        print(f"nuScenes metrics: {static}")
    if "motion" in result:  # (as `mctrack eval` prints them for KITTI)
        print_motion(result["motion"])
    print(f"wrote {out / 'eval.json'} and {out / 'eval.md'}")
    return 0
