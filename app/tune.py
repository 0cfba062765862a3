"""`mctrack tune`: cross-validated search of one class's tracker settings over several detectors.

Honest tuning: the 11 labelled sequences are split into ``--folds`` groups (balanced by frames).
For each fold, Optuna's TPE sampler searches the settings on the other folds' sequences
(objective: HOTA averaged over the detectors and over the clean and the ``--noise`` perturbed
detections, :mod:`tracker.eval.perturb`) with score profiles fitted on those sequences only;
the best settings then track the held-out fold. The held-out result files of all folds are
evaluated together: that is the cross-validated figure. A last search on all sequences (with
the shipped profiles; for a detector without one, a profile fitted on all the sequences) gives
the settings to ship and their in-sample figure.

Only that last search starts from the config's current values (its first trial). A fold's
search does not: the current values came from earlier searches on all the labelled sequences,
held-out fold included, so offering them to a fold would leak its labels into its figure.

Why noise in the objective: on clean detections of three detectors, settings that never output a
coasting track and confirm late score the same as robust ones (within ~0.1 HOTA) but lose 11 HOTA
when 10% of the boxes go missing; a detector we have not seen is more like the perturbed set than
like the one we fitted. Each trial therefore scores the clean and the perturbed (seeded) sets.

Settings of one class never affect another (matching and lifecycle are per class), so each class
is tuned on its own: ``--class car --detectors pointrcnn,virconv,second_iou``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import multiprocessing
import os
import shutil
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from app.common import command_line, remove_earlier_outputs
from app.inputs import (
    add_kitti_root_argument,
    check_kitti_root,
    class_list,
    default_kitti_root,
    positive_int,
    sequence_list,
    unique_names,
)
from app.outputs import FILES, outputs_of
from tracker.config import BUILTIN, config_for_mode, load_config, range_error, toml_value
from tracker.errors import InputError
from tracker.eval.perturb import CLEAN, NOISE_LEVELS, perturb_frames
from tracker.frame import Frame
from tracker.io.convert.kitti import VALIDATION_SEQS
from tracker.io.fileio import make_work_folder, write_text_atomic

LOG = logging.getLogger(__name__)

# (kind, low, high): the settings searched, per class, in calibrated units. "confirm_nines" n
# sets confirm_prob = 1 - 10^-n; "pose.r_scale" sets the position measurement variance of the
# filter, how much it trusts one box, as a multiple of the detections' own centre variance
# (estimated as the tracker runs, tracker/noise.py), so that r follows the detector's noise.
ONLINE_SPACE: dict[str, tuple[str, float, float]] = {
    "score_min": ("log", 0.01, 0.6),
    "birth_score_min": ("float", 0.2, 0.95),
    "lifecycle.confirm_nines": ("float", 1.0, 4.0),
    "lifecycle.min_hits": ("int", 2, 5),
    "lifecycle.max_misses_output": ("int", 0, 3),
    "lifecycle.max_misses": ("int", 5, 30),
    "bev.cost_max": ("float", 1.0, 2.0),
    "pose.r_scale": ("log", 3.0, 300.0),
}
# Searched for cars only: the output gate on the track's mean log-odds. 0 is "more likely real
# than not" for independent hits, but a detector's hits of one object are correlated, so where
# the boundary lies is measured: searched, it raised the car's held-out HOTA for all three
# detectors; for pedestrians (one detector, ten settings) it lowered it (52.13 against 53.35,
# docs/tune/ped_online_gate_searched.json), so they keep 0.
CAR_SPACE: dict[str, tuple[str, float, float]] = {"lifecycle.track_score_min": ("float", -1.5, 0.5)}
# Searched for pedestrians only: their annotated 2D boxes are narrower than their cuboids'
# projections (median 1/1.49 on ground truth), while cars' and cyclists' match them (IoU 0.96;
# bench/kitti_box_shapes.py).
PEDESTRIAN_SPACE: dict[str, tuple[str, float, float]] = {"image_width_scale": ("float", 0.6, 1.0)}
OFFLINE_SPACE: dict[str, tuple[str, float, float]] = {
    "score_min": ("log", 0.01, 0.6),
    "birth_score_min": ("float", 0.05, 0.9),
    "offline.track_score_min": ("float", -1.0, 5.0),
    "lifecycle.max_misses": ("int", 5, 30),
}

# shared with the forked evaluation workers (set before the pool starts; never pickled), keyed
# by (detector, profile key, noise level)
_FRAMES: dict[tuple[str, str, str], dict[str, list[Frame]]] = {}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_kitti_root_argument(parser)
    parser.add_argument(
        "--class",
        dest="cls",
        type=scored_class,
        default="car",
        help="the class whose settings are searched: car, pedestrian or cyclist (default: "
        "%(default)s)",
    )
    parser.add_argument(
        "--detectors",
        type=detector_names,
        default="pointrcnn,virconv,second_iou",
        help="detectors the objective averages over (default: %(default)s)",
    )
    parser.add_argument(
        "--config", default="kitti", help="base config, name or TOML (default: %(default)s)"
    )
    parser.add_argument(
        "--mode",
        choices=["online", "offline"],
        default=None,
        help="tune the config in this mode, as --mode gives it in every command (offline: its "
        "offline variant; online: an offline variant's base); default: the config's own mode "
        "(kitti online, kitti_offline offline), named in tune.json and best.toml",
    )
    parser.add_argument("--trials", type=positive_int, default=20, help="trials per search")
    parser.add_argument(
        "--folds",
        type=fold_count,
        default=3,
        help="sequence folds, 2 to the number of --seqs (default: %(default)s)",
    )
    parser.add_argument("--seed", type=sampler_seed, default=0, help="sampler seed (default: 0)")
    parser.add_argument(
        "--noise",
        default="noise",
        help="perturbation levels (tracker.eval.perturb) the objective averages with the clean "
        "detections, comma-separated, or 'none' (default: %(default)s)",
    )
    parser.add_argument(
        "--noise-seed",
        type=seed_list,
        default=(0,),
        metavar="SEED[,SEED...]",
        help="perturbation seed(s); with several, each noisy level is drawn once per seed and "
        "the objective averages the draws (default: 0)",
    )
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=2,
        help="parallel evaluations (default: %(default)s)",
    )
    parser.add_argument(
        "--seqs",
        type=sequence_list,
        default=",".join(VALIDATION_SEQS),
        help="labelled sequences the folds are made of (default: the 11 validation sequences)",
    )
    parser.add_argument(
        "--search",
        action="append",
        default=None,
        metavar="KEY=KIND:LOW:HIGH",
        help="also search this setting of the class, KIND int, float or log (repeatable; e.g. "
        "lifecycle.max_misses_tentative=int:0:2; LOW and HIGH inside the setting's range)",
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


def scored_class(text: str) -> str:
    """argparse type of ``--class``: one class, spelled as ``--classes`` accepts it elsewhere
    (:func:`app.inputs.class_list`), that the KITTI protocol scores (the objective is its
    HOTA)."""
    from tracker.eval.kitti import SUPPORTED_CLASSES

    names = class_list(text)
    if len(names) != 1:
        raise argparse.ArgumentTypeError(f"one class at a time, got {text!r}")
    if names[0] not in SUPPORTED_CLASSES:
        raise argparse.ArgumentTypeError(
            f"{names[0]!r} is not scored by the KITTI protocol, so it cannot be tuned "
            f"(tunable: {', '.join(SUPPORTED_CLASSES)})"
        )
    return names[0]


def detector_names(text: str) -> str:
    """argparse type of ``--detectors``: checked (at least one name, each once) and kept as
    given (Ray Tune's resume record compares the text)."""
    unique_names([d.strip() for d in text.split(",") if d.strip()], text, "detectors")
    return text


def fold_count(text: str) -> int:
    """argparse type of ``--folds``: at least 2 (with one fold nothing is left to search on
    but the held-out sequences themselves). The upper bound, the number of ``--seqs``, is
    checked once both are read."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 2:
        raise argparse.ArgumentTypeError(
            f"expected an integer >= 2 (each fold is searched on the others), got {text!r}"
        )
    return value


#: The largest ``--seed``: the searches use seed + fold and seed + 100, and Optuna's sampler
#: takes seeds below 2**32.
MAX_SEED = 2**32 - 1 - 100


def sampler_seed(text: str) -> int:
    """argparse type of ``--seed``: an integer from 0 to :data:`MAX_SEED`."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"expected an integer 0..{MAX_SEED}, got {text!r}")
    return value


def parse_search(text: str) -> tuple[str, tuple[str, float, float]]:
    """``--search KEY=KIND:LOW:HIGH`` → ``(key, (kind, low, high))``."""
    key, _, spec = text.partition("=")
    parts = spec.split(":")
    if not key.strip() or len(parts) != 3:
        example = "lifecycle.min_hits=int:2:5"
        raise InputError(f"--search {text!r}: expected KEY=KIND:LOW:HIGH (e.g. {example})")
    kind, low_text, high_text = (p.strip() for p in parts)
    if kind not in ("int", "float", "log"):
        raise InputError(f"--search {text!r}: KIND must be int, float or log, not {kind!r}")
    try:
        low, high = float(low_text), float(high_text)
    except ValueError:
        raise InputError(f"--search {text!r}: LOW and HIGH must be numbers") from None
    if not (math.isfinite(low) and math.isfinite(high)):
        raise InputError(f"--search {text!r}: LOW and HIGH must be finite")
    if not low < high or (kind == "log" and low <= 0):
        raise InputError(f"--search {text!r}: needs LOW < HIGH (and LOW > 0 for log)")
    if kind == "int" and not (low.is_integer() and high.is_integer()):
        raise InputError(f"--search {text!r}: int bounds must be whole numbers")
    return key.strip(), (kind, low, high)


def with_searched(
    space: dict[str, tuple[str, float, float]],
    texts: Sequence[str],
    config: Any,
    cls: str,
    mode: str,
) -> dict[str, tuple[str, float, float]]:
    """``space`` with the ``--search`` settings added, each checked against the loaded
    ``config``: a number setting of ``cls`` (``offline.<name>`` in offline mode), searched as an
    ``int`` if it is one, not searched already and not set by a searched one."""
    space = dict(space)
    for text in texts:
        key, spec = parse_search(text)
        where = f"--search {text!r}"
        if key in space:
            kind, low, high = space[key]
            raise InputError(f"{where}: {key} is searched already ({kind} {low:g}..{high:g})")
        if key == "lifecycle.confirm_prob":
            raise InputError(f"{where}: searched already, as lifecycle.confirm_nines")
        if key == "pose.r_scale" and "pose.ca.r" in space:
            raise InputError(f"{where}: this config's filter has a fixed r (pose.ca.r, searched)")
        if key.startswith("offline.") and mode != "offline":
            raise InputError(f"{where}: an offline setting, searched with --mode offline only")
        try:
            value = _raw_value(config, cls, key)
        except AttributeError:
            section = "[offline]" if key.startswith("offline.") else cls
            raise InputError(f"{where}: the {section} settings have no setting {key!r}") from None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise InputError(f"{where}: {key} is not a number setting")
        if isinstance(value, int) != (spec[0] == "int"):
            need = "int" if isinstance(value, int) else "float or log"
            what = "an int" if isinstance(value, int) else "a float"
            raise InputError(f"{where}: {key} is {what} setting: KIND {need}")
        # every trial's config would be refused (or load): each range is an interval, so its
        # ends decide, before any work
        table, name = _setting_table(config, cls, key)
        for end, bound in (("LOW", spec[1]), ("HIGH", spec[2])):
            what = range_error(table, name, int(bound) if spec[0] == "int" else bound)
            if what is not None:
                raise InputError(f"{where}: {key} {what}; {end} {bound:g} is outside")
        space[key] = spec
    return space


def folds_by_frames(lengths: dict[str, int], k: int) -> list[list[str]]:
    """``k`` sequence groups of similar total length (longest first into the lightest group)."""
    groups: list[list[str]] = [[] for _ in range(k)]
    load = [0] * k
    for seq in sorted(lengths, key=lambda s: (-lengths[s], s)):
        i = load.index(min(load))
        groups[i].append(seq)
        load[i] += lengths[seq]
    return [sorted(g) for g in groups]


def noise_levels(text: str) -> list[str]:
    """``--noise`` → level names (clean is always scored and never listed)."""
    names = [n.strip() for n in text.split(",") if n.strip() and n.strip() != "none"]
    unknown = [n for n in names if n not in NOISE_LEVELS]
    if unknown:
        known = ", ".join(n for n in NOISE_LEVELS if n != CLEAN)
        raise InputError(f"--noise: unknown level(s) {unknown}; known: {known}, none")
    return [n for n in dict.fromkeys(names) if n != CLEAN]


def seed_list(text: str) -> tuple[int, ...]:
    """``--noise-seed 0`` or ``0,1,2`` → the seeds, in order, each once."""
    try:
        seeds = tuple(dict.fromkeys(int(t) for t in text.split(",")))
    except ValueError:
        wanted = "SEED[,SEED...] (integers)"
        raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
    if any(s < 0 for s in seeds):
        raise argparse.ArgumentTypeError(f"seeds must be >= 0, got {text!r}")
    return seeds


def draw_levels(levels: Sequence[str], seeds: Sequence[int]) -> list[str]:
    """The runs' level names: clean once, each noisy level once per perturbation seed (its own
    name with one seed, ``LEVEL@SEED`` with several; :func:`base_level` undoes it)."""
    return [
        level if level == CLEAN or len(seeds) == 1 else f"{level}@{seed}"
        for level in levels
        for seed in ((0,) if level == CLEAN else seeds)
    ]


def base_level(run_level: str) -> str:
    """``noise@2`` → ``noise`` (the level a draw belongs to)."""
    return run_level.partition("@")[0]


def objective_value(metrics: dict[tuple[str, str], dict[str, Any]]) -> float:
    """The search's objective: HOTA averaged over every (detector, noise level) scored, a
    level's draws (one per perturbation seed) averaged first, so more draws of the noise give a
    steadier estimate of the same objective, not more weight to the noise."""
    draws: dict[tuple[str, str], list[float]] = {}
    for (det, level), m in metrics.items():
        draws.setdefault((det, base_level(level)), []).append(m["HOTA"])
    return sum(sum(v) / len(v) for v in draws.values()) / len(draws)


def settings_to_overrides(cls: str, params: dict[str, Any]) -> dict[str, Any]:
    """Searched values → a nested config override (``category.<cls>...``, ``offline...``)."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        if key == "lifecycle.confirm_nines":
            key, value = "lifecycle.confirm_prob", round(1.0 - 10.0 ** (-value), 6)
        elif key == "pose.ca.r":  # (records of tunes before pose.r_scale: a fixed r)
            value = [round(value, 6)] * 2
            out.setdefault("category", {}).setdefault(cls, {}).setdefault("pose", {})["r_scale"] = (
                0.0
            )
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


Trials = list[tuple[dict[str, Any], float]]  # (settings, objective) per trial, in trial order
# (search key, sequences, sampler seed, first trial or None) -> trials
Search = Callable[[str, Sequence[str], int, "dict[str, Any] | None"], Trials]


def startup_trials(trials: int) -> int:
    """Random trials before TPE models the objective: a third of the budget, at least 4."""
    return max(4, trials // 3)


def make_sampler(seed: int, n_startup: int) -> Any:
    """The search algorithm of every backend (local and Ray Tune): Optuna's TPE, seeded."""
    import optuna

    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=n_startup)


