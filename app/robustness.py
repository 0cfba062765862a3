"""`mctrack robustness`: seeded detection noise, tracked and scored against the clean input.

Converts the KITTI detections once, perturbs them per noise level and seed
(:mod:`tracker.eval.perturb`), tracks each set, writes KITTI results and scores them with the
standard evaluator (TrackEval, KITTI 2D box protocol). Prints HOTA per class and level (mean over
seeds ± the seeds' standard deviation, and the change from clean) and writes
``OUT/robustness.json`` and ``OUT/robustness.md``; the result files stay in
``OUT/runs/<level>/seed<k>/``. The clean level is always run, once (it does not depend on the seed).
A run into the folder of an earlier one replaces its outputs (the files above; others stay).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from app.common import (
    NO_PROFILE,
    command_line,
    log_self_profile,
    profile_argument,
    remove_earlier_outputs,
    score_source,
    self_calibrated_note,
    warn_undetected_classes,
)
from app.inputs import (
    add_detector_argument,
    add_kitti_root_argument,
    check_kitti_root,
    class_list,
    default_kitti_root,
    sequence_list,
)
from app.outputs import outputs_of
from tracker.calibration import (
    calibrate_frames,
    raw_outside_profile,
    raw_scored_per_class,
    warn_classes_without_map,
    warn_scores_outside,
)
from tracker.categories import category_index
from tracker.config import load_config
from tracker.errors import InputError
from tracker.eval.perturb import (
    CLEAN,
    JITTERED_BOXES,
    NOISE_LEVELS,
    JitteredBoxes,
    PerturbSpec,
    Rescore,
    perturb_frames,
)
from tracker.io.convert.kitti import VALIDATION_SEQS
from tracker.io.fileio import check_output_folder, write_text_atomic
from tracker.io.writers import write_kitti_sequence
from tracker.pipeline import run_scene

EVALUATOR = "trackeval 1.3.0, KITTI 2D box protocol (HOTA, CLEAR, Identity)"
#: Metrics kept per run in the json (the table shows HOTA).
KEPT_METRICS = ("HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW", "Frag", "FP", "FN")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_kitti_root_argument(parser)
    add_detector_argument(parser)
    parser.add_argument(
        "--seqs",
        type=sequence_list,
        default=",".join(VALIDATION_SEQS),
        help="comma-separated sequences (default: the 11 validation sequences)",
    )
    parser.add_argument(
        "--classes",
        type=class_list,
        default="car,pedestrian,cyclist",
        help="comma-separated classes to track and score (default: %(default)s)",
    )
    parser.add_argument("--config", default="kitti", help="kitti or a TOML path")
    parser.add_argument(
        "--levels",
        default="clean,noise,double",
        help=f"noise levels, from {', '.join(NOISE_LEVELS)} (clean is always run; drop, jitter"
        " and fp are the parts of noise, one at a time)",
    )
    parser.add_argument(
        "--level",
        action="append",
        metavar="NAME:drop=R:centre=M:yaw=DEG:fp=R",
        help="a level of your own, run after --levels (repeatable): drop rate in [0, 1], centre"
        " jitter σ in metres, yaw jitter σ in degrees, false positives per real box; parts left"
        " out are 0, not all of them unless --score-sigma is set (e.g."
        " double_jitter:centre=0.3:yaw=5)",
    )
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated seeds (integers >= 0)")
    parser.add_argument(
        "--score-sigma",
        type=float,
        default=0.0,
        help="std of the noise added to the raw detector score on the noisy levels (default 0)",
    )
    parser.add_argument(
        "--image-boxes",
        choices=JITTERED_BOXES,
        default="follow",
        help="what the centre and yaw jitter does to a detection's 2D box: follow = moves it"
        " with its 3D box's projection (a LiDAR detector's 2D box is that projection); keep ="
        " leaves it (a 2D box from an image head) (default: follow)",
    )
    parser.add_argument(
        "--profile",
        default=None,
        help="score calibration profile, as `mctrack kitti --profile` takes it (default: the one "
        "shipped for --detector, else 'self': fitted without labels on the run's detections)",
    )
    parser.add_argument("--out", default="robustness", help="output folder")


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    custom_levels, seeds = parse_levels(args.level or []), _seeds(args.seeds)
    root = args.kitti_root or default_kitti_root()
    check_kitti_root(root, seqs=args.seqs, detector=args.detector)
    report = run_robustness(
        kitti_root=root,
        seqs=args.seqs,
        classes=args.classes,
        config_name=args.config,
        detector=args.detector,
        levels=_names(args.levels),
        custom_levels=custom_levels,
        seeds=seeds,
        score_sigma=args.score_sigma,
        image_boxes=args.image_boxes,
        profile=profile_argument(args.profile),
        out=Path(args.out),
    )
    print("\n".join(table_lines(report, markdown=False)))
    print(f"wall time {time.perf_counter() - t0:.1f} s; wrote {Path(args.out) / 'robustness.md'}")
    return 0


def run_robustness(
    *,
    kitti_root: Path,
    seqs: Sequence[str],
    classes: Sequence[str],
    config_name: str | Path = "kitti",
    detector: str = "pointrcnn",
    levels: Sequence[str] = (CLEAN, "noise", "double"),
    custom_levels: Mapping[str, PerturbSpec] | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    score_sigma: float = 0.0,
    image_boxes: JitteredBoxes = "follow",
    rescore: Rescore | None = None,
    profile: Path | str | None = None,
    out: Path,
    quiet: bool = False,
) -> dict[str, Any]:
    """The benchmark; returns (and writes) ``out/robustness.json``.

    ``custom_levels`` are levels of the caller's own (name -> noise), run after ``levels``.
    ``profile``: a profile file or shipped name, ``"self"`` or ``"none"`` as ``mctrack kitti
    --profile`` takes them; by default the detector's shipped profile, else one fitted without
    labels on the run's detections (as ``mctrack kitti`` does). ``rescore`` maps (category, raw
    score) to the tracker's score after score noise (default: that profile's map, when the
    config asks for calibrated scores; else the converter's sigmoid; not an option of the
    command line the report records).
    """
    from tracker.eval.kitti import SUPPORTED_CLASSES, check_kitti_labels, evaluate_kitti
    from tracker.io.convert.kitti import convert_kitti

    bad_classes = [c for c in classes if c not in SUPPORTED_CLASSES]
    if bad_classes:
        raise InputError(f"--classes: cannot score {bad_classes}; supported: {SUPPORTED_CLASSES}")
    unknown = [name for name in levels if name not in NOISE_LEVELS]
    if unknown:
        raise InputError(f"unknown noise level(s) {unknown}; known: {', '.join(NOISE_LEVELS)}")
    if score_sigma < 0 or not np.isfinite(score_sigma):
        raise InputError(f"--score-sigma must be a finite value >= 0, got {score_sigma}")
    custom_levels = dict(custom_levels or {})
    taken = [name for name in custom_levels if name.lower() in NOISE_LEVELS]
    if taken:
        raise InputError(f"--level: {taken} already name built-in levels; choose other names")
    bad = [name for name in custom_levels if not LEVEL_NAME.fullmatch(name)]
    if bad:  # (the name is a folder under out/runs)
        raise InputError(f"--level: names {bad} are not 1-64 letters, digits, '_' or '-'")
    specs = {CLEAN: NOISE_LEVELS[CLEAN]}  # the reference every drop is measured from
    for name, spec in [*((n, NOISE_LEVELS[n]) for n in levels), *custom_levels.items()]:
        if name != CLEAN:
            specs[name] = dataclasses.replace(spec, score_sigma=score_sigma)
    same = [name for name in custom_levels if specs[name].is_clean]
    if same:  # (its row would be clean's again, under another name: a level given no parts)
        raise InputError(
            f"--level {same[0]}: no noise (drop, centre, yaw and fp all 0, and --score-sigma "
            f"0), the clean level again; give it a part, e.g. {same[0]}:centre=0.3"
        )
    label_dir = kitti_root / "training" / "label_02"
    missing = [str(label_dir / f"{s}.txt") for s in seqs if not (label_dir / f"{s}.txt").is_file()]
    if missing:
        raise InputError(f"no labels to score against: {', '.join(missing)}")
    config = load_config(config_name, overrides={"categories": list(classes)})
    calibrate, calibration, calibration_note = score_source(config, detector, profile)
    # every argument is accepted: only now is --out made (a refused run leaves no folder
    # behind), and a bad --out still fails before any work, naming --out
    check_output_folder(out)
    t0 = time.perf_counter()
    try:
        detections, _ = convert_kitti(
            kitti_root, seqs=seqs, detector=detector, classes=classes, with_gt=False
        )
    except FileNotFoundError as exc:
        raise InputError(str(exc)) from None
    found = {int(c) for fr in detections.values() for f in fr for c in np.unique(f.boxes.category)}
    warn_undetected_classes(detector, [c for c in classes if category_index(c) not in found])
    if calibrate:  # thresholds in calibrated units
        if calibration is not None:  # a profile's classes without a map keep the fallback
            every = [frame for frames in detections.values() for frame in frames]
            source = str(profile or f"{detector} (shipped)")
            warn_classes_without_map(calibration, detector, raw_scored_per_class(every), source)
        elif profile != NO_PROFILE:  # as `mctrack kitti` does
            from tracker.eval.calibrate import fit_self_profile

            calibration = fit_self_profile(detector, detections, classes)
            log_self_profile(calibration, classes)
            calibration_note = self_calibrated_note(profile, detector, calibration)
        detections = {s: calibrate_frames(f, calibration) for s, f in detections.items()}
        if calibration is not None:
            every = [frame for frames in detections.values() for frame in frames]
            warn_scores_outside(calibration, detector, raw_outside_profile(calibration, every))
        if calibration is not None and rescore is None:
            rescore = calibration.scores
    lengths = {seq: len(frames) for seq, frames in detections.items()}
    # a bad label file stops the run here, not after the clean level is tracked (and the
    # earlier run's outputs are gone)
    labelled = check_kitti_labels(
        label_dir, lengths, dict.fromkeys(lengths, "the kit's pose lines"), classes=classes
    )
    # checked as evaluate_kitti checks them (the classes scored, these lengths), so each job's
    # evaluation need not read them again; one not found here is left to its check to name
    labels_checked = labelled.keys() >= lengths.keys()
    options = [
        ("--kitti-root", kitti_root), ("--detector", detector), ("--seqs", ",".join(seqs)),
        ("--classes", ",".join(classes)), ("--config", config_name),
        ("--levels", ",".join(levels)),
        *(("--level", level_text(n, dataclasses.asdict(sp))) for n, sp in custom_levels.items()),
        ("--seeds", ",".join(map(str, seeds))), ("--score-sigma", _number(score_sigma)),
        ("--image-boxes", image_boxes), *([("--profile", profile)] if profile else []),
        ("--out", out),
    ]  # fmt: skip
    # the inputs are accepted: the earlier run's outputs go (a refused run keeps them); other
    # files (and a runs/ folder's other contents) are left alone
    remove_earlier_outputs(out, outputs_of("robustness"))

    jobs = [(name, None if name == CLEAN else seed) for name in specs for seed in seeds]
    jobs = list(dict.fromkeys(jobs))  # clean once
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in specs}
    total = len(jobs) * sum(lengths.values())
    with tqdm(total=total, unit="frame", disable=quiet or None, file=sys.stderr) as bar:
        for name, seed in jobs:
            run_dir = out / "runs" / name / ("clean" if seed is None else f"seed{seed}")
            for seq, frames in detections.items():
                bar.set_description(f"{name} seed {'-' if seed is None else seed} seq {seq}")
                noisy = perturb_frames(
                    frames, specs[name], seed=seed or 0, rescore=rescore, image_boxes=image_boxes
                )
                result = run_scene(noisy, config)
                write_kitti_sequence(
                    run_dir / f"{seq}.txt",
                    result.outputs,
                    noisy,
                    **config.kitti_writer_options(),
                )
                bar.update(len(frames))
            metrics = evaluate_kitti(
                label_dir=label_dir,
                result_dir=run_dir,
                seq_lengths=lengths,
                classes=classes,
                labels_checked=labels_checked,
            )
            runs[name].append(
                {
                    "seed": seed,
                    "metrics": {
                        cls: {k: m[k] for k in KEPT_METRICS if k in m} for cls, m in metrics.items()
                    },
                }
            )
    report: dict[str, Any] = {
        "dataset": "kitti",
        "detector": detector,
        "sequences": list(detections),
        "classes": list(classes),
        "config": str(config_name),
        "mode": config.mode.value,
        "seeds": list(seeds),
        "image_boxes": image_boxes,
        "score_calibration": calibration_note,
        "custom_levels": list(custom_levels),
        # every option that changes the result, as given: the line repeats the run
        "command": command_line(["robustness", *(str(w) for pair in options for w in pair)]),
        "evaluator": EVALUATOR,
        "spread": "standard deviation over seeds (ddof=1; 0 for one run)",
        "levels": {
            name: {
                "spec": dataclasses.asdict(spec),
                "runs": runs[name],
                "summary": _summary(runs[name], runs[CLEAN], classes),
            }
            for name, spec in specs.items()
        },
        "wall_seconds": round(time.perf_counter() - t0, 1),
    }
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "robustness.json", [json.dumps(report, indent=2)])
    write_text_atomic(out / "robustness.md", ["\n".join(markdown_lines(report))])
    return report


def _summary(
    runs: list[dict[str, Any]], clean: list[dict[str, Any]], classes: Sequence[str]
) -> dict[str, dict[str, float]]:
    """Per class: HOTA mean and spread over the runs, and the mean's change from clean."""
    out = {}
    for cls in classes:
        hota = np.array([r["metrics"][cls]["HOTA"] for r in runs], dtype=np.float64)
        clean_hota = float(np.mean([r["metrics"][cls]["HOTA"] for r in clean]))
        spread = float(np.std(hota, ddof=1)) if len(hota) > 1 else 0.0
        out[cls] = {
            "HOTA_mean": round(float(hota.mean()), 3),
            "HOTA_spread": round(spread, 3),
            "HOTA_drop": round(float(hota.mean()) - clean_hota, 3),
        }
    return out


