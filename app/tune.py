"""`mctrack tune`: cross-validated search of one class's tracker settings over several detectors.

Honest tuning: the 11 labelled sequences are split into ``--folds`` groups (balanced by frames).
For each fold, Optuna's TPE sampler searches the settings on the other folds' sequences
(objective: HOTA averaged over the detectors) with score profiles fitted on those sequences
only; the best settings then track the held-out fold. The held-out result files of all folds
are evaluated together: that is the cross-validated figure. A last search on all sequences (with
the shipped profiles) gives the settings to ship and their in-sample figure.

Settings of one class never affect another (matching and lifecycle are per class), so each class
is tuned on its own: ``--class car --detectors pointrcnn,virconv,second_iou``.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import shutil
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.inputs import (
    add_kitti_root_argument,
    check_kitti_root,
    default_kitti_root,
    positive_int,
)
from tracker.config import load_config
from tracker.errors import InputError
from tracker.frame import Frame
from tracker.io.convert.kitti import VALIDATION_SEQS
from tracker.io.fileio import write_text_atomic

# (kind, low, high): the settings searched, per class, in calibrated units. "confirm_nines" n
# sets confirm_prob = 1 - 10^-n.
ONLINE_SPACE: dict[str, tuple[str, float, float]] = {
    "score_min": ("log", 0.01, 0.6),
    "birth_score_min": ("float", 0.2, 0.95),
    "lifecycle.confirm_nines": ("float", 1.0, 4.0),
    "lifecycle.min_hits": ("int", 2, 5),
    "lifecycle.max_misses_output": ("int", 0, 3),
    "lifecycle.max_misses": ("int", 5, 30),
    "bev.cost_max": ("float", 1.0, 2.0),
}
OFFLINE_SPACE: dict[str, tuple[str, float, float]] = {
    "score_min": ("log", 0.01, 0.6),
    "birth_score_min": ("float", 0.05, 0.9),
    "offline.track_score_min": ("float", -1.0, 5.0),
    "lifecycle.max_misses": ("int", 5, 30),
}

# shared with the forked evaluation workers (set before the pool starts; never pickled)
_FRAMES: dict[tuple[str, str], dict[str, list[Frame]]] = {}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_kitti_root_argument(parser)
    parser.add_argument(
        "--class",
        dest="cls",
        default="car",
        help="the class whose settings are searched (default: %(default)s)",
    )
    parser.add_argument(
        "--detectors",
        default="pointrcnn,virconv,second_iou",
        help="detectors the objective averages over (default: %(default)s)",
    )
    parser.add_argument(
        "--config", default="kitti", help="base config, name or TOML (default: %(default)s)"
    )
    parser.add_argument(
        "--mode",
        choices=["online", "offline"],
        default="online",
        help="tune the online config or <config>_offline (default: %(default)s)",
    )
    parser.add_argument("--trials", type=positive_int, default=20, help="trials per search")
    parser.add_argument("--folds", type=positive_int, default=3, help="sequence folds")
    parser.add_argument("--seed", type=int, default=0, help="sampler seed (default: 0)")
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=2,
        help="parallel evaluations (default: %(default)s)",
    )
    parser.add_argument(
        "--seqs",
        default=",".join(VALIDATION_SEQS),
        help="labelled sequences the folds are made of (default: the 11 validation sequences)",
    )
    parser.add_argument("--out", required=True, help="output folder (tune.json, best.toml)")
    parser.add_argument(
        "--ray",
        nargs="?",
        const="local",
        default=None,
        metavar="ADDRESS",
        help="run the trials on Ray Tune: no ADDRESS starts a local instance (--workers CPUs), "
        "'auto' joins the running cluster; the same --out again resumes (docs/scale.md)",
    )
    parser.add_argument(
        "--max-concurrent",
        type=positive_int,
        default=None,
        help="with --ray: trials at once (default: the cluster's CPUs)",
    )


def folds_by_frames(lengths: dict[str, int], k: int) -> list[list[str]]:
    """``k`` sequence groups of similar total length (longest first into the lightest group)."""
    groups: list[list[str]] = [[] for _ in range(k)]
    load = [0] * k
    for seq in sorted(lengths, key=lambda s: (-lengths[s], s)):
        i = load.index(min(load))
        groups[i].append(seq)
        load[i] += lengths[seq]
    return [sorted(g) for g in groups]


def settings_to_overrides(cls: str, params: dict[str, Any]) -> dict[str, Any]:
    """Searched values → a nested config override (``category.<cls>...``, ``offline...``)."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        if key == "lifecycle.confirm_nines":
            key, value = "lifecycle.confirm_prob", round(1.0 - 10.0 ** (-value), 6)
        node = (
            out
            if key.startswith("offline.")
            else out.setdefault("category", {}).setdefault(cls, {})
        )
        *parents, leaf = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out