def best_trial(trials: Trials) -> tuple[dict[str, Any], float]:
    """The first trial with the highest objective (Optuna's own rule for ties)."""
    params, value = trials[0]
    for p, v in trials[1:]:
        if v > value:
            params, value = p, v
    return params, value


@dataclass(frozen=True, slots=True)
class Objective:
    """What a trial computes: each (detector, noise level) tracks ``seqs`` with the trial's
    settings and is scored; :func:`objective_value` averages them. One definition for the local
    pool and the Ray Tune trials (app/tune_ray.py)."""

    detectors: tuple[str, ...]
    levels: tuple[str, ...]
    config_name: str
    base: dict[str, Any]
    cls: str
    label_dir: str
    labels_checked: bool = False  # (by the caller, as evaluate_kitti would: not read per trial)

    @property
    def runs(self) -> list[tuple[str, str]]:
        return [(det, level) for det in self.detectors for level in self.levels]

    def tasks(
        self, key: str, seqs: Sequence[str], params: dict[str, Any], work: Path, evaluate: bool
    ) -> list[tuple[Any, ...]]:
        """One :func:`_track_and_score` task per run, reading ``_FRAMES[(det, key, level)]``
        and writing ``work/<detector>/<level>``."""
        overrides = {**self.base, **settings_to_overrides(self.cls, params)}  # disjoint keys
        return [((det, key, level), list(seqs), self.config_name, overrides,
                 str(work / det / level), self.label_dir, self.cls, evaluate, self.labels_checked)
                for det, level in self.runs]  # fmt: skip

    def metrics(
        self,
        key: str,
        seqs: Sequence[str],
        params: dict[str, Any],
        work: Path,
        map_fn: Callable[[Callable, Iterable], Iterable] = map,
    ) -> dict[tuple[str, str], dict[str, Any]]:
        """{(detector, level): metrics} of one setting on ``seqs``."""
        results = map_fn(_track_and_score, self.tasks(key, seqs, params, work, True))
        return dict(zip(self.runs, results, strict=True))


