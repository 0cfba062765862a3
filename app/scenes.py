"""Scene-parallel runs: one scene is one task, run here, in a local process pool
(``--workers N``) or as Ray tasks (``--ray [ADDRESS]``).

A task gets its scene's input by path (the job loads it) or as frames (a pickled argument, or a
Ray object reference), runs a fresh tracker, writes the scene's output files atomically and
returns a small :class:`SceneRecord`: the tracker state never leaves the task. Records are put
back in input order, so files assembled from them are byte-identical to a sequential run, and
the evaluation runs once, in the caller, at the end.

Faults: a scene whose input is bad (:class:`~tracker.errors.InputError`, a missing file) fails
alone, with its error in its record. A task whose worker process dies is run again (Ray's task
retries; for the local pool, a new pool for the scenes not done), at most :data:`MAX_RETRIES`
times, then recorded as failed. Outputs are written to a temporary name and renamed, so a task
that dies or is retried never leaves half a file.

Ray is optional (``pip install -e ".[ray]"``) and imported only by ``--ray``.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import multiprocessing
import signal
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

from tqdm import tqdm

from app.common import ctrl_c_deferred
from tracker.errors import InputError

log = logging.getLogger(__name__)

MAX_RETRIES = 3  # re-runs of a scene whose worker process died
STOP_SECONDS = 10.0  # a stopped worker not gone by then (SIGTERM) is killed (SIGKILL)
PARTS_DIR = ".scenes"  # per-scene parts of the combined output files, removed after assembly
LOCAL = "local"  # --ray without an address: start a local Ray instance


@dataclass(frozen=True, slots=True)
class SceneRecord:
    """What a scene task sends back: counts and timings, or the error that stopped it."""

    index: int
    scene: str
    frames: int = 0
    tracker_seconds: float = 0.0
    task_seconds: float = 0.0  # wall time of the whole task
    cpu_seconds: float = 0.0  # CPU time of the task's process: its work, whatever the load
    error: str | None = None
    info: dict[str, Any] = field(default_factory=dict)  # small per-job counts
    kept: Any = None  # data the caller asked to keep (the motion metrics need the outputs)


class SceneJob(Protocol):
    """Processes one scene: load it (when ``data`` is None) or take its input from ``data``
    (e.g. its frames), track it, write its files."""

    def process(self, index: int, scene: str, data: Any) -> SceneRecord: ...


@dataclass(frozen=True, slots=True)
class Parallelism:
    """How scenes run: ``workers`` processes here, or Ray tasks when ``ray`` is set.

    ``ray``: None (no Ray), :data:`LOCAL` (start a local instance), ``auto`` (join the running
    cluster) or a cluster address (``ray://host:10001``, ``host:6379``).
    """

    workers: int = 1
    ray: str | None = None

    @property
    def backend(self) -> str:
        if self.ray is not None:
            return "ray"
        return "processes" if self.workers > 1 else "sequential"


SEQUENTIAL = Parallelism()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--workers N`` and ``--ray [ADDRESS]`` (shared by every command that runs scenes)."""
    parser.add_argument(
        "--workers",
        type=_positive_int,
        default=1,
        help="scenes tracked in parallel on this machine (processes; with --ray: the CPUs of "
        "the local Ray instance)",
    )
    parser.add_argument(
        "--ray",
        nargs="?",
        const=LOCAL,
        default=None,
        metavar="ADDRESS",
        help="run scenes as Ray tasks: no ADDRESS starts a local instance, 'auto' joins the "
        "running cluster (needs the extra: pip install -e '.[ray]'); docs/scale.md",
    )


def from_args(args: argparse.Namespace) -> Parallelism:
    return Parallelism(workers=args.workers, ray=args.ray)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def part_path(out: Path, index: int, suffix: str) -> Path:
    """Where task ``index`` writes its part of a combined file (named by index, never by the
    scene name, which comes from the input)."""
    return out / PARTS_DIR / f"{index:06d}.{suffix}"


def run_task(job: SceneJob, index: int, scene: str, data: Any = None) -> SceneRecord:
    """One scene task; bad input becomes an error record, so the scene fails alone."""
    start, cpu_start = time.perf_counter(), time.process_time()
    try:
        record = job.process(index, scene, data)
    except (InputError, OSError) as exc:
        log.debug("scene %s failed", scene, exc_info=True)
        record = SceneRecord(index, scene, error=str(exc))
    return replace(
        record,
        task_seconds=time.perf_counter() - start,
        cpu_seconds=time.process_time() - cpu_start,
    )


def run_scenes(
    job: SceneJob,
    scenes: Sequence[str],
    *,
    inputs: Mapping[str, Any] | None = None,
    parallel: Parallelism = SEQUENTIAL,
    quiet: bool = False,
) -> list[SceneRecord]:
    """Run ``job`` on every scene; the records in the order of ``scenes``.

    ``inputs``: each scene's input (e.g. its frames) when the caller has already loaded it
    (sent to the task pickled, or as a Ray object reference); otherwise the job loads each
    scene by name, in its task. Progress (scenes done / total) goes to stderr.
    """
    items = [(i, s, inputs[s] if inputs is not None else None) for i, s in enumerate(scenes)]
    records: dict[int, SceneRecord] = {}
    with tqdm(total=len(items), unit="scene", disable=quiet or None, file=sys.stderr) as bar:

        def done(record: SceneRecord) -> None:
            records[record.index] = record
            bar.update(1)
            failed = sum(r.error is not None for r in records.values())
            if failed:
                bar.set_postfix(failed=failed)

        if parallel.ray is not None:
            _run_ray(job, items, parallel, done)
        elif parallel.workers > 1 and len(items) > 1:
            _run_pool(job, items, parallel.workers, done)
        else:
            for i, scene, scene_frames in items:
                done(run_task(job, i, scene, scene_frames))
    return [records[i] for i in range(len(items))]


Item = tuple[int, str, Any]


def _run_pool(
    job: SceneJob, items: list[Item], workers: int, done: Callable[[SceneRecord], None]
) -> None:
    """A local process pool; when a worker dies the pool breaks, and the scenes not done run
    again in a new pool."""
    # forkserver: workers fork from a clean server process, not from this one (which may hold
    # threads, e.g. the progress bar's); its preload pays the imports and the loading of the
    # compiled kernels once, not once per worker.
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["app.scenes", "app.pool_preload"])
    pending = {i: (i, s, f) for i, s, f in items}
    for attempt in range(MAX_RETRIES + 1):
        try:
            with ProcessPoolExecutor(
                max_workers=min(workers, len(pending)),
                mp_context=context,
                initializer=_leave_ctrl_c_to_the_parent,
            ) as pool:
                try:
                    futures = [pool.submit(run_task, job, *item) for item in pending.values()]
                    for future in as_completed(futures):
                        record = future.result()
                        del pending[record.index]
                        done(record)
                except BaseException:
                    _stop_workers(pool)
                    raise
            return
        except BrokenProcessPool:
            log.warning(
                "a worker process died (attempt %d); running %d scenes again",
                attempt + 1,
                len(pending),
            )
    for i, scene, _ in pending.values():
        done(SceneRecord(i, scene, error=f"worker process died {MAX_RETRIES + 1} times"))