#: Random trials before TPE models the results (both backends: one sampler, :func:`make_sampler`)
STARTUP_TRIALS = 8

Trials = list[tuple[dict[str, Any], float]]  # (settings, objective) per trial, in trial order


def make_sampler(seed: int) -> Any:
    """The search algorithm of every backend: Optuna's TPE, seeded."""
    import optuna

    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=STARTUP_TRIALS)


def best_trial(trials: Trials) -> tuple[dict[str, Any], float]:
    """The first trial with the highest objective (Optuna's own rule for ties)."""
    params, value = trials[0]
    for p, v in trials[1:]:
        if v > value:
            params, value = p, v
    return params, value


@dataclass(frozen=True, slots=True)
class Objective:
    """The searched objective: HOTA averaged over the detectors, each tracking ``seqs`` with a
    trial's settings. One definition for the local pool and the Ray Tune trials (app/tune_ray)."""

    detectors: tuple[str, ...]
    config_name: str
    base: dict[str, Any]
    cls: str
    label_dir: str

    def overrides(self, params: dict[str, Any]) -> dict[str, Any]:
        return {**self.base, **settings_to_overrides(self.cls, params)}  # disjoint keys

    def tasks(
        self, key: str, seqs: Sequence[str], params: dict[str, Any], work: Path, evaluate: bool
    ) -> list[tuple[Any, ...]]:
        """One :func:`_track_and_score` task per detector (frames from ``_FRAMES[(det, key)]``)."""
        return [((det, key), list(seqs), self.config_name, self.overrides(params),
                 str(work / det), self.label_dir, self.cls, evaluate)
                for det in self.detectors]  # fmt: skip

    def metrics(
        self,
        key: str,
        seqs: Sequence[str],
        params: dict[str, Any],
        work: Path,
        map_fn: Callable[[Callable, Iterable], Iterable] = map,
    ) -> dict[str, dict[str, Any]]:
        """Each detector's metrics on ``seqs`` (result files under ``work/<detector>``)."""
        results = map_fn(_track_and_score, self.tasks(key, seqs, params, work, True))
        return dict(zip(self.detectors, results, strict=True))

    @staticmethod
    def value(metrics: dict[str, dict[str, Any]]) -> float:
        return sum(m["HOTA"] for m in metrics.values()) / len(metrics)


def _track_and_score(task: tuple[Any, ...]) -> dict[str, Any]:
    """One detector: track ``seqs`` with the overrides, write KITTI files to ``result_dir``,
    and (when ``evaluate``) score them. Runs in a forked worker reading ``_FRAMES``."""
    from tracker.eval.kitti import evaluate_kitti
    from tracker.io.writers import write_kitti_sequence
    from tracker.pipeline import run_scene

    key, seqs, config_name, overrides, result_dir, label_dir, cls, evaluate = task
    config = load_config(config_name, overrides=overrides)
    frames = _FRAMES[key]
    result_dir = Path(result_dir)
    result_dir.mkdir(parents=True, exist_ok=True)
    for seq in seqs:
        result = run_scene(frames[seq], config)
        write_kitti_sequence(result_dir / f"{seq}.txt", result.outputs, frames[seq])
    if not evaluate:
        return {}
    return evaluate_kitti(
        label_dir=Path(label_dir),
        result_dir=result_dir,
        seq_lengths={s: len(frames[s]) for s in seqs},
        classes=[cls],
    )[cls]