def level_frames(
    raw: dict[str, list[Frame]], profile: Any, specs: dict[str, Any], seeds: Sequence[int]
) -> dict[str, dict[str, list[Frame]]]:
    """``{run level: {seq: frames}}``: the raw frames calibrated with ``profile``, then
    perturbed per noise level (``specs``: level -> PerturbSpec; the clean level is the
    calibrated frames) and per seed (names: :func:`draw_levels`), seeded per scene so every
    trial and fold sees the same noise."""
    from tracker.calibration import calibrate_frames

    clean = {s: calibrate_frames(f, profile) for s, f in raw.items()}
    out: dict[str, dict[str, list[Frame]]] = {}
    for level, spec in specs.items():
        if level == CLEAN:
            out[CLEAN] = clean
            continue
        for name, seed in zip(draw_levels([level], seeds), seeds, strict=True):
            out[name] = {s: perturb_frames(f, spec, seed=seed) for s, f in clean.items()}
    return out


def record_seeds(record: dict[str, Any]) -> tuple[int, ...]:
    """A tune record's perturbation seeds (``noise_seed``: one int, or a list)."""
    seeds = record.get("noise_seed", 0)
    return tuple(seeds) if isinstance(seeds, list) else (int(seeds),)


def _track_and_score(task: tuple[Any, ...]) -> dict[str, Any]:
    """One detector: track ``seqs`` with the overrides, write KITTI files to ``result_dir``,
    and (when ``evaluate``) score them (``labels_checked``: see :func:`evaluate_kitti`). Runs in
    a forked worker reading ``_FRAMES``."""
    from tracker.eval.kitti import evaluate_kitti
    from tracker.io.writers import write_kitti_sequence
    from tracker.pipeline import run_scene

    key, seqs, config_name, overrides, result_dir, label_dir, cls, evaluate, checked = task
    config = load_config(config_name, overrides=overrides)
    frames = _FRAMES[key]
    result_dir = Path(result_dir)
    result_dir.mkdir(parents=True, exist_ok=True)
    for seq in seqs:
        result = run_scene(frames[seq], config)
        write_kitti_sequence(
            result_dir / f"{seq}.txt",
            result.outputs,
            frames[seq],
            **config.kitti_writer_options(),
        )
    if not evaluate:
        return {}
    return evaluate_kitti(
        label_dir=Path(label_dir),
        result_dir=result_dir,
        seq_lengths={s: len(frames[s]) for s in seqs},
        classes=[cls],
        labels_checked=checked,
    )[cls]


