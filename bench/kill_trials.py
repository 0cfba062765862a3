"""Kill trials (docs/reliability.md): SIGKILL `mctrack track` and `mctrack demo` at spread-out
moments, then check what a killed run leaves in its output folder and that the next run
cleans it up.

    python bench/kill_trials.py [--trials 8] [--out DIR]

The trials run in a work folder of their own (tracker.io.fileio.work_folder), removed at the
end; with ``--out DIR`` in a new folder ``DIR/kill-<pid>-<time>``, kept to look at (nothing
already in DIR is touched, and two runs never share one).

For each trial it prints the files present after the kill and whether each is complete:
tracks.json / KITTI files load, summary.json (written last) exists only for a finished run and
lists the sizes on disk, demo.rrd passes `rerun rrd verify`, and no temporary file survives the
next run in the same folder.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from tracker.io.fileio import work_folder

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "kitti-0001" / "detections.json.gz"
TRACK = ["track", str(SAMPLE), "--config", "kitti_offline", "--kitti-results"]


def _mctrack(args: list[str]) -> list[str]:
    return [sys.executable, "-m", "app.cli", *args]


def _timed_run(args: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(_mctrack(args), check=True, capture_output=True, cwd=ROOT)
    return time.perf_counter() - start


def _kill_after(args: list[str], secs: float) -> bool:
    """Start, SIGKILL after ``secs``; True when the kill landed before the run finished."""
    proc = subprocess.Popen(
        _mctrack(args), cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        proc.wait(timeout=secs)
        return False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        return True


def _inspect(out: Path) -> dict[str, object]:
    from tracker.io.baseversion import read_baseversion

    files = sorted(p for p in out.rglob("*") if p.is_file())
    temps = [p for p in files if p.name.startswith(".")]
    state: dict[str, object] = {"files": len(files) - len(temps), "temps": len(temps)}
    tracks = out / "tracks.json"
    if tracks.exists():
        read_baseversion(tracks)  # raises if truncated
        state["tracks.json"] = "complete"
    summary = out / "summary.json"
    if summary.exists():
        listed = json.loads(summary.read_text())["outputs"]
        ok = all((out / o["path"]).stat().st_size == o["bytes"] for o in listed)
        state["summary.json"] = "lists sizes on disk" if ok else "STALE"
    for txt in (out / "data").glob("*.txt") if (out / "data").is_dir() else []:
        lines = txt.read_text().splitlines()
        if any(len(ln.split()) != 18 for ln in lines):
            state[txt.name] = "TRUNCATED"
    for rrd in out.glob("*.rrd"):
        verify = subprocess.run(["rerun", "rrd", "verify", str(rrd)], capture_output=True)
        state[rrd.name] = "verifies" if verify.returncode == 0 else "FAILS verify"
    return state


@contextlib.contextmanager
def trials_folder(out: Path | None) -> Iterator[Path]:
    """Where one run of the trials writes: without ``out`` a work folder, removed at the end;
    else a new folder under ``out`` (made exclusively, named with the pid: a second run never
    shares it), kept. Nothing else in ``out`` is touched (it was removed whole)."""
    if out is None:
        with work_folder("kill") as folder:
            yield folder
        return
    out.mkdir(parents=True, exist_ok=True)
    stem = f"kill-{os.getpid()}-{time.strftime('%Y%m%d-%H%M%S')}"
    for n in itertools.count(1):
        folder = out / (stem if n == 1 else f"{stem}-{n}")
        try:
            folder.mkdir()  # (exclusive: an existing folder is never taken over)
            break
        except FileExistsError:
            continue
    print(f"trials in {folder}")
    yield folder


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--trials", type=int, default=8, help="kills per command")
    parser.add_argument(
        "--out", type=Path, default=None, help="keep the trials in a new folder under DIR"
    )
    args = parser.parse_args(argv)
    with trials_folder(args.out) as folder:
        return _trials(folder, args.trials)


def _trials(root: Path, trials: int) -> int:
    problems = 0
    for name, cmd in (("track", TRACK), ("demo", ["demo"])):
        full = _timed_run([*cmd, "--out", str(root / f"{name}-timing")])
        print(f"## mctrack {name}: an uninterrupted run takes {full:.1f} s")
        for k in range(trials):
            out = root / f"{name}-{k}"
            secs = full * (k + 0.5) / trials
            killed = _kill_after([*cmd, "--out", str(out)], secs)
            out.mkdir(parents=True, exist_ok=True)
            after_kill = _inspect(out)
            _timed_run([*cmd, "--out", str(out)])  # the next run in the same folder
            after_rerun = _inspect(out)
            bad = any(str(v) in {"STALE", "TRUNCATED", "FAILS verify"} for v in after_kill.values())
            bad |= after_rerun["temps"] != 0 or (
                "summary.json" not in after_rerun and name == "track"
            )
            problems += bad
            print(
                f"kill at {secs:.1f} s ({'killed' if killed else 'finished first'}): "
                f"after kill {after_kill}; after the next run {after_rerun}"
                + ("  <-- PROBLEM" if bad else "")
            )
    print(f"problems: {problems}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