def run(args: argparse.Namespace) -> int:
    import optuna
    from tqdm import tqdm

    from tracker.calibration import calibrate_frames, find_profile
    from tracker.eval.calibrate import fit_profile
    from tracker.io.convert.kitti import convert_kitti

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if args.ray is not None:
        from app.scenes import import_ray

        import_ray()  # the one-line error when the extra is not installed, before any work
    elif args.max_concurrent is not None:
        raise InputError("--max-concurrent needs --ray (local trials run one at a time)")
    root = args.kitti_root or default_kitti_root()
    detectors = [d.strip() for d in args.detectors.split(",") if d.strip()]
    seqs = [s.strip().zfill(4) for s in args.seqs.split(",") if s.strip()]
    if len(seqs) < args.folds:
        raise InputError(f"--folds {args.folds} needs at least as many --seqs (got {len(seqs)})")
    for detector in detectors:
        check_kitti_root(root, seqs=seqs, detector=detector)
    label_dir = root / "training" / "label_02"
    cls = args.cls
    space = OFFLINE_SPACE if args.mode == "offline" else ONLINE_SPACE
    config_name = f"{args.config}_offline" if args.mode == "offline" else args.config
    base = {"categories": [cls], "mode": args.mode}
    load_config(config_name, overrides=base)  # fail early on a bad config
    out = Path(args.out)
    ray_search = None
    if args.ray is not None:
        try:
            from app.tune_ray import RaySearch
        except ImportError:  # Ray without Ray Tune's dependencies
            raise InputError("--ray needs Ray Tune: pip install -e '.[ray]'") from None

        ray_search = RaySearch.from_args(args, out, root, seqs)  # refuses a changed command

    raw: dict[str, dict[str, list[Frame]]] = {}
    gt: dict[str, dict[str, list[Frame]]] = {}
    for det in detectors:
        raw[det], labels = convert_kitti(root, seqs=seqs, detector=det, classes=[cls])
        gt[det] = labels or {}
    lengths = {s: len(f) for s, f in raw[detectors[0]].items()}
    folds = folds_by_frames(lengths, args.folds)

    # calibrated frames per (detector, fold): profiles fitted on the fold's training sequences
    for det in detectors:
        for k, test in enumerate(folds):
            train = [s for s in lengths if s not in test]
            profile = fit_profile(det, {s: raw[det][s] for s in train}, gt[det], [cls])
            _FRAMES[(det, f"fold{k}")] = {s: calibrate_frames(raw[det][s], profile)
                                          for s in lengths}  # fmt: skip
        shipped = find_profile(det)
        _FRAMES[(det, "all")] = {s: calibrate_frames(raw[det][s], shipped) for s in lengths}

    objective = Objective(tuple(detectors), config_name, base, cls, str(label_dir))
    first = _current(config_name, base, cls, space)
    work = Path(tempfile.mkdtemp(prefix="mctrack-tune-"))
    total = args.trials * (len(folds) + 1)
    ctx = multiprocessing.get_context("fork")
    record: dict[str, Any] = {
        "class": cls, "mode": args.mode, "config": config_name, "detectors": detectors,
        "folds": folds, "trials_per_search": args.trials, "seed": args.seed,
        "sampler": "optuna TPESampler", "space": space,
    }  # fmt: skip
    start = time.perf_counter()
    try:
        # the pool forks before Ray starts (a forked Ray driver is unsafe)
        with ctx.Pool(max(1, args.workers)) as pool, tqdm(total=total, unit="trial") as bar:

            def local_search(key: str, seqs: Sequence[str], seed: int) -> Trials:
                study = optuna.create_study(direction="maximize", sampler=make_sampler(seed))
                study.enqueue_trial(first)

                def trial_value(trial: optuna.Trial) -> float:
                    params = suggest(trial, space)
                    metrics = objective.metrics(key, seqs, params, work / f"{key}-trial", pool.map)
                    bar.update(1)
                    return objective.value(metrics)

                study.optimize(trial_value, n_trials=args.trials)
                return [(t.params, t.value) for t in study.trials]

            if ray_search is None:
                search: Callable[[str, Sequence[str], int], Trials] = local_search
            else:
                search = ray_search.start(objective, space, first, _FRAMES, bar.update)

            record["cv"] = []
            for k, test in enumerate(folds):
                train = [s for s in lengths if s not in test]
                trials = search(f"fold{k}", train, args.seed + k)
                params, value = best_trial(trials)
                # the held-out fold, tracked with the settings its search chose
                heldout = objective.tasks(f"fold{k}", test, params, work / "heldout", False)
                pool.map(_track_and_score, heldout)
                record["cv"].append({"test": test, "best": params, "train_hota": round(value, 3),
                                     "trials": _trial_list(trials)})  # fmt: skip
            record["cross_validated"] = {
                det: _evaluate_dir(work / "heldout" / det, label_dir, lengths, cls)
                for det in detectors
            }
            trials = search("all", list(lengths), args.seed + 100)
            params, value = best_trial(trials)
            record["final"] = {
                "best": params,
                "overrides": settings_to_overrides(cls, params),
                "in_sample": objective.metrics("all", list(lengths), params, work / "final",
                                               pool.map),
                "trials": _trial_list(trials),
            }  # fmt: skip
            if ray_search is not None:
                record["ray"] = ray_search.describe()
    finally:
        if ray_search is not None:
            ray_search.stop()
        shutil.rmtree(work, ignore_errors=True)
    record["seconds"] = round(time.perf_counter() - start, 1)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "tune.json", [json.dumps(record, indent=2)])
    _print(record)
    return 0