def _leave_ctrl_c_to_the_parent() -> None:
    """A pool worker's start: Ctrl-C (SIGINT to the terminal's whole process group) is the
    parent's to handle, which stops the workers (:func:`_stop_workers`). A worker of its own
    would end its scene's task and take the next one, or print a traceback and die."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _stop_workers(pool: ProcessPoolExecutor) -> None:
    """Stop the pool's workers now, its scenes not begun cancelled, and wait until each worker
    has exited: after Ctrl-C or an error here, a worker still tracking would write its scene's
    files after the caller removed the stopped run's outputs. (The executor's own shutdown
    waits for every scene instead, and a second Ctrl-C during that wait left the workers
    writing, and the process hanging at its exit.)"""
    # (a private attribute, pid -> Process; without it, only the shutdown below)
    processes = list((getattr(pool, "_processes", None) or {}).values())
    with ctrl_c_deferred():  # (a second Ctrl-C: the workers are stopped all the same)
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            with contextlib.suppress(OSError, ValueError):  # (exited meanwhile)
                process.terminate()
        # one deadline for them all (stopping together), not STOP_SECONDS each in turn
        deadline = time.monotonic() + STOP_SECONDS
        for process in processes:
            with contextlib.suppress(ValueError):  # (closed)
                process.join(max(0.0, deadline - time.monotonic()))
        for process in processes:
            with contextlib.suppress(ValueError):
                if process.is_alive():
                    process.kill()
                    process.join()


def import_ray() -> Any:
    """The ``ray`` module, or the one-line error saying how to install the extra."""
    try:
        import ray
    except ImportError:
        raise InputError("--ray needs Ray, an optional extra: pip install -e '.[ray]'") from None
    return ray


def connect_ray(address: str, num_cpus: int | None) -> bool:
    """Connect to Ray: :data:`LOCAL` starts an instance on loopback with ``num_cpus`` (None: all
    of this machine's), anything else joins a cluster. True when this call started the
    connection (the caller then shuts it down); False when one was already open (a caller or
    a test connected first)."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    if address == LOCAL:
        ray.init(
            address="local",
            num_cpus=num_cpus,
            include_dashboard=False,
            _node_ip_address="127.0.0.1",  # a local instance listens on loopback only
        )
    else:
        ray.init(address=address)
    return True


def _run_ray(
    job: SceneJob, items: list[Item], parallel: Parallelism, done: Callable[[SceneRecord], None]
) -> None:
    """Ray tasks (one per scene, one CPU each, retried when their worker dies)."""
    ray = import_ray()
    started = connect_ray(parallel.ray or LOCAL, parallel.workers if parallel.workers > 1 else None)
    scene_of: dict[Any, tuple[int, str]] = {}  # (filled as submitted: a stop may come between)
    try:
        task = ray.remote(num_cpus=1, max_retries=MAX_RETRIES)(run_task)
        job_ref = ray.put(job)  # shipped once, not once per scene
        for i, s, f in items:
            scene_of[task.remote(job_ref, i, s, None if f is None else ray.put(f))] = (i, s)
        remaining = list(scene_of)
        while remaining:
            finished, remaining = ray.wait(remaining, num_returns=1)
            if remaining:  # and every other one already done: one call, not one per scene
                more, remaining = ray.wait(remaining, num_returns=len(remaining), timeout=0)
                finished += more
            for ref in finished:
                i, scene = scene_of[ref]
                try:
                    record = ray.get(ref)
                except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError) as exc:
                    record = SceneRecord(i, scene, error=f"Ray worker died: {type(exc).__name__}")
                done(record)
    except BaseException:
        _stop_ray_tasks(ray, scene_of)
        raise
    finally:
        if started:
            ray.shutdown()


