"""Scene-parallel wall times (docs/scale.md): `mctrack kitti` on the 21 KITTI training
sequences and a synthetic fleet of short scenes, sequential, with local worker processes and
on a local Ray instance; Ray's start-up and per-scene overhead; the per-scene tracker cost of
nuScenes- and Waymo-sized synthetic scenes (the inputs of the projection in docs/scale.md).

    python bench/bench_parallel.py [--kitti-root DIR] [--fleet 1000] [--json out.json]

Every case checks that its result files are byte-identical to the sequential run's.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app import scenes
from app.cli import main as mctrack
from app.kitti import DEFAULT_KITTI_ROOT, run_kitti
from tracker.config import load_config
from tracker.io.baseversion import read_baseversion, write_baseversion
from tracker.io.fileio import work_folder
from tracker.io.synthetic import synthetic_scene
from tracker.pipeline import run_scene

KITTI_SEQS = [f"{i:04d}" for i in range(21)]


def _digest(out: Path) -> str:
    """One hash of every result file (not the summary, which holds timings)."""
    h = hashlib.sha256()
    for path in sorted(out.rglob("*")):
        if path.is_file() and path.name != "summary.json":
            h.update(str(path.relative_to(out)).encode() + path.read_bytes())
    return h.hexdigest()


def _timed(fn: Callable[[], Any]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def _best(fn: Callable[[], Any], repeat: int) -> float:
    return min(_timed(fn) for _ in range(repeat))


def _with_ray(num_cpus: int, fn: Callable[[], float]) -> tuple[float, float]:
    """(seconds to start a local Ray instance, ``fn()`` run on it)."""
    import ray

    start = time.perf_counter()
    ray.init(
        address="local",
        num_cpus=num_cpus,
        include_dashboard=False,
        _node_ip_address="127.0.0.1",
        log_to_driver=False,
    )
    init_secs = time.perf_counter() - start
    try:
        return init_secs, fn()
    finally:
        ray.shutdown()


def _cases(has_ray: bool) -> list[tuple[str, scenes.Parallelism, int]]:
    cases = [
        ("sequential", scenes.Parallelism(), 0),
        ("2 worker processes", scenes.Parallelism(workers=2), 0),
    ]
    if has_ray:
        cases += [
            ("Ray, 1 CPU", scenes.Parallelism(ray="auto"), 1),
            ("Ray, 2 CPUs", scenes.Parallelism(ray="auto"), 2),
        ]
    return cases


def bench_kitti(root: Path, work: Path, has_ray: bool, repeat: int) -> list[dict[str, Any]]:
    rows = []
    reference = None
    for name, parallel, ray_cpus in _cases(has_ray):
        out = work / f"kitti-{len(rows)}"

        def job(out: Path = out, parallel: scenes.Parallelism = parallel) -> dict[str, Any]:
            return run_kitti(
                kitti_root=root,
                seqs=KITTI_SEQS,
                classes=["car", "pedestrian", "cyclist"],
                out=out,
                quiet=True,
                parallel=parallel,
            )

        init = None
        if ray_cpus:
            init, wall = _with_ray(ray_cpus, lambda job=job: _best(job, repeat))
        else:
            wall = _best(job, repeat)
        summary = json.loads((out / "summary.json").read_text())
        digest = _digest(out)
        reference = reference or digest
        rows.append(
            {
                "case": name,
                "wall_secs": round(wall, 2),
                "ray_init_secs": None if init is None else round(init, 2),
                "tracker_secs": summary["tracker_seconds"],
                "convert_secs": summary["convert_seconds"],
                "write_secs": summary["write_seconds"],
                "task_secs": summary["parallel"]["task_seconds"],
                "task_cpu_secs": summary["parallel"]["task_cpu_seconds"],
                "frames": summary["frames"],
                "identical": digest == reference,
            }
        )
        print(rows[-1], file=sys.stderr)
    return rows


def bench_kitti_eval(root: Path, work: Path) -> dict[str, Any]:
    """The evaluation's own time (it runs once, after the scenes): the 11 labelled sequences."""
    from tracker.eval.kitti import evaluate_kitti

    out = work / "kitti-0"
    val = [s for s in KITTI_SEQS if (root / "training" / "label_02" / f"{s}.txt").is_file()]
    lengths = {
        s: sum(1 for _ in open(root / "training" / "pose_orbslam3" / f"{s}.txt")) for s in val
    }
    secs = _timed(
        lambda: evaluate_kitti(
            label_dir=root / "training" / "label_02",
            result_dir=out / "data",
            seq_lengths=lengths,
            classes=["car", "pedestrian", "cyclist"],
        )
    )
    return {"sequences": len(val), "frames": sum(lengths.values()), "eval_secs": round(secs, 2)}


