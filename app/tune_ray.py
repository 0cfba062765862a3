"""`mctrack tune --ray [ADDRESS]`: the tuning searches as Ray Tune experiments.

Same search as the local path (app/tune.py), not a copy of it: the same Optuna TPE sampler and
seed (:func:`app.tune.make_sampler`, wrapped by Ray's ``OptunaSearch``), the same search space
(:func:`app.tune.suggest`, a define-by-run function), the same first trial (the base config's
values, in the search on all sequences only), and the same objective
(:class:`app.tune.Objective`). What differs is where trials run: one Ray Tune trial per Optuna
trial, up to ``--max-concurrent`` at once, each on one CPU and tracking its detectors and
sequences one after another. With ``--max-concurrent 1`` the proposals are the local path's,
trial for trial; with more, TPE proposes while earlier trials are still running, so the trials
depend on which finish first.

Resume: each search is one Ray Tune experiment, ``OUT/ray_tune/<search>`` (fold0, fold1, ...,
all). Run the same command again after an interruption and a finished search is read back, an
unfinished one continues from its saved state (``Tuner.restore``): finished trials are kept and
the trials that were running, or had failed, start again under their own ids. Each save is also
packed whole into ``OUT/ray_tune/<search>.resume.zip`` (:class:`_Snapshot`): Ray Tune's own copy
of it can be cut short by a kill. ``OUT/ray_tune/run.json`` holds the options the run was
started with; a different command line on the same ``--out`` is refused. Ray Tune saves its state
with pickle, so resume only from a folder this command wrote.

This module imports Ray; app/tune.py imports it only for ``--ray``.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import io
import json
import os
import shutil
import signal
import sys
import threading
import zipfile
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import ray
from ray import tune
from ray.exceptions import RayActorError
from ray.tune.search import ConcurrencyLimiter
from ray.tune.search.optuna import OptunaSearch

from app import scenes
from app.tune import (
    Objective,
    Search,
    Trials,
    make_sampler,
    noise_seed_value,
    objective_value,
    parse_search,
    suggest,
)
from tracker.config import config_for_mode, config_to_dict, load_config
from tracker.errors import InputError
from tracker.frame import Frame
from tracker.io.fileio import make_work_folder, write_bytes_atomic, write_text_atomic

METRIC = "hota"  # the objective's name in a trial's result
# The Optuna trial number, added to each trial's config: a restored ResultGrid does not keep the
# order of proposal, and the best trial is the first of the best (as Optuna's own rule).
NUMBER = "optuna_trial"
STATE_DIR = "ray_tune"  # under --out: one Ray Tune experiment per search, and run.json
# run.json keys written only when their option is given: a resume without it is a change too
OPTIONAL_OPTIONS = frozenset({"search"})
MAX_FAILURES = 3  # re-runs of a trial whose worker process died
# By default Ray Tune saves an experiment's state no more often than every 10 s; a hard kill
# then loses the trials finished since. Every second costs one small state write per second.
CHECKPOINT_SECONDS = "1"

# the driver's progress bar; a module global because Ray Tune pickles its callbacks
_PROGRESS: list[Callable[[int], Any]] = []


# Ray Tune's own state files at the top of an experiment folder (trials, searcher, search
# generator, callbacks), as its TuneController and SearchGenerator name them
# (Ray writes its callbacks' states after asking them, so those are not part of a whole save;
# none of ours keeps state)
RAY_STATE_FILES = (
    "experiment_state-*.json",
    "search_gen_state-*.json",
    "searcher-state-*.pkl",
)
SNAPSHOT_SUFFIX = ".resume.zip"  # OUT/ray_tune/<search>.resume.zip, beside the experiment


class _Snapshot(tune.Callback):
    """Keeps ``OUT/ray_tune/<search>.resume.zip``: Ray Tune's state as of its last save, whole.

    Ray Tune writes its state files to a staging folder, then copies the folder to
    ``OUT/ray_tune/<search>`` in the background, file by file and in parallel. A hard kill
    during that copy leaves the trials of one save beside the searcher of an earlier one, and
    the restored run fails (the searcher does not know a trial) or runs trials again. Ray Tune
    asks its callbacks for their state right after writing all its own files of a save, so
    that is when this packs them into one file, replaced atomically; a resume puts them back
    first (:func:`restore_snapshot`).
    """

    def __init__(self) -> None:
        self._storage: Any = None

    def on_step_begin(self, iteration: int, trials: list, **info: Any) -> None:
        if trials:
            self._storage = trials[0].storage

    def on_trial_start(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        self._storage = trial.storage

    def get_state(self) -> dict | None:
        if self._storage is not None:
            experiment = Path(self._storage.experiment_fs_path)
            snapshot = experiment.with_name(experiment.name + SNAPSHOT_SUFFIX)
            try:
                write_snapshot(Path(self._storage.experiment_driver_staging_path), snapshot)
            except OSError as exc:  # the previous snapshot stays whole; a resume starts there
                print(f"mctrack tune: could not write {snapshot} ({exc})", file=sys.stderr)
        return None  # stateless: Ray Tune writes no file for it


def _is_state_name(name: str) -> bool:
    """A name Ray Tune gives a state file (and no path: the snapshot is input on resume)."""
    return "/" not in name and any(Path(name).match(pattern) for pattern in RAY_STATE_FILES)


def _is_state_file(path: Path) -> bool:
    return path.is_file() and _is_state_name(path.name)


def write_snapshot(staging: Path, snapshot: Path) -> None:
    """Packs Ray Tune's state files in ``staging`` into ``snapshot`` (complete or unchanged)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in sorted(staging.iterdir()):
            if _is_state_file(path):
                archive.writestr(path.name, path.read_bytes())
    write_bytes_atomic(snapshot, buffer.getvalue())