def _stop_ray_tasks(ray: Any, scene_of: Mapping[Any, tuple[int, str]]) -> None:
    """Cancel the run's Ray tasks, a running one's worker process killed (``force``; the done
    ones are left as they are), and wait until each has ended: after Ctrl-C or an error here, a
    task still tracking would write its scene's files after the caller removed the stopped
    run's outputs. (Shutting Ray down ends a local instance's workers, not a joined cluster's,
    whose tasks ran on.) A scene whose task has not ended within :data:`STOP_SECONDS` (a
    node out of reach) is named in a warning."""
    refs = list(scene_of)
    if not refs:
        return
    with ctrl_c_deferred():  # (a second Ctrl-C: the tasks are stopped all the same)
        for ref in refs:
            with contextlib.suppress(Exception):  # (Ray's own failure: waited for below)
                ray.cancel(ref, force=True)
        try:
            _, running = ray.wait(
                refs, num_returns=len(refs), timeout=STOP_SECONDS, fetch_local=False
            )
        except Exception as exc:  # (the connection lost: the stop's own cause goes on)
            log.warning("could not wait for the Ray tasks to stop: %s", exc)
            return
    if running:
        log.warning(
            "Ray tasks of scenes %s did not stop within %.0f s: their files may still be written",
            ", ".join(scene_of[ref][1] for ref in running),
            STOP_SECONDS,
        )


