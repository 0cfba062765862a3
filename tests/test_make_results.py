"""bench/make_results.py's text that is not a measurement: the quoted summary.json."""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from make_results import QUOTE_LEFT_OUT, summary_quote


def test_the_summary_quote_leaves_out_what_it_says_and_no_machine_path() -> None:
    summary = {
        "command": "kitti",
        "kitti_root": "/home/me/work/../shared/kit",
        "labels": "/home/me/work/../shared/kit/training/label_02",
        "skipped_at_load": {},
        "evaluated_sequences": ["0001"],
        **{k: {"long": 1} for k in QUOTE_LEFT_OUT},
    }
    lines = summary_quote(summary, cwd=Path("/home/me/work"))
    text = "\n".join(lines)
    quoted = json.loads(text.split("```json\n")[1].split("\n```")[0])
    assert quoted == {
        "command": "kitti",
        "kitti_root": "../shared/kit",
        "labels": "../shared/kit/training/label_02",
        "skipped_at_load": {},
        "evaluated_sequences": ["0001"],
    }
    prose = " ".join(lines[0].split())
    assert all(f"`{k}`" in prose for k in QUOTE_LEFT_OUT) and "relative to the folder" in prose