def run(args: argparse.Namespace) -> int:
    # each trial tracks every sequence: the per-scene notes (offline removals) would bury the
    # progress bar; restored after, as the process may go on (tests call main() in-process)
    notes = logging.getLogger("tracker.pipeline")
    level = notes.level
    if not getattr(args, "verbose", False):
        notes.setLevel(logging.WARNING)
    try:
        return _run(args)
    finally:
        notes.setLevel(level)


def _run(args: argparse.Namespace) -> int:
    import optuna
    from tqdm import tqdm

    from tracker.calibration import find_profile
    from tracker.eval.calibrate import fit_profile, one_score_warning
    from tracker.eval.kitti import check_kitti_labels
    from tracker.io.convert.kitti import convert_kitti

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    levels = [CLEAN, *noise_levels(args.noise)]  # before any work: a typo fails at once
    if args.ray is not None:
        from app.scenes import import_ray

        import_ray()  # the one-line error when the extra is not installed, before any work
    elif args.max_concurrent is not None:
        raise InputError("--max-concurrent needs --ray (local trials run one at a time)")
    cls = args.cls
    if args.mode is None:
        # the config's own mode, as every command takes it (--config kitti_offline: offline);
        # from here on it is named, so the record, best.toml, the repeating command and a Ray
        # resume's options all say which mode ran
        args = argparse.Namespace(**{**vars(args), "mode": load_config(args.config).mode.value})
    config_name = str(config_for_mode(args.config, args.mode))
    base = {"categories": [cls], "mode": args.mode}
    base_config = load_config(config_name, overrides=base)  # fail early on a bad config
    space = search_space(cls, args.mode, r_scale=base_config.per_category[cls].pose.r_scale > 0)
    space = with_searched(space, args.search or [], base_config, cls, args.mode)
    root = args.kitti_root or default_kitti_root()
    detectors = [d.strip() for d in args.detectors.split(",") if d.strip()]
    seqs = args.seqs
    if len(seqs) < args.folds:
        raise InputError(f"--folds {args.folds} needs at least as many --seqs (got {len(seqs)})")
    out = Path(args.out)
    if out.exists() and not out.is_dir():  # (else found only when writing, after the search)
        raise InputError(f"{out}: exists and is not a folder; pass another --out")
    if Path(args.config).resolve() in {(out / name).resolve() for name in FILES["tune"]}:
        # (a new search there replaces the results, its own config among them, and every
        # trial reads the config again)
        raise InputError(
            f"--config {args.config} is this --out's own result: pass another --out to search "
            "on from it"
        )
    for detector in detectors:
        check_kitti_root(root, seqs=seqs, detector=detector, detector_flag="--detectors A,B")
    label_dir = root / "training" / "label_02"
    unlabelled = [s for s in seqs if not (label_dir / f"{s}.txt").is_file()]
    if unlabelled:
        raise InputError(f"--seqs: no labels for {', '.join(unlabelled)} in {label_dir}")
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
        if not any(len(f.boxes) for frames in raw[det].values() for f in frames):
            # a HOTA of 0 would be averaged into every trial's objective and the search
            # would still write a best.toml
            raise InputError(
                f"{root / 'detections' / det}: no {cls} detections in --seqs "
                f"({', '.join(seqs)}); --detectors must name detectors that detect {cls}"
            )
    lengths = {s: len(f) for s, f in raw[detectors[0]].items()}
    # a bad label file stops the search here, not in its first trial (Optuna's traceback)
    labelled = check_kitti_labels(
        label_dir, lengths, dict.fromkeys(lengths, "the kit's pose lines"), classes=[cls]
    )
    # checked as evaluate_kitti checks them (the classes scored, these lengths), so no trial's
    # evaluation reads them again; one not found here is left to its check to name
    labels_checked = labelled.keys() >= lengths.keys()
    folds = folds_by_frames(lengths, args.folds)

    # calibrated frames per (detector, fold): profiles fitted on the fold's training sequences;
    # each noise level perturbs the calibrated frames (seeded per scene, so every trial and fold
    # sees the same noise)
    profile_notes: dict[str, str] = {}
    one_score: dict[str, str] = {}
    for det in detectors:
        profiles = {}
        for k, test in enumerate(folds):
            train = [s for s in lengths if s not in test]
            profiles[f"fold{k}"] = fit_profile(det, {s: raw[det][s] for s in train}, gt[det], [cls])
        # the in-sample search: the shipped profile (fitted on the 11 validation sequences), else
        # one fitted on every tuning sequence, as each fold's is on its own
        profiles["all"] = find_profile(det) or fit_profile(det, raw[det], gt[det], [cls])
        profile_notes[det] = (
            "shipped" if find_profile(det) else f"fitted on --seqs ({', '.join(lengths)})"
        )
        # a class whose boxes all score the same: a map gives them all one probability, so each
        # trial keeps all of them or none. Said once, before the search: the in-sample profile's
        # note (a fold's where only a fold's sequences score the same)
        said = (
            one_score_warning(det, cls, profiles[key].quality.get(cls, {}))
            for key in ("all", *(k for k in profiles if k != "all"))
        )
        warning = next((w for w in said if w is not None), None)
        if warning is not None:
            LOG.warning("%s", warning)
            one_score[det] = warning
        specs = {level: NOISE_LEVELS[level] for level in levels}
        for key, profile in profiles.items():
            for level, frames in level_frames(raw[det], profile, specs, args.noise_seed).items():
                _FRAMES[(det, key, level)] = frames

    runs = tuple(draw_levels(levels, args.noise_seed))
    objective = Objective(
        tuple(detectors), runs, config_name, base, cls, str(label_dir), labels_checked
    )
    first = _current(config_name, base, cls, space)
    n_startup = startup_trials(args.trials)
    work = make_work_folder("tune")  # (a killed tune's goes: its pid is in the name)
    total = args.trials * (len(folds) + 1)
    ctx = multiprocessing.get_context("fork")
    record: dict[str, Any] = {
        "class": cls, "mode": args.mode, "config": config_name, "detectors": detectors,
        "folds": folds, "trials_per_search": args.trials, "seed": args.seed,
        "sampler": f"optuna TPESampler, {n_startup} random startup trials", "space": space,
        "noise": {lv: dataclasses.asdict(NOISE_LEVELS[lv]) for lv in levels if lv != CLEAN},
        "noise_seed": noise_seed_value(args.noise_seed),
        "profiles": {"folds": "fitted on each fold's own sequences", "in_sample": profile_notes},
    }  # fmt: skip
    if one_score:  # (the warnings above, per detector)
        record["profiles"]["one_score"] = one_score
    record["command"] = command_line(tune_command(args, root, detectors, seqs))
    # the inputs are accepted and the search starts: an earlier search's results go, so the
    # folder never shows them as this one's (this one writes its own when it ends; a Ray
    # resume reads its finished searches back and writes them again). Only where a search
    # wrote them: tune.json says so (a best.toml alone may be anyone's)
    if (out / "tune.json").is_file():
        remove_earlier_outputs(out, outputs_of("tune"))
    start = time.perf_counter()
    try:
        # the pool forks before Ray starts (a forked Ray driver is unsafe)
        with ctx.Pool(max(1, args.workers)) as pool, tqdm(total=total, unit="trial") as bar:

            def local_search(
                key: str, seqs: Sequence[str], seed: int, start: dict[str, Any] | None
            ) -> Trials:
                study = optuna.create_study(
                    direction="maximize", sampler=make_sampler(seed, n_startup)
                )
                if start is not None:
                    study.enqueue_trial(start)

                def trial_value(trial: optuna.Trial) -> float:
                    params = suggest(trial, space)
                    metrics = objective.metrics(key, seqs, params, work / f"{key}-trial", pool.map)
                    bar.update(1)
                    return objective_value(metrics)

                study.optimize(trial_value, n_trials=args.trials)
                return [(t.params, t.value) for t in study.trials]

            if ray_search is None:
                search: Search = local_search
            else:
                search = ray_search.start(objective, space, n_startup, _FRAMES, bar.update)

            record["cv"] = []
            for k, test in enumerate(folds):
                train = [s for s in lengths if s not in test]
                # no first trial from the current config: it was fitted on this fold's labels
                trials = search(f"fold{k}", train, args.seed + k, None)
                params, value = best_trial(trials)
                # the held-out fold, tracked with the settings its search chose
                heldout_tasks = objective.tasks(f"fold{k}", test, params, work / "heldout", False)
                pool.map(_track_and_score, heldout_tasks)
                record["cv"].append({"test": test, "best": params,
                                     "train_objective": round(value, 3),
                                     "trials": _trial_list(trials)})  # fmt: skip
            heldout = {
                (det, level): _evaluate_dir(
                    work / "heldout" / det / level, label_dir, lengths, cls, labels_checked
                )
                for det, level in objective.runs
            }
            record["cross_validated"] = {det: heldout[(det, CLEAN)] for det in detectors}
            record["cross_validated_noise"] = _by_level(heldout, runs)
            trials = search("all", list(lengths), args.seed + 100, first)
            params, value = best_trial(trials)
            final = objective.metrics("all", list(lengths), params, work / "final", pool.map)
            record["final"] = {
                "best": params,
                "overrides": settings_to_overrides(cls, params),
                "objective": round(value, 3),
                "in_sample": {det: final[(det, CLEAN)] for det in detectors},
                "in_sample_noise": _by_level(final, runs),
                "trials": _trial_list(trials),
            }
            if ray_search is not None:
                record["ray"] = ray_search.describe()
    except KeyboardInterrupt:
        if ray_search is not None:
            ray_search.interrupted()  # says how to resume
        raise
    finally:
        if ray_search is not None:
            ray_search.stop()
        shutil.rmtree(work, ignore_errors=True)
    record["seconds"] = round(time.perf_counter() - start, 1)
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "tune.json", [json.dumps(record, indent=2)])
    write_text_atomic(out / "best.toml", [best_config_toml(record, out / "best.toml")])
    _print(record)
    print(f"wrote {out / 'tune.json'} and {out / 'best.toml'} (use: --config {out / 'best.toml'})")
    return 0


