"""Held-out figures of offline mode (`kitti_offline`: the online settings + post-processing).

    python bench/offline_from_online.py [docs/tune/car_online.json] [--kitti-root ROOT]
        [--choose KEY=V1,V2,... ...] [--choose-online] [--after CHOICE.json]
        [--noise-seed SEED[,SEED...]] [--out RECORD.json]

For each fold of a `mctrack tune --mode online` record, the fold's chosen settings (with score
profiles fitted on the fold's training sequences, as the tune does) track the fold's held-out
sequences online and offline. The online figure reproduces the record's cross-validated one; the
offline figure is the held-out figure of offline mode.

`--choose` names offline-only settings (`offline.<key>`, or a category key such as
`lifecycle.max_misses_tentative`, applied in offline mode only) and their candidates. Each fold
then takes the combination with the best objective of the tune (HOTA averaged over the record's
detectors and its clean and perturbed detections) in offline mode on its training sequences,
and tracks its held-out sequences with it (and with the grid's first point, the plain values,
for comparison), on its clean detections and on the objective's noisy ones: the choice made
the same way on all the sequences with the shipped settings and profiles ships where choosing
per fold holds out better on that objective (records before December 2026 hold the clean
held-out figure only, and were judged by it). With
`--choose-online` the settings are online ones, chosen the same way in online mode and applied
in both modes: one value added to a searched record without searching the rest again.
`--after CHOICE.json` holds such a record's choices (each fold's own, and the final one) while
choosing the next. The noise is
drawn with the record's perturbation seed, or once per seed of `--noise-seed` (the objective
averages a level's draws first): a choice between values a few tenths of HOTA apart can turn
on one draw of the noise. `--out` writes the whole record
(docs/tune/<class>_offline_choice.json; an online choice: docs/tune/<record>_choice.json).

A setting that a `--choose-online` record ships (such as the pedestrians' `bev.gate_motion_m`) is
not in the tune record's folds: without `--after` that record, every fold runs with the shipped
value, which was chosen on all the sequences (a warning says so).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import multiprocessing
import sys
import time
from pathlib import Path
from typing import Any

from app import tune
from app.inputs import default_kitti_root
from app.tune import (
    Objective,
    _evaluate_dir,
    _track_and_score,
    draw_levels,
    folds_by_frames,
    level_frames,
    noise_seed_value,
    objective_value,
    record_seeds,
    seed_list,
    settings_to_overrides,
)
from tracker.calibration import find_profile
from tracker.config import load_config
from tracker.eval.calibrate import fit_profile, fit_self_profile
from tracker.eval.perturb import CLEAN, PerturbSpec
from tracker.io.convert.kitti import VALIDATION_SEQS, convert_kitti
from tracker.io.fileio import work_folder, write_text_atomic

ROOT = Path(__file__).resolve().parents[1]

MODES = {"online": "kitti", "offline": "kitti_offline"}


def held_out(
    record_path: Path,
    root: Path,
    *,
    detectors: list[str] | None = None,
    modes: tuple[str, ...] = ("online", "offline"),
    profile: str = "labels",
    choose: dict[str, list[Any]] | None = None,
    noise_seeds: tuple[int, ...] | None = None,
    workers: int = 2,
    choose_online: bool = False,
    after: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """``{detector: {mode: metrics}}`` over the record's held-out folds.

    ``detectors``: those to track (default: the record's own; others are held out as detectors
    too). ``profile``: "labels", each fold's score profile fitted on its training sequences (as
    the tune does), or "self", the label-free profile fitted on the detections themselves (what
    a detector without a profile gets). ``choose``: offline-only settings and their candidates,
    chosen per fold on its training sequences (module docstring); the choices are returned
    under ``"choice"``, and offline mode at the grid's first point under ``"offline_first"``.
    ``choose_online``: the settings are online ones, chosen in online mode and applied in both
    (online mode at the grid's first point under ``"online_first"``). ``after``: an earlier
    ``choose_online`` record of the same tune; each fold keeps its own choice from it (and the
    final choice its final one), in both modes.
    ``noise_seeds``: the perturbation seeds of the objective's noisy levels (default: the
    record's)."""
    if profile not in ("labels", "self"):
        raise ValueError(f"profile: expected 'labels' or 'self', got {profile!r}")
    record = json.loads(record_path.read_text())
    if record["mode"] != "online":
        raise SystemExit(f"{record_path}: an online tune record is needed")
    if after is not None:
        record = hold_choices(record, after, record_path)
    held = set(record["cv"][0]["best"]) | (set(choose) if choose and choose_online else set())
    if "bev.gate_motion_m" not in held and math.isfinite(
        load_config("kitti").per_category[record["class"]].bev.gate_motion_m
    ):
        print(
            f"warning: {record['class']}'s bev.gate_motion_m is the shipped one in every fold"
            " (chosen on all sequences); hold its per-fold choice with --after"
            " docs/tune/<its choice record>",
            file=sys.stderr,
        )
    cls = record["class"]
    label_dir = root / "training" / "label_02"
    dets = detectors or record["detectors"]
    choose_mode = "online" if choose_online else "offline"
    if choose and choose_mode not in modes:
        raise ValueError(f"choose: {choose_mode} settings need the {choose_mode} mode")
    # the tune's noise levels (each perturbs the calibrated frames) join the objective when
    # choosing; the held-out figures are the clean ones
    specs = {CLEAN: None} | (
        {lv: PerturbSpec(**spec) for lv, spec in record.get("noise", {}).items()} if choose else {}
    )
    seeds = noise_seeds or record_seeds(record)
    levels = tuple(draw_levels(list(specs), seeds))
    lengths: dict[str, int] = {}
    grid = (
        [dict(zip(choose, combo, strict=True)) for combo in itertools.product(*choose.values())]
        if choose
        else []
    )
    out: dict[str, Any] = {}
    choice: dict[str, Any] = {
        "grid": choose, "levels": list(specs), "noise_seed": noise_seed_value(seeds), "folds": []
    }  # fmt: skip
    added: list[tuple[str, str, str]] = []  # the _FRAMES keys this call sets
    try:
        for det in dets:  # calibrated (and perturbed) frames per (detector, fold, level)
            raw, gt = convert_kitti(root, seqs=VALIDATION_SEQS, detector=det, classes=[cls])
            lengths = {s: len(f) for s, f in raw.items()}
            if [f["test"] for f in record["cv"]] != folds_by_frames(lengths, len(record["cv"])):
                raise SystemExit(f"{record_path}: its folds are not this kit's")
            self_profile = fit_self_profile(det, raw, [cls]) if profile == "self" else None
            profiles = {}
            if choose:  # the final choice's profile: the shipped one (or the label-free one)
                profiles["all"] = find_profile(det) if self_profile is None else self_profile
            for k, fold in enumerate(record["cv"]):
                train = {s: raw[s] for s in lengths if s not in fold["test"]}
                profiles[f"fold{k}"] = (
                    self_profile
                    if self_profile is not None
                    else fit_profile(det, train, gt or {}, [cls])
                )
            for key, fitted in profiles.items():
                for level, frames in level_frames(raw, fitted, specs, seeds).items():
                    added.append((det, key, level))
                    tune._FRAMES[det, key, level] = frames
        with (
            work_folder("folds") as tmp,
            multiprocessing.get_context("fork").Pool(workers) as pool,
        ):
            work = Path(tmp)

            def pick(key: str, seqs: list[str], settings: dict[str, Any]) -> dict[str, Any]:
                """The grid point with the best objective (in ``choose_mode``) on ``seqs``."""
                objective = Objective(tuple(dets), levels, MODES[choose_mode],
                                      {"categories": [cls]}, cls, str(label_dir))  # fmt: skip
                scores, exact = {}, {}
                for i, point in enumerate(grid):
                    where = work / "choose" / key / str(i)
                    metrics = objective.metrics(key, seqs, {**settings, **point}, where, pool.map)
                    exact[i] = objective_value(metrics)
                    scores[json.dumps(point)] = round(exact[i], 3)
                best = grid[max(exact, key=lambda i: exact[i])]  # the first of ties
                return {"objective": scores, "chosen": best}

            # with a grid, the chosen mode also runs at its first point (the plain values): what
            # choosing per fold is compared with
            runs = {mode: MODES[mode] for mode in modes}
            if grid:
                runs[f"{choose_mode}_first"] = MODES[choose_mode]
            # the two runs a choice is judged by are also tracked on the held-out folds' noisy
            # detections: the choice ships where it holds out better on the objective it was
            # chosen by (clean and noisy), not on the clean figure alone
            judged = [choose_mode, f"{choose_mode}_first"] if grid else []
            noisy = [lv for lv in levels if lv != CLEAN]
            tasks = []
            for k, fold in enumerate(record["cv"]):
                extra: dict[str, dict[str, Any]] = {}
                if grid:
                    train = [s for s in lengths if s not in fold["test"]]
                    picked = pick(f"fold{k}", train, fold["best"])
                    choice["folds"].append({"test": fold["test"], **picked})
                    extra = {"offline": picked["chosen"], f"{choose_mode}_first": grid[0]}
                    if choose_online:
                        extra["online"] = picked["chosen"]
                for det in dets:
                    for run, config in runs.items():
                        settings = {**fold["best"], **extra.get(run, {})}
                        overrides = {"categories": [cls], **settings_to_overrides(cls, settings)}
                        where = str(work / run / det)
                        tasks.append(((det, f"fold{k}", CLEAN), fold["test"], config, overrides,
                                      where, str(label_dir), cls, False, False))  # fmt: skip
                        for level in noisy if run in judged else []:
                            tasks.append(((det, f"fold{k}", level), fold["test"], config,
                                          overrides, str(work / f"{run}@@{level}" / det),
                                          str(label_dir), cls, False, False))  # fmt: skip
            pool.map(_track_and_score, tasks)
            for det in dets:
                out[det] = {
                    run: _evaluate_dir(work / run / det, label_dir, lengths, cls) for run in runs
                }
            if judged:
                scored = {
                    run: {
                        (det, level): out[det][run]
                        if level == CLEAN
                        else _evaluate_dir(work / f"{run}@@{level}" / det, label_dir, lengths, cls)
                        for det in dets
                        for level in levels
                    }
                    for run in judged
                }
                choice["held_out_objective"] = {
                    run: round(objective_value(m), 3) for run, m in scored.items()
                }
                choice["held_out_noise"] = {
                    run: {
                        f"{det} {level}": m[det, level]["HOTA"]
                        for det, level in m
                        if level in noisy
                    }
                    for run, m in scored.items()
                }
            if grid:
                choice["final"] = pick("all", list(lengths), record["final"]["best"])
                out["choice"] = choice
    finally:
        for key in added:
            tune._FRAMES.pop(key, None)
    return out


def hold_choices(record: dict[str, Any], after: dict[str, Any], name: Any) -> dict[str, Any]:
    """``record`` (an online tune's, file ``name``) with each fold's settings, and the final
    ones, joined by that fold's (the final) choice of ``after``: a ``--choose-online`` record
    made for the same tune record."""
    if after.get("online_record") != Path(name).name:
        raise SystemExit(
            f"--after: made for {after.get('online_record')!r}, not for {Path(name).name!r}"
        )
    if not all("online_first" in m for m in after["held_out"].values()):
        raise SystemExit("--after: not a --choose-online record (its choice is offline-only)")
    choice = after["choice"]
    if [f["test"] for f in choice["folds"]] != [f["test"] for f in record["cv"]]:
        raise SystemExit(f"{name}: --after's folds are not this record's")
    cv = [
        {**fold, "best": {**fold["best"], **held["chosen"]}}
        for fold, held in zip(record["cv"], choice["folds"], strict=True)
    ]
    final = {**record["final"], "best": {**record["final"]["best"], **choice["final"]["chosen"]}}
    return {**record, "cv": cv, "final": final}


def _parse_choose(items: list[str]) -> dict[str, list[Any]]:
    grid = {}
    for item in items:
        key, _, values = item.partition("=")
        if not key or not values:
            raise SystemExit(f"--choose {item!r}: expected KEY=V1,V2,...")
        grid[key] = [json.loads(v) for v in values.split(",")]
    return grid


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("record", nargs="?", default=str(ROOT / "docs/tune/car_online.json"))
    parser.add_argument("--kitti-root", type=Path, default=None)
    parser.add_argument("--choose", action="append", default=[], metavar="KEY=V1,V2,...")
    parser.add_argument(
        "--choose-online",
        action="store_true",
        help="the --choose settings are online ones (chosen online, applied in both modes)",
    )
    parser.add_argument(
        "--after",
        type=Path,
        default=None,
        metavar="CHOICE.json",
        help="an earlier --choose-online record of the same tune: its choices are held",
    )
    parser.add_argument(
        "--noise-seed",
        type=seed_list,
        default=None,
        metavar="SEED[,SEED...]",
        help="perturbation seed(s) of the objective's noise (default: the record's)",
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None, help="write the record here (JSON)")
    args = parser.parse_args()
    start = time.perf_counter()
    figures = held_out(
        Path(args.record),
        args.kitti_root or default_kitti_root(),
        choose=_parse_choose(args.choose) or None,
        noise_seeds=args.noise_seed,
        workers=args.workers,
        choose_online=args.choose_online,
        after=json.loads(args.after.read_text()) if args.after else None,
    )
    choice = figures.pop("choice", None)
    if choice:
        for fold in choice["folds"]:
            print(
                f"fold {fold['test']}: {fold['chosen']}  (training objective {fold['objective']})"
            )
        print(
            f"final (all sequences): {choice['final']['chosen']}  ({choice['final']['objective']})"
        )
        judged = choice.get("held_out_objective", {})
        print(
            "held-out objective (clean and noisy): "
            + ", ".join(f"{run} {value:.3f}" for run, value in judged.items())
        )
    for det, by_mode in figures.items():
        on, off = by_mode["online"], by_mode["offline"]
        first_mode = "online" if args.choose_online else "offline"
        first = by_mode.get(f"{first_mode}_first")
        print(
            f"{det:12s} held out: online {on['HOTA']:.2f}  offline {off['HOTA']:.2f}"
            f"  ({off['HOTA'] - on['HOTA']:+.2f}; FP {on['FP']} -> {off['FP']})"
            + (f"  {first_mode} at the grid's first point {first['HOTA']:.2f}" if first else ""),
            flush=True,
        )
    if args.out:
        cls = json.loads(Path(args.record).read_text())["class"]
        record = {"class": cls, "online_record": Path(args.record).name, "held_out": figures,
                  "choice": choice, "command": " ".join(["python bench/offline_from_online.py",
                  f"docs/tune/{Path(args.record).name}", *(f"--choose {c}" for c in args.choose),
                  *(["--choose-online"] if args.choose_online else []),
                  *([f"--after docs/tune/{args.after.name}"] if args.after else []),
                  *([f"--noise-seed {','.join(map(str, args.noise_seed))}"]
                    if args.noise_seed else [])]),
                  "seconds": round(time.perf_counter() - start, 1)}  # fmt: skip
        write_text_atomic(args.out, [json.dumps(record, indent=1) + "\n"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
