"""Held-out figures of offline mode (`kitti_offline`: the online settings + post-processing).

    python bench/offline_from_online.py [docs/tune/car_online.json] [--kitti-root ROOT]

`kitti_offline` adds nothing tuned to the online settings, so its held-out figure follows from
the online tune's folds: for each fold of a `mctrack tune --mode online` record, the fold's chosen
settings (with score profiles fitted on the fold's training sequences, as the tune does) track
the fold's held-out sequences online and offline. The online figure reproduces the record's
cross-validated one; the offline figure is the held-out figure of offline mode.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

from app import tune
from app.inputs import default_kitti_root
from app.tune import _evaluate_dir, _track_and_score, folds_by_frames, settings_to_overrides
from tracker.calibration import calibrate_frames
from tracker.eval.calibrate import fit_profile, fit_self_profile
from tracker.io.convert.kitti import VALIDATION_SEQS, convert_kitti

ROOT = Path(__file__).resolve().parents[1]

MODES = {"online": "kitti", "offline": "kitti_offline"}


def held_out(
    record_path: Path,
    root: Path,
    *,
    detectors: list[str] | None = None,
    modes: tuple[str, ...] = ("online", "offline"),
    profile: str = "labels",
) -> dict[str, dict[str, dict[str, Any]]]:
    """``{detector: {mode: metrics}}`` over the record's held-out folds.

    ``detectors``: those to track (default: the record's own; others are held out as detectors
    too). ``profile``: "labels", each fold's score profile fitted on its training sequences (as
    the tune does), or "self", the label-free profile fitted on the detections themselves (what
    a detector without a profile gets)."""
    if profile not in ("labels", "self"):
        raise ValueError(f"profile: expected 'labels' or 'self', got {profile!r}")
    record = json.loads(record_path.read_text())
    if record["mode"] != "online":
        raise SystemExit(f"{record_path}: an online tune record is needed")
    cls = record["class"]
    label_dir = root / "training" / "label_02"
    out: dict[str, dict[str, dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory(prefix="fold-figures-") as tmp:
        work = Path(tmp)
        for det in detectors or record["detectors"]:
            raw, gt = convert_kitti(root, seqs=VALIDATION_SEQS, detector=det, classes=[cls])
            lengths = {s: len(f) for s, f in raw.items()}
            if [f["test"] for f in record["cv"]] != folds_by_frames(lengths, len(record["cv"])):
                raise SystemExit(f"{record_path}: its folds are not this kit's")
            self_profile = fit_self_profile(det, raw, [cls]) if profile == "self" else None
            for k, fold in enumerate(record["cv"]):
                train = [s for s in lengths if s not in fold["test"]]
                fitted = (
                    self_profile
                    if self_profile is not None
                    else fit_profile(det, {s: raw[s] for s in train}, gt or {}, [cls])
                )
                key = (det, f"fold{k}", "clean")
                tune._FRAMES[key] = {s: calibrate_frames(raw[s], fitted) for s in fold["test"]}
                overrides = {"categories": [cls], **settings_to_overrides(cls, fold["best"])}
                for mode in modes:
                    result_dir = str(work / mode / det)
                    task = (key, fold["test"], MODES[mode], overrides, result_dir,
                            str(label_dir), cls, False)  # fmt: skip
                    _track_and_score(task)
                del tune._FRAMES[key]
            out[det] = {
                mode: _evaluate_dir(work / mode / det, label_dir, lengths, cls) for mode in modes
            }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("record", nargs="?", default=str(ROOT / "docs/tune/car_online.json"))
    parser.add_argument("--kitti-root", type=Path, default=None)
    args = parser.parse_args()
    figures = held_out(Path(args.record), args.kitti_root or default_kitti_root())
    for det, by_mode in figures.items():
        on, off = by_mode["online"], by_mode["offline"]
        print(
            f"{det:12s} held out: online {on['HOTA']:.2f}  offline {off['HOTA']:.2f}"
            f"  ({off['HOTA'] - on['HOTA']:+.2f}; FP {on['FP']} -> {off['FP']})",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
