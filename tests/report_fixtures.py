"""Hand-made runs with known ID-switch differences, for the compare and report tests.

One KITTI sequence ("0001", 10 frames) with three cars whose 2D boxes never overlap. Each run's
result file repeats the GT boxes with chosen track ids, so TrackEval's CLEAR matches every box
and the only ID switches are the planned ones:

========  ==========================  ==========================
GT        run A                       run B
========  ==========================  ==========================
car 1     T1 f0-4, T2 f5-9: IDSW f5   T1 throughout (fixed)
car 2     T3 f0-2, T4 f3-9: IDSW f3   T3 f0-3, T4 f4-9: IDSW f4 (kept, 1 frame later)
car 3     T5 throughout               T5 f0-5, T6 f6-9: IDSW f6 (introduced)
========  ==========================  ==========================
"""

from __future__ import annotations

import json
from pathlib import Path

SEQ = "0001"
FRAMES = 10
BOXES = {1: (0, 100, 100, 200), 2: (200, 100, 300, 200), 3: (400, 100, 500, 200)}
RUN_A = {1: lambda f: 1 if f < 5 else 2, 2: lambda f: 3 if f < 3 else 4, 3: lambda f: 5}
RUN_B = {1: lambda f: 1, 2: lambda f: 3 if f < 4 else 4, 3: lambda f: 5 if f < 6 else 6}


def _line(frame: int, track: int, box: tuple[int, int, int, int], score: float | None) -> str:
    x1, y1, x2, y2 = box
    tail = f" {score:.3f}" if score is not None else ""
    return (
        f"{frame} {track} Car 0 0 -1.5 {x1} {y1} {x2} {y2} 1.5 1.6 4.0 "
        f"{2.0 + track} 1.6 {20.0 + frame} 0.0{tail}"
    )


def write_labels(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    lines = [_line(f, g, BOXES[g], None) for f in range(FRAMES) for g in BOXES]
    (folder / f"{SEQ}.txt").write_text("\n".join(lines) + "\n")
    return folder


def write_run(folder: Path, tracks: dict, labels: Path, *, name: str) -> Path:
    """A minimal `mctrack kitti --out` folder: summary.json and data/<seq>.txt."""
    (folder / "data").mkdir(parents=True, exist_ok=True)
    lines = [_line(f, tracks[g](f), BOXES[g], 0.9) for f in range(FRAMES) for g in BOXES]
    (folder / "data" / f"{SEQ}.txt").write_text("\n".join(lines) + "\n")
    idsw = sum(tracks[g](f) != tracks[g](f - 1) for g in BOXES for f in range(1, FRAMES))
    summary = {
        "command": "kitti",  # (what marks a run's summary.json: app.outputs.is_run_summary)
        "dataset": "kitti",
        "detector": "hand-made",
        "config_name": name,
        "labels": str(labels),
        "sequences": [SEQ],
        "mode": "online",
        "classes": ["car"],
        "metrics": {"car": {"HOTA": 90.0 if name == "a" else 95.0, "IDSW": idsw, "Frag": 0}},
        "per_sequence": {SEQ: {"car": {"IDSW": idsw, "Frag": 0}}},
    }
    (folder / "summary.json").write_text(json.dumps(summary))
    return folder


def make_runs(root: Path) -> tuple[Path, Path, Path]:
    """(run A, run B, labels folder) under ``root``."""
    labels = write_labels(root / "label_02")
    a = write_run(root / "a", RUN_A, labels, name="a")
    b = write_run(root / "b", RUN_B, labels, name="b")
    return a, b, labels