def tune_command(
    args: argparse.Namespace, root: Path, detectors: Sequence[str], seqs: Sequence[str]
) -> list[str]:
    """The words after ``mctrack`` that repeat this search: every option that changes its
    result (and --out), as given."""
    words = [
        "tune", "--kitti-root", str(root), "--class", args.cls,
        "--detectors", ",".join(detectors), "--config", str(args.config), "--mode", args.mode,
        "--trials", str(args.trials), "--folds", str(args.folds), "--seed", str(args.seed),
        "--noise", args.noise, "--noise-seed", ",".join(map(str, args.noise_seed)),
        "--seqs", ",".join(seqs), "--workers", str(args.workers),
        *(w for text in args.search or [] for w in ("--search", text)),
    ]  # fmt: skip
    if args.ray is not None:
        words += ["--ray", args.ray]
        if args.max_concurrent is not None:
            words += ["--max-concurrent", str(args.max_concurrent)]
    return [*words, "--out", str(args.out)]


def best_config_toml(record: dict[str, Any], path: Path | None = None) -> str:
    """The settings the search chose on all sequences as a config file (``--config
    best.toml``) to be written at ``path``: the tuned config as its base, the search's mode and
    the chosen values (exact) over it, every other class and setting as in the base."""
    base = record["config"]
    if base not in BUILTIN:  # a file: relative to best.toml, so the two move together
        base = written_base(Path(base), path)
    held_out = ", ".join(f"{d} {m['HOTA']:.2f}" for d, m in record["cross_validated"].items())
    in_sample = ", ".join(f"{d} {m['HOTA']:.2f}" for d, m in record["final"]["in_sample"].items())
    command = record.get("command") or f"mctrack tune --class {record['class']}"
    lines = [
        f"# `{command}`: the settings chosen on all sequences (the record: tune.json beside this"
        " file)",
        f"# HOTA held out: {held_out}; in-sample: {in_sample}",
        f"base = {toml_value(base)}",
        f"mode = {toml_value(record['mode'])}",  # (the search's, whatever the base file says)
    ]
    overrides = record["final"]["overrides"]
    tables = [(f"category.{c}", v) for c, v in overrides.get("category", {}).items()]
    if "offline" in overrides:
        tables.append(("offline", overrides["offline"]))
    for name, values in tables:
        exact = (f"{k} = {toml_value(v, decimals=None)}" for k, v in values.items())
        lines += ["", f"[{name}]", *exact]
    return "\n".join(lines) + "\n"


