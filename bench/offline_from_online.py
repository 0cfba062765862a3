"""Held-out figure of offline mode built on the online settings (a design measured, not shipped).

    python bench/offline_from_online.py [docs/tune/car_online.json] [--track-score-min 0|gate]

For each fold of a `mctrack tune --mode online` record, the fold's chosen online settings (and
score profiles fitted on the fold's training sequences, as the tune does) track the held-out
sequences twice: online, and offline with the untuned whole-track post-processing (track score
gate on the mean log-odds, interpolation up to 30 frames, 1.5 s smoothing, one size per track)
instead of the separately tuned `kitti_offline` settings. The online figure reproduces the
record's cross-validated one; the offline figure is the held-out figure of this design.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from app import tune
from app.tune import _evaluate_dir, _track_and_score, folds_by_frames, settings_to_overrides
from tracker.calibration import calibrate_frames
from tracker.eval.calibrate import fit_profile
from tracker.io.convert.kitti import VALIDATION_SEQS, convert_kitti

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("record", nargs="?", default=str(ROOT / "docs/tune/car_online.json"))
    parser.add_argument("--kitti-root", default=str(ROOT.parent / "shared/data/kitti/tracking"))
    parser.add_argument(
        "--track-score-min",
        default="0",
        help="offline whole-track gate (mean log-odds), or 'gate': each fold's online gate",
    )
    args = parser.parse_args()
    record = json.loads(Path(args.record).read_text())
    cls = record["class"]
    root = Path(args.kitti_root)
    label_dir = root / "training" / "label_02"
    work = Path(tempfile.mkdtemp(prefix="offline-from-online-"))
    for det in record["detectors"]:
        raw, gt = convert_kitti(root, seqs=VALIDATION_SEQS, detector=det, classes=[cls])
        lengths = {s: len(f) for s, f in raw.items()}
        if [f["test"] for f in record["cv"]] != folds_by_frames(lengths, len(record["cv"])):
            raise SystemExit(f"{args.record}: its folds are not this kit's")
        for k, fold in enumerate(record["cv"]):
            train = [s for s in lengths if s not in fold["test"]]
            profile = fit_profile(det, {s: raw[s] for s in train}, gt or {}, [cls])
            key = (det, f"fold{k}", "clean")
            tune._FRAMES[key] = {s: calibrate_frames(raw[s], profile) for s in fold["test"]}
            gate = (
                fold["best"].get("lifecycle.track_score_min", 0.0)
                if args.track_score_min == "gate"
                else float(args.track_score_min)
            )
            offline = {
                "track_score_min": gate,
                "interpolate_max_gap": 30,
                "smooth_seconds": 1.5,
                "constant_size": True,
            }
            for mode in ("online", "offline"):
                overrides = {
                    "categories": [cls],
                    "mode": mode,
                    "offline": offline,
                    **settings_to_overrides(cls, fold["best"]),
                }
                out = str(work / mode / det)
                _track_and_score(
                    (key, fold["test"], "kitti", overrides, out, str(label_dir), cls, False)
                )
        on = _evaluate_dir(work / "online" / det, label_dir, lengths, cls)
        off = _evaluate_dir(work / "offline" / det, label_dir, lengths, cls)
        print(
            f"{det:12s} held out: online {on['HOTA']:.2f}  offline {off['HOTA']:.2f}"
            f"  ({off['HOTA'] - on['HOTA']:+.2f}; FP {on['FP']} -> {off['FP']})",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
