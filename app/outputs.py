"""What each command writes in its output folder: one list per command, read by the command
itself (a failed run removes what it wrote of them) and by every command that replaces an
earlier run in its folder (so the folder never mixes two runs). Below every app module: no app
imports here."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path, PurePosixPath

from tracker.io.fileio import safe_filename

#: Each command's output files in --out (globs relative to it; .scenes/: the scene parts of a
#: run while it runs, see app.scenes.PARTS_DIR). The temporary files each is written under
#: (``.<name>.<pid>.<random>.tmp``, tracker.io.fileio.temp_name) come with it (:func:`outputs_of`).
FILES: dict[str, tuple[str, ...]] = {
    "track": ("summary.json", "tracks.json", "self_profile.toml", "data/*.txt", ".scenes/*"),
    "kitti": (
        "summary.json", "tracks.json", "self_profile.toml", "motion.md", "motion_velocity.png",
        "data/*.txt", "recordings/*.rrd", "recordings/causes.md", ".scenes/*",
    ),
    "nuscenes": (
        "summary.json", "results.json", "tracks.json", "gt.json", "motion.md",
        "motion_velocity.png", "eval/*.json", "recordings/*.rrd", ".scenes/*",
    ),
    "waymo": (
        "summary.json", "tracks.json", "gt.json", "motion.md", "motion_velocity.png",
        "results/*/*.npz", "recordings/*.rrd", ".scenes/*",
    ),
    # (its --out defaults to the tracks file's folder: a run's)
    "eval": (
        "eval.json", "eval.md", "motion_velocity.png", "eval_results.json",
        "nuscenes_eval/*.json",
    ),
    "compare": ("compare.json", "compare.md", "recordings/*.rrd"),
    "robustness": (
        "robustness.json", "robustness.md", "runs/*/clean/*.txt", "runs/*/seed*/*.txt",
    ),
    # (written at its end; its Ray Tune state, ray_tune/, is what a resume reads: kept)
    "tune": ("tune.json", "best.toml"),
    # (what an earlier report's folder loses first: its compare.json before a report without
    # --compare, its shots of other runs or events; index.html, written last, marks a report's
    # folder and is replaced. There every file these match goes, anyone's too: any
    # plots/*.svg; a plots/ file of another name stays, and in a folder without index.html
    # nothing is removed, only the report's own names rewritten)
    "report": (
        "compare.json", "plots/*.svg", "plots/motion_velocity.png", "shots/*/*.png",
        "b/shots/*/*.png",
    ),
}  # fmt: skip

#: The commands whose run fills a folder of its own (its scenes' files, tracks.json and the
#: summary.json written last, which marks the run complete).
RUN_COMMANDS = ("track", "kitti", "nuscenes", "waymo")
#: Whose outputs a run folder may hold: the runs', and what is written beside one (`mctrack
#: eval` writes in the tracks file's folder by default; `mctrack compare` may write in a run
#: folder). All of them describe the run in the folder, so a new run there removes them all.
RUN_FOLDER = (*RUN_COMMANDS, "eval", "compare")
#: Where a run's scene parts are while it runs (app.scenes.PARTS_DIR): a folder holding them
#: is a run's (one cut short). Else only its summary.json, written last, marks a run's folder.
RUN_PARTS = ".scenes"
#: The patterns of a file per scene (sequence), ``*`` its name (tracker.io.fileio.path_in): a
#: run writes those of its own scenes alone (:func:`outputs_of` with ``scenes``).
PER_SCENE = ("data/*.txt",)
#: The largest summary.json read to tell whether it is a run's.
_SUMMARY_MAX_BYTES = 64 << 20


def _with_temps(patterns: tuple[str, ...]) -> tuple[str, ...]:
    """The patterns, each followed by its temporary files' (``data/*.txt``:
    ``data/.*.txt.*.tmp``); a pattern of any name (``.scenes/*``) has them already."""
    out: list[str] = []
    for pattern in patterns:
        out.append(pattern)
        path = PurePosixPath(pattern)
        if path.name != "*":
            out.append(str(path.with_name(f".{path.name}.*.tmp")))
    return tuple(out)


def outputs_of(command: str, scenes: Iterable[str] | None = None) -> tuple[str, ...]:
    """What ``command`` writes in its folder, temporary files included: what a failed run of
    it removes (those it wrote), and what it refuses to take as an input there. ``scenes``:
    the scenes a run writes a file of, once known: each per-scene pattern (:data:`PER_SCENE`)
    becomes their files (none for no scenes: `track` without --kitti-results)."""
    patterns = FILES[command]
    if scenes is not None:
        names = [safe_filename(s) for s in scenes]  # (no glob character: [A-Za-z0-9._%-])
        patterns = tuple(
            q
            for p in patterns
            for q in ([p.replace("*", n) for n in names] if p in PER_SCENE else [p])
        )
    return _with_temps(patterns)


def outputs_replaced_by(command: str) -> tuple[str, ...]:
    """What a run of ``command`` removes of an earlier run in its folder, once its inputs are
    accepted: for a run (:data:`RUN_COMMANDS`), everything a run folder may hold of any
    command (:data:`RUN_FOLDER`: a `track` into a `kitti` run's folder removes its motion.md
    and recordings too); for the others, their own outputs."""
    commands = RUN_FOLDER if command in RUN_COMMANDS else (command,)
    return tuple(dict.fromkeys(p for c in commands for p in outputs_of(c)))


def is_run_summary(summary: object) -> bool:
    """Whether ``summary`` (a summary.json's JSON) is a run's: an object naming one of
    :data:`RUN_COMMANDS` as its "command" (or, written before that field, holding the
    "detection_fates" every run's has). Anyone's file of that name (``{}``) is not."""
    if not isinstance(summary, dict):
        return False
    if "command" in summary:
        return summary["command"] in RUN_COMMANDS
    return isinstance(summary.get("detection_fates"), dict)


def _run_summary(path: Path) -> bool:
    """Whether ``path`` is a run's summary.json (:func:`is_run_summary`)."""
    try:
        if not path.is_file() or path.stat().st_size > _SUMMARY_MAX_BYTES:
            return False
        summary = json.loads(path.read_bytes())
    except (OSError, ValueError, RecursionError):  # (unreadable, not JSON, not UTF-8)
        return False
    return is_run_summary(summary)


def holds_a_run(folder: Path) -> bool:
    """Whether a run has written ``folder``: its summary.json (:func:`_run_summary`), or its
    scene parts (:data:`RUN_PARTS`, a run cut short). Only then are the files there an earlier
    run's, which a new run removes (:func:`outputs_replaced_by`): a results.json or gt.json
    alone could be anyone's."""
    return _run_summary(folder / "summary.json") or (folder / RUN_PARTS).is_dir()


def outputs_at_stake(
    command: str, folder: Path, scenes: Iterable[str] | None = None
) -> tuple[str, ...]:
    """What a run of ``command`` into ``folder`` writes or removes there, once its inputs are
    accepted (an input among them is refused): in a folder holding a run
    (:func:`holds_a_run`), all it replaces of it (:func:`outputs_replaced_by`: every
    data/*.txt); else only what it writes (:func:`outputs_of`, of ``scenes`` where known:
    data/<scene>.txt of its own scenes), which is all it may touch there."""
    if command in RUN_COMMANDS and holds_a_run(folder):
        return outputs_replaced_by(command)
    return outputs_of(command, scenes)
