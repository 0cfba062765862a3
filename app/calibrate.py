"""`mctrack calibrate`: fit a detector's score calibration profile on labelled KITTI sequences."""

from __future__ import annotations

import argparse
import json
import logging

from app.inputs import (
    add_kitti_root_argument,
    check_kitti_root,
    class_list,
    default_kitti_root,
    sequence_list,
)
from tracker.calibration import profile_toml, raw_scored_per_class
from tracker.errors import InputError
from tracker.io.convert.kitti import VALIDATION_SEQS
from tracker.io.fileio import check_output_file, write_text_atomic

LOG = logging.getLogger("mctrack")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_kitti_root_argument(parser)
    parser.add_argument(
        "--detector",
        required=True,
        help="detections folder name under <root>/detections/ (e.g. virconv)",
    )
    parser.add_argument(
        "--seqs",
        type=sequence_list,
        default=",".join(VALIDATION_SEQS),
        help="labelled sequences to fit on (default: the 11 validation sequences)",
    )
    parser.add_argument(
        "--classes",
        type=class_list,
        default="car,pedestrian,cyclist",
        help="classes to calibrate; a class without detections keeps the fallback "
        "(default: %(default)s)",
    )
    parser.add_argument("--out", required=True, help="the profile to write (PROFILE.toml)")


def run(args: argparse.Namespace) -> int:
    from tracker.eval.calibrate import MIN_FIT_BOXES, fit_profile, one_score_warning
    from tracker.io.convert.kitti import convert_kitti

    classes, seqs = args.classes, args.seqs
    out = check_output_file(args.out)  # before the fit: a folder, or not writable
    root = args.kitti_root or default_kitti_root()
    check_kitti_root(root, seqs=seqs, detector=args.detector)
    detections, gt = convert_kitti(
        root, seqs=seqs, detector=args.detector, classes=classes, with_gt=True
    )
    if not gt:
        raise InputError(f"{root / 'training' / 'label_02'}: no labels for {seqs}")
    detections = {s: f for s, f in detections.items() if s in gt}
    profile = fit_profile(args.detector, detections, gt, classes)
    missing = [c for c in classes if c not in profile.maps]
    if missing:
        boxes = raw_scored_per_class([f for frames in detections.values() for f in frames])
        counts = ", ".join(f"{c} {boxes.get(c, 0)} boxes" for c in missing)
        why = (
            f"{counts} in {','.join(detections)} "
            f"(a map needs at least {MIN_FIT_BOXES} boxes of the class, some matching a label "
            "and some not)"
        )
        if not profile.maps:  # a profile without a class is no profile: write nothing
            raise InputError(
                f"no class could be fitted: {why}; nothing written to {out}",
                path=root / "detections" / args.detector / "training",
            )
    write_text_atomic(out, [profile_toml(profile)])
    for name, q in profile.quality.items():
        print(f"{args.detector} {name}: {json.dumps(q)}")
        one_score = one_score_warning(args.detector, name, q)
        if one_score is not None:  # a valid profile, but for this class it decides nothing
            LOG.warning("%s", one_score)
        held_out = q["held_out_by_sequence"]
        held = held_out["log_loss"] if isinstance(held_out, dict) else None
        plain = q["uncalibrated"]["log_loss"]
        if held is not None and held > plain:  # the fit does not carry over between sequences
            LOG.warning(
                "%s %s: fitted on some sequences and scored on the others, the profile predicts "
                "worse than the uncalibrated scores (log loss %.4f against %.4f): fit it on more "
                "labelled sequences (--seqs), or run without it",
                args.detector,
                name,
                held,
                plain,
            )
    if missing:
        print(f"no fit for {why}: they keep the fallback (sigmoid(raw), or raw where in [0, 1])")
    print(f"wrote {out}")
    return 0