def _trial_folders(experiment_state: bytes) -> set[str]:
    """The trial folders (``trial_<id>``, :func:`_trial_dirname`) an experiment state lists."""
    return {
        f"trial_{json.loads(t[0])['trial_id']}" for t in json.loads(experiment_state)["trial_data"]
    }


def restore_snapshot(experiment: Path, snapshot: Path) -> None:
    """Puts the state files of ``snapshot`` back in ``experiment``, in place of whatever a kill
    left there, and removes the folders of trials that state does not hold (they are proposed
    again)."""
    try:
        with zipfile.ZipFile(snapshot) as archive:
            files = {name: archive.read(name) for name in archive.namelist()}
        names = sorted(n for n in files if Path(n).match(RAY_STATE_FILES[0]))
        if not names or any(not _is_state_name(n) for n in files):
            raise ValueError("not Ray Tune's state files")
        kept = _trial_folders(files[names[-1]])  # Ray Tune restores from the newest
    except (
        OSError, EOFError, ValueError, KeyError, TypeError, IndexError, zipfile.BadZipFile,
        zlib.error,
    ) as exc:  # fmt: skip
        raise InputError(
            f"{snapshot}: not a saved Ray Tune search ({exc}); pass another --out"
        ) from None
    for path in experiment.iterdir():
        if _is_state_file(path):
            path.unlink()
    for name, data in files.items():
        write_bytes_atomic(experiment / name, data)
    for path in sorted(experiment.glob("trial_*")):
        if path.is_dir() and path.name not in kept:
            shutil.rmtree(path)


def prepare_resume(experiment: Path) -> str:
    """Before a search runs: puts back its last whole save (``"restored"``); leaves a folder
    without one that holds trials to Ray Tune's own restore (``"unsnapshotted"``: written by a
    version before the snapshots); removes one that holds none (``"started over"``: stopped
    before a save after a trial started); else ``"new"``."""
    snapshot = experiment.with_name(experiment.name + SNAPSHOT_SUFFIX)
    if snapshot.is_file():
        experiment.mkdir(parents=True, exist_ok=True)
        restore_snapshot(experiment, snapshot)
        return "restored"
    if not experiment.exists():
        return "new"
    if (experiment / "tuner.pkl").is_file() and _holds_trials(experiment):
        return "unsnapshotted"
    shutil.rmtree(experiment)
    return "started over"