def written_base(base: Path, path: Path | None) -> str:
    """A base config file as ``path`` (the config that names it) writes it: relative to
    ``path``'s folder when the two share a folder below the filesystem's root (a copied or
    moved tree keeps working), else absolute (works from anywhere)."""
    target = base.resolve()
    if path is None:
        return str(target)
    folder = path.resolve().parent
    common = Path(os.path.commonpath([target, folder]))
    if common == Path(common.anchor):
        return str(target)
    return Path(os.path.relpath(target, folder)).as_posix()


def noise_seed_value(seeds: Sequence[int]) -> int | list[int]:
    """``noise_seed`` as records keep it: one int (as before several were possible), or a list."""
    return seeds[0] if len(seeds) == 1 else list(seeds)


def _trial_list(trials: Trials) -> list[dict[str, Any]]:
    return [{"params": p, "objective": round(v, 3)} for p, v in trials]


def _current(config_name: str, base: dict[str, Any], cls: str, space: dict) -> dict[str, Any]:
    """The base config's own values of the searched settings (the first trial)."""
    config = load_config(config_name, overrides=base)
    values: dict[str, Any] = {}
    for key, (kind, low, high) in space.items():
        if key == "lifecycle.confirm_nines":
            p = config.per_category[cls].lifecycle.confirm_prob
            value: Any = -math.log10(max(1.0 - p, 1e-12))
        elif key == "pose.ca.r":
            value = config.per_category[cls].pose.ca.r[0]
        else:
            value = _raw_value(config, cls, key)
        values[key] = min(max(value, low), high)
        if kind == "int":
            values[key] = int(values[key])
    return values


