"""Where the recording's overhead goes (docs/debugger.md, "Overhead per frame").

1. Wall clock, best of ``--repeat`` interleaved runs on the bundled KITTI 0001 (no GT): plain
   tracking; with an observer that does nothing but asks for the image-plane costs (so the
   tracker runs stage 2 on every frame and builds its events); with one that takes them
   deferred, as the Rerun observer does (stage 2 skipped where it cannot match);
   with the detection fates; with the Rerun observer alone (its run, then its flush of the
   buffered rows); and ``record_scene`` (track, flush, post).
2. cProfile of ``record_scene`` against plain ``run_scene``: the cumulative seconds of the main
   parts. Profiled times are about twice the real ones; compare shares, not seconds.

Usage: ``python bench/profile_record.py [--repeat 3]``
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SAMPLE = ROOT / "sample_data" / "kitti-0001"
PARTS = {  # (file, function): cumulative seconds of that function
    "image-plane stage (tracker)": ("mctracker.py", "_rv_stage"),
    "  skipped frames' stage 2, at flush": ("image_stage.py", "deferred_image_stage"),
    "observers (Rerun observer, fates)": ("fates.py", "__call__"),
    "  of which the Rerun observer": ("observer.py", "__call__"),
    "buffered rows -> columns, sent": ("columns.py", "flush"),
    "velocity curves (after the run)": ("record.py", "_log_velocity_series"),
    "tracker with observers": ("pipeline.py", "run_scene"),
}


def _profile(fn: Callable[[], object]) -> pstats.Stats:
    profile = cProfile.Profile()
    profile.enable()
    fn()
    profile.disable()
    return pstats.Stats(profile)


def _cumulative(stats: pstats.Stats, part: tuple[str, str]) -> float:
    file, function = part
    found = [
        ct
        for (f, _, name), (_, _, _, ct, _) in stats.stats.items()  # type: ignore[attr-defined]
        if f.endswith("/" + file) and name == function
    ]
    return max(found, default=0.0)


class _AsksForCosts:
    """An observer that only makes the tracker compute every stage and build its events."""

    wants_rv_costs = True

    def __call__(self, event: object) -> None:
        pass


class _TakesCostsDeferred(_AsksForCosts):
    """As the Rerun observer: stage 2 is skipped where it cannot match (inputs kept)."""

    rv_costs_deferred = True


def wall_clock(repeat: int) -> None:
    from tracker.config import load_config
    from tracker.eval.fates import FateCounter
    from tracker.io.baseversion import read_baseversion
    from tracker.io.fileio import work_folder
    from tracker.pipeline import run_scene
    from viz.observer import RerunObserver
    from viz.record import new_recording, record_scene

    config = load_config("kitti")
    frames = read_baseversion(SAMPLE / "detections.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    images = {"CAM_FRONT": SAMPLE / "image_02"}
    n = len(frames)

    def observer_alone(path: Path) -> tuple[float, ...]:
        rec = new_recording("0001", path=path)
        observer = RerunObserver(rec, images=images)
        t0 = time.perf_counter()
        run_scene(frames, config, observer=observer)
        t1 = time.perf_counter()
        observer.flush()
        t2 = time.perf_counter()
        rec.flush()
        rec.disconnect()
        return t1 - t0, t2 - t1

    def recorded(path: Path) -> tuple[float, ...]:
        r = record_scene(frames, config, path=path, images=images)
        return r.seconds["track"], r.seconds["flush"], r.seconds["post"]

    variants: dict[str, Callable[[Path], object]] = {
        "plain tracking": lambda _: run_scene(frames, config),
        "+ observer asking for stage-2 costs": lambda _: run_scene(
            frames, config, observer=_AsksForCosts()
        ),
        "+ observer taking them deferred": lambda _: run_scene(
            frames, config, observer=_TakesCostsDeferred()
        ),
        "+ detection fates": lambda _: run_scene(frames, config, observer=FateCounter()),
        "Rerun observer alone: run, flush": observer_alone,
        "record_scene: track, flush, post": recorded,
    }
    best: dict[str, tuple[float, tuple[float, ...]]] = {}
    with work_folder("profile") as tmp:
        run_scene(frames, config)  # warm-up (imports, caches)
        for i in range(repeat):
            for name, fn in variants.items():
                t0 = time.perf_counter()
                parts = fn(Path(tmp) / f"{i}.rrd")
                total = time.perf_counter() - t0
                if name not in best or total < best[name][0]:
                    best[name] = (total, parts if isinstance(parts, tuple) else ())
    print(f"KITTI 0001 ({n} frames), best of {repeat}, wall clock, ms/frame:")
    for name, (total, parts) in best.items():
        split = " / ".join(f"{1000 * p / n:.2f}" for p in parts)
        print(f"  {name:<38} {1000 * total / n:6.2f}" + (f"  ({split})" if split else ""))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    wall_clock(args.repeat)

    from tracker.config import load_config
    from tracker.io.baseversion import read_baseversion
    from tracker.io.fileio import work_folder
    from tracker.pipeline import run_scene
    from viz.record import record_scene

    config = load_config("kitti")
    frames = read_baseversion(SAMPLE / "detections.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    images = {"CAM_FRONT": SAMPLE / "image_02"}
    with work_folder("profile") as tmp:
        run_scene(frames, config)  # warm-up (imports, caches)
        record_scene(frames, config, path=Path(tmp) / "warm.rrd", images=images)
        plain = _profile(lambda: run_scene(frames, config))
        out = Path(tmp) / "r.rrd"
        rec = _profile(lambda: record_scene(frames, config, path=out, images=images))
    plain_s, rec_s = plain.total_tt, rec.total_tt  # type: ignore[attr-defined]
    print(f"KITTI 0001, profiled: tracking {plain_s:.2f} s, with the recording {rec_s:.2f} s")
    print(f"  overhead {rec_s - plain_s:.2f} s")
    for label, part in PARTS.items():
        base = _cumulative(plain, part)
        extra = f" (plain run: {base:.2f})" if base else ""
        print(f"  {label:<36} {_cumulative(rec, part):6.2f} s{extra}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