def _spec_text(spec: dict[str, float]) -> str:
    if not any(spec.values()):
        return "none"
    text = (
        f"drop {spec['drop_rate']:.0%}, σ {spec['centre_sigma_m']:g} m, "
        f"yaw σ {spec['yaw_sigma_deg']:g}°, FP {spec['fp_rate']:.0%}"
    )
    return text + (f", score σ {spec['score_sigma']:g}" if spec["score_sigma"] else "")


def table_lines(report: dict[str, Any], *, markdown: bool) -> list[str]:
    """The HOTA table: a row per level; per class the mean ± spread and the change from clean."""
    classes = report["classes"]
    header = ["level", "perturbation"]
    for cls in classes:
        header += [f"{cls} HOTA", f"{cls} Δ"]
    rows = []
    for name, level in report["levels"].items():
        row = [name, _spec_text(level["spec"])]
        for cls in classes:
            s = level["summary"][cls]
            row += [f"{s['HOTA_mean']:.2f} ± {s['HOTA_spread']:.2f}", f"{s['HOTA_drop']:+.2f}"]
        rows.append(row)
    if markdown:
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        return lines + ["| " + " | ".join(row) + " |" for row in rows]
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    return ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in [header, *rows]]


def markdown_lines(report: dict[str, Any]) -> list[str]:
    seeds = ",".join(map(str, report["seeds"]))
    image_boxes = report["image_boxes"]
    moves = {
        "follow": "the jitter moves each detection's 2D box with its 3D box's projection",
        "keep": "the jitter leaves each detection's 2D box where the detector put it",
    }[image_boxes]
    return [
        "# Robustness to detection noise",
        "",
        f"Detector `{report['detector']}`, config `{report['config']}` ({report['mode']}), "
        f"sequences {' '.join(report['sequences'])}; {report['evaluator']}. HOTA: mean over "
        f"seeds {seeds} ± {report['spread']}; Δ: change of the mean from clean. Clean runs once;"
        f" {moves} (`--image-boxes {image_boxes}`).",
        "",
        *table_lines(report, markdown=True),
        "",
        f"Command: `{report['command']}` ({report['wall_seconds']} s).",
        "",
    ]