def _raw_value(config: Any, cls: str, key: str) -> Any:
    """A setting's value in a loaded config: ``offline.<name>`` or a dotted key of the class's."""
    table, name = _setting_table(config, cls, key)
    return getattr(table, name)


def _setting_table(config: Any, cls: str, key: str) -> tuple[Any, str]:
    """The table of a loaded config that holds setting ``key`` (as :func:`_raw_value` reads
    it), and the setting's name in it."""
    if key.startswith("offline."):
        return config.offline, key.split(".", 1)[1]
    *parents, name = key.split(".")
    table = config.per_category[cls]
    for part in parents:
        table = getattr(table, part)
    return table, name


def search_space(
    cls: str, mode: str, *, r_scale: bool = True
) -> dict[str, tuple[str, float, float]]:
    """The settings searched for ``cls`` in ``mode`` (online or offline). ``r_scale``: whether
    the base config sets the filter's r from the detections' noise (``pose.r_scale`` > 0, then
    searched); if not, the fixed r itself is searched (``pose.ca.r``)."""
    space = dict(OFFLINE_SPACE if mode == "offline" else ONLINE_SPACE)
    if not r_scale and "pose.r_scale" in space:
        del space["pose.r_scale"]
        space["pose.ca.r"] = ("log", 0.02, 2.0)
    if cls == "pedestrian":
        space.update(PEDESTRIAN_SPACE)
    if cls == "car" and mode == "online":  # (offline, the track score decides instead)
        space.update(CAR_SPACE)
    return space