def _trial_list(trials: Trials) -> list[dict[str, Any]]:
    return [{"params": p, "hota": round(v, 3)} for p, v in trials]


def _current(config_name: str, base: dict[str, Any], cls: str, space: dict) -> dict[str, Any]:
    """The base config's own values of the searched settings (the first trial)."""
    import math

    config = load_config(config_name, overrides=base)
    values: dict[str, Any] = {}
    for key, (kind, low, high) in space.items():
        if key == "lifecycle.confirm_nines":
            p = config.per_category[cls].lifecycle.confirm_prob
            value: Any = -math.log10(max(1.0 - p, 1e-12))
        elif key.startswith("offline."):
            value = getattr(config.offline, key.split(".", 1)[1])
        else:
            value = config.per_category[cls]
            for part in key.split("."):
                value = getattr(value, part)
        values[key] = min(max(value, low), high)
        if kind == "int":
            values[key] = int(values[key])
    return values


def suggest(trial: Any, space: dict[str, tuple[str, float, float]]) -> dict[str, Any]:
    draw: dict[str, Callable[..., Any]] = {
        "int": lambda k, lo, hi: trial.suggest_int(k, int(lo), int(hi)),
        "float": lambda k, lo, hi: trial.suggest_float(k, lo, hi),
        "log": lambda k, lo, hi: trial.suggest_float(k, lo, hi, log=True),
    }
    return {key: draw[kind](key, lo, hi) for key, (kind, lo, hi) in space.items()}


def _evaluate_dir(
    result_dir: Path, label_dir: Path, lengths: dict[str, int], cls: str
) -> dict[str, Any]:
    from tracker.eval.kitti import evaluate_kitti

    return evaluate_kitti(
        label_dir=label_dir, result_dir=result_dir, seq_lengths=lengths, classes=[cls]
    )[cls]


def _print(record: dict[str, Any]) -> None:
    print(f"class {record['class']}, {record['mode']}, folds {record['folds']}")
    for det, m in record["cross_validated"].items():
        final = record["final"]["in_sample"][det]
        print(
            f"{det:12s} HOTA cross-validated {m['HOTA']:.2f} (MOTA {m['MOTA']:.2f}, IDSW "
            f"{m['IDSW']})   in-sample {final['HOTA']:.2f} (MOTA {final['MOTA']:.2f}, IDSW "
            f"{final['IDSW']})"
        )
    print("settings to ship:", json.dumps(record["final"]["overrides"]))