def _holds_trials(experiment: Path) -> bool:
    """Whether Ray Tune's newest experiment state in ``experiment`` lists a trial."""
    states = sorted(experiment.glob(RAY_STATE_FILES[0]))
    try:
        return bool(states and _trial_folders(states[-1].read_bytes()))
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return False


class _Progress(tune.Callback):
    """Moves the driver's progress bar by one per finished trial."""

    def on_trial_complete(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        if _PROGRESS:
            _PROGRESS[0](1)


def _suggest_numbered(trial: Any, space: dict[str, tuple[str, float, float]]) -> dict[str, Any]:
    """:func:`app.tune.suggest` (the one search space), plus the trial's number."""
    return {**suggest(trial, space), NUMBER: trial.number}


def _trial(
    config: dict[str, Any],
    *,
    objective: Objective,
    key: str,
    seqs: list[str],
    frames: dict[tuple[str, str], dict[str, list[Frame]]],
) -> None:
    """One Ray Tune trial: the objective of one proposal, in a Ray worker process."""
    from app import tune as local

    local._FRAMES.clear()  # a reused worker holds another search's frames
    for (det, level), by_seq in frames.items():
        local._FRAMES[(det, key, level)] = by_seq
    work = make_work_folder("trial")
    try:
        params = {k: v for k, v in config.items() if k != NUMBER}
        metrics = objective.metrics(key, seqs, params, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    each = {f"{METRIC}_{det}_{level}": m["HOTA"] for (det, level), m in metrics.items()}
    tune.report({METRIC: objective_value(metrics), **each})


def _ctrl_c(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def _fit(tuner: Any) -> tuple[Any, bool]:
    """``tuner.fit()``, and whether Ctrl-C stopped it.

    Ray Tune catches Ctrl-C, saves the experiment and returns normally: when the search was
    nearly done its results can even look complete, and the next search would start. Its
    handler puts back the one it found, so finding ours in place afterwards means it ran.
    """
    if threading.current_thread() is not threading.main_thread():
        return tuner.fit(), False  # no signal handlers outside the main thread
    previous = signal.signal(signal.SIGINT, _ctrl_c)
    try:
        grid = tuner.fit()
    finally:
        ran = signal.getsignal(signal.SIGINT) is _ctrl_c and not int(
            os.environ.get("TUNE_DISABLE_SIGINT_HANDLER", "0")  # Ray left ours alone
        )
        signal.signal(signal.SIGINT, previous)  # not Ray's handler of a finished run
    return grid, ran


def _trial_dirname(trial: Any) -> str:
    return f"trial_{trial.trial_id}"  # not Ray's default, which lists every setting


def fitted_profile_option(detectors: str) -> dict[str, list[str]]:
    """The detectors whose in-sample search calibrates with a profile fitted on the tuning
    sequences (no shipped profile; before December 2026 it used their uncalibrated scores), as
    a run.json option: a search begun the old way is then not resumed the new way. Empty when
    every detector has a shipped profile, so the folders of such runs still resume."""
    from tracker.calibration import find_profile

    names = [d.strip() for d in detectors.split(",") if d.strip()]
    fitted = [d for d in names if find_profile(d) is None]
    return {"in_sample_profile_fitted": fitted} if fitted else {}


class RaySearch:
    """Runs each search of a tune as a Ray Tune experiment under ``OUT/ray_tune``."""

    def __init__(
        self,
        address: str,
        num_cpus: int,
        max_concurrent: int | None,
        trials: int,
        state: Path,
        options: dict[str, Any],
    ) -> None:
        self.address = address
        self.num_cpus = num_cpus
        self.max_concurrent = max_concurrent
        self.trials = trials
        self.state = state.resolve()  # Ray Tune wants an absolute storage path
        self.options = options
        self.started = False
        self.resumed: list[str] = []
        self.stopped = ""

    @classmethod
    def from_args(
        cls, args: argparse.Namespace, out: Path, root: Path, seqs: Sequence[str]
    ) -> RaySearch:
        """Checks ``OUT/ray_tune/run.json`` against this command line (a different one is
        refused) and writes it for a new run."""
        config_name = str(config_for_mode(args.config, args.mode))
        config = config_to_dict(load_config(config_name, overrides={"mode": args.mode}))
        options = {
            "class": args.cls,
            "detectors": args.detectors,
            "config": config_name,
            "config_sha256": hashlib.sha256(
                json.dumps(config, sort_keys=True).encode()
            ).hexdigest(),
            "mode": args.mode,
            "trials": args.trials,
            "folds": args.folds,
            "seed": args.seed,
            "noise": args.noise,
            "noise_seed": noise_seed_value(args.noise_seed),
            "seqs": list(seqs),
            "max_concurrent": args.max_concurrent,
            "kitti_root": str(root.resolve()),
        }
        options |= fitted_profile_option(args.detectors)
        if args.search:  # (only when given: folders of runs without it still resume)
            options["search"] = sorted(
                f"{key}={kind}:{low:g}:{high:g}"
                for key, (kind, low, high) in map(parse_search, args.search)
            )
        state = out / STATE_DIR
        check_options(state / "run.json", options)
        return cls(args.ray, args.workers, args.max_concurrent, args.trials, state, options)

    def start(
        self,
        objective: Objective,
        space: dict[str, tuple[str, float, float]],
        n_startup: int,
        frames: dict[tuple[str, str, str], dict[str, list[Frame]]],
        progress: Callable[[int], Any],
    ) -> Search:
        """Connects to Ray and returns the search function (key, sequences, seed) -> trials."""
        self.state.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.state / "run.json", [json.dumps(self.options, indent=2)])
        os.environ.setdefault("TUNE_GLOBAL_CHECKPOINT_S", CHECKPOINT_SECONDS)
        os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # our progress bar, not Tune's tables
        self.started = scenes.connect_ray(self.address, self.num_cpus)
        if self.max_concurrent is None:
            self.max_concurrent = max(1, int(ray.cluster_resources().get("CPU", 1)))
        _PROGRESS[:] = [progress]

        def search(
            key: str, seqs: Sequence[str], seed: int, start: dict[str, Any] | None
        ) -> Trials:
            trainable = tune.with_resources(
                tune.with_parameters(
                    _trial,
                    objective=objective,
                    key=key,
                    seqs=list(seqs),
                    frames={run: frames[(run[0], key, run[1])] for run in objective.runs},
                ),
                {"cpu": 1},
            )
            path = self.state / key
            how = prepare_resume(path)
            if how == "started over":
                print(
                    f"mctrack tune: search {key} was stopped before its first save after a trial "
                    "started; it starts over",
                    file=sys.stderr,
                )
            elif how == "unsnapshotted":
                print(
                    f"mctrack tune: search {key} was saved by an earlier version, without a whole "
                    f"snapshot; resuming from Ray Tune's own copy in {path}",
                    file=sys.stderr,
                )

            def restore() -> Any:
                # resume_errored: a failed trial runs again under its own id (restart_errored
                # gives it a new one, which Ray's OptunaSearch does not know: a KeyError)
                return tune.Tuner.restore(str(path), trainable=trainable, resume_errored=True)

            if tune.Tuner.can_restore(str(path)):
                self.resumed.append(key)
                tuner = restore()
            else:
                searcher = OptunaSearch(
                    space=functools.partial(_suggest_numbered, space=space),
                    metric=METRIC,
                    mode="max",
                    points_to_evaluate=None if start is None else [start],
                    sampler=make_sampler(seed, n_startup),
                )
                tuner = tune.Tuner(
                    trainable,
                    tune_config=tune.TuneConfig(
                        search_alg=ConcurrencyLimiter(searcher, self.max_concurrent),
                        num_samples=self.trials,
                        # a new worker process per trial would reload the tracker and its
                        # compiled kernels each time (seconds); a reused one holds them
                        reuse_actors=True,
                        trial_dirname_creator=_trial_dirname,
                    ),
                    run_config=tune.RunConfig(
                        name=key,
                        storage_path=str(self.state),
                        verbose=0,
                        failure_config=tune.FailureConfig(max_failures=MAX_FAILURES),
                        callbacks=[_Progress(), _Snapshot()],
                    ),
                )
            grid, ctrl_c = _fit(tuner)
            for _ in range(MAX_FAILURES):
                # Ray Tune re-runs a trial whose worker dies while it runs, but fails one whose
                # (reused) worker dies while being handed the trial (still PENDING then). Run
                # those again, as a resume does.
                died = sum(isinstance(r.error, RayActorError) for r in grid)
                if ctrl_c or not died:
                    break
                print(
                    f"mctrack tune: {died} trial(s) of search {key} failed as their worker "
                    "process died; running them again",
                    file=sys.stderr,
                )
                prepare_resume(path)
                grid, ctrl_c = _fit(restore())
            trials = self._trials(grid, key)
            if ctrl_c or len(trials) < self.trials:
                self.stopped = f"search {key} stopped after {len(trials)} of {self.trials} trials"
                raise KeyboardInterrupt
            return trials

        return search

    def _trials(self, grid: Any, key: str) -> Trials:
        """(settings, objective) per trial, in the order the searcher proposed them."""
        numbered: list[tuple[int, dict[str, Any], float]] = []
        for result in grid:
            if result.error is not None:
                raise RuntimeError(
                    f"a Ray Tune trial of search {key} failed "
                    f"({type(result.error).__name__}: {result.error}); "
                    f"its log is under {self.state / key}"
                )
            if result.metrics and METRIC in result.metrics:
                params = {k: v for k, v in result.config.items() if k != NUMBER}
                numbered.append((result.config[NUMBER], params, float(result.metrics[METRIC])))
        trials: Trials = [(params, value) for _, params, value in sorted(numbered)]
        return trials

    def interrupted(self) -> None:
        """Says how to resume (the command was stopped by Ctrl-C)."""
        print(
            f"mctrack tune: {self.stopped or 'stopped'}; the finished trials are saved: run the "
            f"same command again to resume (state: {self.state})",
            file=sys.stderr,
        )

    def describe(self) -> dict[str, Any]:
        return {
            "address": self.address,
            "max_concurrent": self.max_concurrent,
            "cluster_cpus": ray.cluster_resources().get("CPU"),
            "state": str(self.state),
            "resumed_searches": self.resumed,
        }

    def stop(self) -> None:
        _PROGRESS.clear()
        if self.started:
            ray.shutdown()
            self.started = False


def check_options(path: Path, options: dict[str, Any]) -> None:
    """Refuse to resume a run that was started with other options."""
    if not path.is_file():
        return
    try:
        saved = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: unreadable ({exc}); pass another --out") from None
    if not isinstance(saved, dict):
        raise InputError(f"{path}: not a tune run's options; pass another --out")
    changed = [
        f"{k} {saved.get(k)!r} -> {options.get(k)!r}"
        for k in sorted(options.keys() | (saved.keys() & OPTIONAL_OPTIONS))
        if saved.get(k) != options.get(k)
    ]
    if changed:
        raise InputError(
            f"{path.parent.parent}: holds a --ray tune run started with other options "
            f"({'; '.join(changed)}); to resume it run the same command, else pass another --out"
        )