def suggest(trial: Any, space: dict[str, tuple[str, float, float]]) -> dict[str, Any]:
    """The search space, drawn by an Optuna trial (define-by-run: Ray Tune's OptunaSearch calls
    the same function, app/tune_ray.py)."""
    draw: dict[str, Callable[..., Any]] = {
        "int": lambda k, lo, hi: trial.suggest_int(k, int(lo), int(hi)),
        "float": lambda k, lo, hi: trial.suggest_float(k, lo, hi),
        "log": lambda k, lo, hi: trial.suggest_float(k, lo, hi, log=True),
    }
    return {key: draw[kind](key, lo, hi) for key, (kind, lo, hi) in space.items()}


def _by_level(
    metrics: dict[tuple[str, str], dict[str, Any]], levels: Sequence[str]
) -> dict[str, dict[str, dict[str, Any]]]:
    """{level: {detector: metrics}} of the noisy levels (clean is reported on its own)."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for (det, level), m in metrics.items():
        if level != CLEAN:
            out.setdefault(level, {})[det] = m
    return {level: out[level] for level in levels if level in out}


def _evaluate_dir(
    result_dir: Path,
    label_dir: Path,
    lengths: dict[str, int],
    cls: str,
    labels_checked: bool = False,
) -> dict[str, Any]:
    from tracker.eval.kitti import evaluate_kitti

    return evaluate_kitti(
        label_dir=label_dir,
        result_dir=result_dir,
        seq_lengths=lengths,
        classes=[cls],
        labels_checked=labels_checked,
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
    for level, per_det in record.get("cross_validated_noise", {}).items():
        for det, m in per_det.items():
            clean = record["cross_validated"][det]["HOTA"]
            print(
                f"{det:12s} {level}: HOTA cross-validated {m['HOTA']:.2f} "
                f"({m['HOTA'] - clean:+.2f} from clean)"
            )
    print("settings to ship:", json.dumps(record["final"]["overrides"]))