# --level's parts: its name for a PerturbSpec field (score noise is --score-sigma, for all)
_LEVEL_PARTS = {
    "drop": "drop_rate",
    "centre": "centre_sigma_m",
    "yaw": "yaw_sigma_deg",
    "fp": "fp_rate",
}


LEVEL_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")


def parse_levels(texts: Sequence[str]) -> dict[str, PerturbSpec]:
    """``--level`` arguments, by name; a name given twice (in any case: it names a folder) is an
    error."""
    levels: dict[str, PerturbSpec] = {}
    for text in texts:
        name, spec = parse_level(text)
        if name.lower() in NOISE_LEVELS:  # (checked here too: before --out is made)
            raise InputError(f"--level {text!r}: {name!r} already names a built-in level")
        if name.lower() in {n.lower() for n in levels}:
            raise InputError(f"--level {text!r}: a level named {name!r} is given already")
        levels[name] = spec
    return levels


def parse_level(text: str) -> tuple[str, PerturbSpec]:
    """``NAME:drop=R:centre=M:yaw=DEG:fp=R`` (parts optional, 0 when left out)."""
    name, *parts = text.split(":")
    if not LEVEL_NAME.fullmatch(name):
        raise InputError(
            f"--level {text!r}: the name must be 1-64 letters, digits, '_' or '-' "
            "(it names the level's folder under --out)"
        )
    values: dict[str, float] = {}
    for part in parts:
        key, _, value = part.partition("=")
        if key in values:
            raise InputError(f"--level {text!r}: {key} is given twice (each part once)")
        if key not in _LEVEL_PARTS:
            raise InputError(
                f"--level {text!r}: {part!r} is not one of {', '.join(_LEVEL_PARTS)} "
                "(each once, as key=value)"
            )
        try:
            values[key] = float(value)
        except ValueError:
            raise InputError(f"--level {text!r}: {key} must be a number, got {value!r}") from None
    try:
        spec = PerturbSpec(**{_LEVEL_PARTS[k]: v for k, v in values.items()})
    except ValueError as exc:
        raise InputError(f"--level {text!r}: {exc}") from None
    return name, spec


def level_text(name: str, spec: dict[str, float]) -> str:
    """The ``--level`` argument that makes the level ``name`` with noise ``spec``."""
    parts = [f"{k}={_number(spec[f])}" for k, f in _LEVEL_PARTS.items() if spec[f]]
    return ":".join([name, *parts])


def _number(value: float) -> str:
    """The shortest text that reads back as ``value``."""
    short = f"{value:g}"
    return short if float(short) == value else repr(value)


def _names(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def _seeds(text: str) -> list[int]:
    try:
        seeds = [int(s) for s in _names(text)]
    except ValueError:
        raise InputError(f"--seeds: expected comma-separated integers, got {text!r}") from None
    if not seeds or min(seeds) < 0:
        raise InputError(f"--seeds: expected integers >= 0, got {text!r}")
    return list(dict.fromkeys(seeds))