def bench_fleet(n: int, work: Path, has_ray: bool, repeat: int) -> list[dict[str, Any]]:
    """``mctrack track`` on one file of ``n`` short synthetic scenes (20 frames, 10 objects)."""
    fleet = {}
    for i in range(n):
        dets, _ = synthetic_scene(num_objects=10, num_frames=20, seed=i, scene=f"s{i:05d}")
        fleet[f"s{i:05d}"] = dets
    path = work / "fleet.json"
    write_baseversion(path, fleet)
    read_secs = _timed(lambda: read_baseversion(path))  # the driver's serial part
    print({"read_fleet_secs": round(read_secs, 2)}, file=sys.stderr)
    rows: list[dict[str, Any]] = []
    reference = None
    for name, parallel, ray_cpus in _cases(has_ray):
        out = work / f"fleet-{len(rows)}"
        argv = ["track", str(path), "--config", "kitti", "--out", str(out)]
        if parallel.workers > 1:
            argv += ["--workers", str(parallel.workers)]
        if ray_cpus:
            argv += ["--ray", "auto"]

        def job(argv: list[str] = argv) -> None:
            assert mctrack(argv) == 0

        init = None
        if ray_cpus:
            init, wall = _with_ray(ray_cpus, lambda job=job: _best(job, repeat))
        else:
            wall = _best(job, repeat)
        digest = _digest(out)
        reference = reference or digest
        rows.append(
            {
                "case": name,
                "scenes": n,
                "wall_secs": round(wall, 2),
                "driver_read_secs": round(read_secs, 2),
                "ray_init_secs": None if init is None else round(init, 2),
                "identical": digest == reference,
            }
        )
        print(rows[-1], file=sys.stderr)
    return rows


@dataclass(frozen=True, slots=True)
class EmptyJob:
    """A task that does nothing: what remains of its wall time is the scheduling overhead."""

    def process(self, index: int, scene: str, data: Any) -> scenes.SceneRecord:
        return scenes.SceneRecord(index, scene)


def bench_overhead(n: int, has_ray: bool) -> list[dict[str, Any]]:
    """Seconds per scene spent on scheduling alone: ``n`` empty tasks (Ray: on a running
    instance, its start-up not counted; the pool: its start-up counted)."""
    names = [f"s{i:05d}" for i in range(n)]
    rows = []
    for name, parallel, ray_cpus in _cases(has_ray):

        def job(parallel: scenes.Parallelism = parallel) -> None:
            scenes.run_scenes(EmptyJob(), names, parallel=parallel, quiet=True)

        wall = _with_ray(ray_cpus, lambda job=job: _timed(job))[1] if ray_cpus else _timed(job)
        rows.append({"case": name, "tasks": n, "ms_per_scene": round(1000 * wall / n, 3)})
        print(rows[-1], file=sys.stderr)
    return rows


def bench_scene_cost() -> list[dict[str, Any]]:
    """Tracker seconds (wall and CPU) of one synthetic scene sized like a nuScenes scene (20 s
    of 2 Hz keyframes, 60 objects) and a Waymo segment (20 s at 10 Hz, 100 objects); best of
    3. CPU seconds do not count the time this process waited for a core on a busy host."""
    rows = []
    for name, config, frames, objects, rate_hz in (
        ("nuScenes-sized", "nuscenes", 40, 60, 2.0),
        ("Waymo-sized", "waymo", 200, 100, 10.0),
    ):
        dets, _ = synthetic_scene(
            num_objects=objects, num_frames=frames, frame_rate_hz=rate_hz, seed=7
        )
        cfg = load_config(config)
        run_scene(dets, cfg)  # warm-up (compiled kernels)
        walls, cpus = [], []
        for _ in range(3):
            cpu_start = time.process_time()
            walls.append(run_scene(dets, cfg).tracker_seconds)
            cpus.append(time.process_time() - cpu_start)
        rows.append(
            {
                "scene": name,
                "frames": frames,
                "objects": objects,
                "secs": round(min(walls), 3),
                "cpu_secs": round(min(cpus), 3),
            }
        )
        print(rows[-1], file=sys.stderr)
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kitti-root", default=DEFAULT_KITTI_ROOT)
    parser.add_argument("--fleet", type=int, default=1000, help="scenes in the synthetic fleet")
    parser.add_argument("--json", default=None, help="also write the results here")
    parser.add_argument("--repeat", type=int, default=1, help="runs per case; the best is kept")
    parser.add_argument(
        "--parts", default="cost,overhead,kitti,fleet", help="which figures (comma-separated)"
    )
    args = parser.parse_args()
    try:
        import ray  # noqa: F401

        has_ray = True
    except ImportError:
        has_ray = False
        print("ray not installed: the Ray cases are skipped", file=sys.stderr)
    root = Path(args.kitti_root)
    results: dict[str, Any] = {"cpus": os.cpu_count(), "load_avg_at_start": os.getloadavg()}
    with work_folder("parallel") as tmp:
        work = Path(tmp)
        parts = set(args.parts.split(","))
        if "cost" in parts:
            results["scene_cost"] = bench_scene_cost()
        if "kitti" in parts and (root / "training" / "calib").is_dir():
            results["kitti21"] = bench_kitti(root, work, has_ray, args.repeat)
            results["kitti_eval"] = bench_kitti_eval(root, work)
        if "overhead" in parts:
            results["overhead"] = bench_overhead(args.fleet, has_ray)
        if "fleet" in parts:
            results["fleet"] = bench_fleet(args.fleet, work, has_ray, args.repeat)
    results["load_avg_at_end"] = os.getloadavg()
    text = json.dumps(results, indent=2)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
