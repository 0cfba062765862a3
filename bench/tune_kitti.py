"""Grid search of KITTI config overrides on the validation sequences (tracking + TrackEval).

Usage:
    python bench/tune_kitti.py --classes car --grid '{"defaults.score_min": [0.5, 0.7]}' \
        [--base '{"defaults.lifecycle.min_hits": 2}'] [--mode online] --out /tmp/tune.jsonl

Keys are dotted config paths; every combination is run with the same settings for all
sequences (settings must generalise). One JSON line per run is appended to --out.
"""

from __future__ import annotations

import argparse
import itertools
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from tracker.config import load_config
from tracker.eval.kitti import evaluate_kitti
from tracker.io.convert.kitti import VALIDATION_SEQS, convert_kitti
from tracker.io.writers import write_kitti_sequence
from tracker.pipeline import run_scene


def nested(flat: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in flat.items():
        node = out
        *parents, leaf = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out


def merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--kitti-root", default="../shared/data/kitti/tracking")
    parser.add_argument("--classes", default="car")
    parser.add_argument("--grid", default="{}")
    parser.add_argument("--base", default="{}")
    parser.add_argument("--mode", default="online")
    parser.add_argument("--config", default="kitti")
    parser.add_argument("--seqs", default=",".join(VALIDATION_SEQS))
    parser.add_argument("--det-image-boxes", action="store_true")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    classes = args.classes.split(",")
    seqs = args.seqs.split(",")
    scenes, _ = convert_kitti(Path(args.kitti_root), seqs=seqs, classes=classes, with_gt=False)
    grid = json.loads(args.grid)
    base = json.loads(args.base)
    keys = list(grid)
    for values in itertools.product(*[grid[k] for k in keys]):
        flat = {**base, **dict(zip(keys, values, strict=True))}
        overrides = merge(nested(flat), {"categories": classes, "mode": args.mode})
        config = load_config(args.config, overrides=overrides)
        with tempfile.TemporaryDirectory() as tmp:
            secs = 0.0
            for seq, frames in scenes.items():
                result = run_scene(frames, config)
                secs += result.tracker_seconds
                write_kitti_sequence(
                    Path(tmp) / f"{seq}.txt",
                    result.outputs,
                    frames,
                    detection_image_boxes=args.det_image_boxes,
                )
            start = time.perf_counter()
            metrics = evaluate_kitti(
                label_dir=Path(args.kitti_root) / "training" / "label_02",
                result_dir=Path(tmp),
                seq_lengths={s: len(f) for s, f in scenes.items()},
                classes=classes,
            )
        record = {
            "overrides": flat,
            "tracker_seconds": round(secs, 2),
            "metrics": metrics,
            "eval_seconds": round(time.perf_counter() - start, 1),
        }
        line = " ".join(
            f"{c}: HOTA {m['HOTA']:.2f} DetA {m['DetA']:.2f} AssA {m['AssA']:.2f} "
            f"MOTA {m['MOTA']:.2f} IDSW {m['IDSW']} FP {m['FP']} FN {m['FN']}"
            for c, m in metrics.items()
        )
        print(json.dumps(flat), "->", line, flush=True)
        with open(args.out, "a") as fh:
            fh.write(json.dumps(record) + "\n")


if __name__ == "__main__":
    main()
