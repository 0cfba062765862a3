"""Where the recording's overhead goes (docs/debugger.md, "Overhead per frame").

cProfile of ``record_scene`` on the bundled KITTI 0001 (no GT) against plain ``run_scene``;
prints the profiled overhead and the cumulative seconds of its main parts. Profiled times are
about twice the real ones; compare shares, not seconds.

Usage: ``python bench/profile_record.py``
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SAMPLE = ROOT / "sample_data" / "kitti-0001"
PARTS = {
    "image-plane stage (tracker)": "mctracker.py:384(_rv_stage)",
    "observers (Rerun observer, fates)": "fates.py:210(__call__)",
    "  of which the Rerun observer": "observer.py:138(__call__)",
    "buffered rows -> columns, sent": "columns.py:111(flush)",
    "velocity curves (after the run)": "(_log_velocity_series)",
    "tracker with observers": "pipeline.py:54(run_scene)",
}


def _profile(fn: Callable[[], object]) -> pstats.Stats:
    profile = cProfile.Profile()
    profile.enable()
    fn()
    profile.disable()
    return pstats.Stats(profile)


def _cumulative(stats: pstats.Stats, pattern: str) -> float:
    found = [
        ct
        for (f, line, name), (_, _, _, ct, _) in stats.stats.items()  # type: ignore[attr-defined]
        if pattern in f"{f}:{line}({name})"
    ]
    return max(found, default=0.0)


def main() -> int:
    from tracker.config import load_config
    from tracker.io.baseversion import read_baseversion
    from tracker.pipeline import run_scene
    from viz.record import record_scene

    config = load_config("kitti")
    frames = read_baseversion(SAMPLE / "detections.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    images = {"CAM_FRONT": SAMPLE / "image_02"}
    with tempfile.TemporaryDirectory() as tmp:
        run_scene(frames, config)  # warm-up (imports, caches)
        record_scene(frames, config, path=Path(tmp) / "warm.rrd", images=images)
        plain = _profile(lambda: run_scene(frames, config))
        out = Path(tmp) / "r.rrd"
        rec = _profile(lambda: record_scene(frames, config, path=out, images=images))
    plain_s, rec_s = plain.total_tt, rec.total_tt  # type: ignore[attr-defined]
    print(f"KITTI 0001, profiled: tracking {plain_s:.2f} s, with the recording {rec_s:.2f} s")
    print(f"  overhead {rec_s - plain_s:.2f} s")
    for label, pattern in PARTS.items():
        base = _cumulative(plain, pattern)
        extra = f" (plain run: {base:.2f})" if base else ""
        print(f"  {label:<36} {_cumulative(rec, pattern):6.2f} s{extra}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