def summary_fields(
    records: Sequence[SceneRecord], parallel: Parallelism, wall_seconds: float
) -> dict[str, Any]:
    """The run's parallel section of ``summary.json`` and its failed scenes."""
    return {
        "parallel": {
            "backend": parallel.backend,
            "workers": parallel.workers,
            "ray": parallel.ray,
            "wall_seconds": round(wall_seconds, 3),
            "task_seconds": round(sum(r.task_seconds for r in records), 3),
            "task_cpu_seconds": round(sum(r.cpu_seconds for r in records), 3),
        },
        "failed": {r.scene: r.error for r in records if r.error is not None},
    }


def tracked_head(failed: Mapping[str, str], names: Sequence[str], unit: str) -> str | None:
    """ "2 scenes", or "tracked 1 of 2 scenes" when some failed: the start of a run's speed
    line; None when every one failed (a speed of 0 frames says nothing)."""
    if len(failed) >= len(names):
        return None
    if failed:
        return f"tracked {len(names) - len(failed)} of {len(names)} {unit}s"
    return f"{len(names)} {unit}s"


def failed_run_line(
    failed: Mapping[str, str], names: Sequence[str], unit: str, scored_note: str
) -> str:
    """The line that says a run failed: on which of its ``names`` (``unit``: "sequence",
    "scene", "segment"; their errors follow on stderr, :func:`print_failures`), then
    ``scored_note`` (what became of the evaluation)."""
    tracked = len(names) - len(failed)
    which = f"{len(failed)} of {len(names)} {unit}s" if tracked else f"every {unit}"
    return f"run failed on {which} ({', '.join(failed)}: the error below); {scored_note}"


def print_failures(command: str, failed: Mapping[str, str]) -> int:
    """One line per failed scene on stderr; the exit status (2 when any failed)."""
    for scene, error in failed.items():
        print(f"mctrack {command}: error: scene {scene}: {error}", file=sys.stderr)
    return 2 if failed else 0


def write_tracks(out: Path, ok: Sequence[SceneRecord]) -> None:
    """``out/tracks.json`` from the finished scenes' parts (in their order), then the parts
    folder removed."""
    from tracker.io.writers import write_tracks_parts

    write_tracks_parts(
        out / "tracks.json", [(r.scene, part_path(out, r.index, "json")) for r in ok]
    )
    remove_parts(out)


def remove_parts(out: Path) -> None:
    parts = out / PARTS_DIR
    if parts.is_dir():
        for path in sorted(parts.iterdir()):
            path.unlink()
        parts.rmdir()


def track_or_record(
    frames: list[Any],
    gt_frames: list[Any] | None,
    config: Any,
    out: Path,
    scene: str,
    *,
    record: bool,
    info: dict[str, Any],
) -> Any:
    """Track one scene, or track it into ``out/recordings/<scene>.rrd``; the detection fates
    (and the recording's path) go to ``info``. Returns the run's result (``.outputs``)."""
    from tracker.eval.fates import FateCounter
    from tracker.io.fileio import path_in
    from tracker.pipeline import run_scene

    if record:
        from viz.record import record_scene

        path = path_in(out / "recordings", scene, ".rrd")  # names are input data
        result = record_scene(frames, config, gt_frames, path)
        info["recording"] = str(path)
        info["fates"] = result.fates
        return result
    fates = FateCounter(rv_gate_consumes=config.rv_reference)
    result = run_scene(frames, config, observer=fates)
    info["fates"] = fates.summary()
    return result
