"""What each command writes in its output folder: one list per command, read by the command
itself (a failed run removes what it wrote of them) and by every command that replaces an
earlier run in its folder (so the folder never mixes two runs). Below every app module: no app
imports here."""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from pathlib import Path, PurePosixPath
from typing import Any

from tracker.errors import InputError
from tracker.io.fileio import safe_filename

#: What the nuScenes devkit's TrackingEval writes in its output folder (besides plots/)
DEVKIT_FILES = ("metrics_summary.json", "metrics_details.json")

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
        "motion_velocity.png", *(f"eval/{n}" for n in DEVKIT_FILES), "recordings/*.rrd",
        ".scenes/*",
    ),
    "waymo": (
        "summary.json", "tracks.json", "gt.json", "motion.md", "motion_velocity.png",
        "results/*/*.npz", "recordings/*.rrd", ".scenes/*",
    ),
    # (its --out defaults to the tracks file's folder: a run's)
    "eval": (
        "eval.json", "eval.md", "motion_velocity.png", "eval_results.json",
        *(f"nuscenes_eval/{n}" for n in DEVKIT_FILES),
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
#: The other patterns of files named by input data, in a run folder: of these too only the
#: earlier run's (its summary.json lists them: :func:`earlier_named_files`) are removed by a
#: new run, never anyone's other file there (a user's recordings/mine.rrd).
NAMED = ("recordings/*.rrd", "results/*/*.npz")
#: The recording per scene of a run with --record (one of :data:`NAMED`): a run without it
#: writes none, so a recordings/<scene>.rrd there is not its to rewrite (a user's stays)
RECORDING = "recordings/*.rrd"
#: The largest summary.json (compare.json) read to tell whether it is a run's (what it lists).
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


def outputs_of(
    command: str, scenes: Iterable[str] | None = None, *, record: bool = True
) -> tuple[str, ...]:
    """What ``command`` writes in its folder, temporary files included: what a failed run of
    it removes (those it wrote), and what it refuses to take as an input there. ``scenes``:
    the scenes a run writes a file of, once known: each per-scene pattern (:data:`PER_SCENE`,
    :data:`NAMED`: its last ``*`` the scene) becomes their files (none for no scenes: `track`
    without --kitti-results); of :data:`RECORDING` only with ``record`` (the run's --record)."""
    patterns = FILES[command]
    if scenes is not None:
        names = [safe_filename(s) for s in scenes]  # (no glob character: [A-Za-z0-9._%-])
        named = names if record else []
        patterns = tuple(
            q
            for p in patterns
            for q in (
                [_of_scene(p, n) for n in (named if p == RECORDING else names)]
                if p in (*PER_SCENE, *NAMED)
                else [p]
            )
        )
    return _with_temps(patterns)


def _of_scene(pattern: str, name: str) -> str:
    """``pattern``'s file of scene ``name``: its last ``*`` (results/*/*.npz: results/*/n.npz)."""
    head, _, tail = pattern.rpartition("*")
    return f"{head}{name}{tail}"


def outputs_replaced_by(
    command: str,
    folder: Path | None = None,
    scenes: Iterable[str] | None = None,
    *,
    record: bool = True,
) -> tuple[str, ...]:
    """What a run of ``command`` removes of an earlier run in its folder, once its inputs are
    accepted: for a run (:data:`RUN_COMMANDS`), everything a run folder may hold of any
    command (:data:`RUN_FOLDER`: a `track` into a `kitti` run's folder removes its motion.md
    and recordings too); for the others, their own outputs.

    Of the files per scene (:data:`PER_SCENE`, data/<scene>.txt; :data:`NAMED`, the
    recordings and Waymo results), given the run's ``folder``: only those the earlier run there
    wrote (:func:`earlier_scene_files`, :func:`earlier_named_files`) and this run's own (of
    ``scenes``; its recordings only with ``record``), not every data/*.txt or
    recordings/*.rrd: a file of anyone's there stays."""
    commands = RUN_FOLDER if command in RUN_COMMANDS else (command,)
    if folder is None or command not in RUN_COMMANDS:
        return tuple(dict.fromkeys(p for c in commands for p in outputs_of(c)))
    listed = (*PER_SCENE, *NAMED)
    shared = [p for c in commands for p in FILES[c] if p not in listed]
    # (a per-scene file's temporary name, .<scene>.txt.<pid>.<random>.tmp, is only ever ours)
    temps = [q for p in listed for q in _with_temps((p,)) if q != p]
    earlier = [*(earlier_scene_files(folder) or []), *(earlier_named_files(folder) or [])]
    patterns = [*_with_temps(tuple(shared)), *temps, *_with_temps(tuple(earlier))]
    return tuple(dict.fromkeys([*patterns, *outputs_of(command, scenes, record=record)]))


def is_run_summary(summary: object) -> bool:
    """Whether ``summary`` (a summary.json's JSON) is a run's: an object naming one of
    :data:`RUN_COMMANDS` as its "command" (or, written before that field, holding the
    "detection_fates" every run's has). Anyone's file of that name (``{}``) is not."""
    if not isinstance(summary, dict):
        return False
    if "command" in summary:
        return summary["command"] in RUN_COMMANDS
    return isinstance(summary.get("detection_fates"), dict)


def _json_file(path: Path) -> object:
    """``path``'s JSON, or None: a file of anyone's name in a run folder, read only when it is
    a regular file of at most :data:`_SUMMARY_MAX_BYTES` (a FIFO would hang the run, a link to
    /dev/zero fill its memory)."""
    try:
        if not path.is_file() or path.stat().st_size > _SUMMARY_MAX_BYTES:
            return None
        return json.loads(path.read_bytes())
    except (OSError, ValueError, RecursionError):  # (unreadable, not JSON, not UTF-8)
        return None


def _run_summary(path: Path) -> dict[str, Any] | None:
    """``path``'s JSON when it is a run's summary.json (:func:`is_run_summary`), else None."""
    summary = _json_file(path)
    return summary if isinstance(summary, dict) and is_run_summary(summary) else None


#: A per-scene file as a summary may list it: a :data:`PER_SCENE` pattern with a
#: safe_filename for ``*``, nothing else (a summary is a file anyone may edit: no glob
#: character, no other folder)
_LISTED_SCENE_FILES = tuple(
    re.compile(re.escape(before) + r"[A-Za-z0-9_%~-][A-Za-z0-9._%~-]*" + re.escape(after))
    for before, after in (p.split("*") for p in PER_SCENE)
)


def earlier_scene_files(folder: Path) -> list[str] | None:
    """The files per scene (:data:`PER_SCENE`, relative to ``folder``) the run in ``folder``
    wrote, as its summary.json says: the files its "outputs" list names (`track`), those of
    its "sequences" (`kitti`), none for a command that writes none (`nuscenes`, `waymo`).
    None when that is not known: a run cut short (its scene parts, no summary), a summary
    that says neither."""
    summary = _run_summary(folder / "summary.json")
    if summary is None:
        return None
    outputs = summary.get("outputs")
    if isinstance(outputs, list):
        paths = [o.get("path") for o in outputs if isinstance(o, dict)]
        listed = [p for p in paths if isinstance(p, str)]
        return sorted(p for p in listed if any(r.fullmatch(p) for r in _LISTED_SCENE_FILES))
    sequences = summary.get("sequences")
    if isinstance(sequences, list) and all(isinstance(q, str) for q in sequences):
        return sorted(p.replace("*", safe_filename(q)) for p in PER_SCENE for q in sequences)
    command = summary.get("command")
    if command in RUN_COMMANDS and not set(FILES[command]) & set(PER_SCENE):
        return []
    return None


#: A recording's name as a summary may list it (the folder it names aside): a safe_filename
_LISTED_RECORDING = re.compile(r"[A-Za-z0-9_%~-][A-Za-z0-9._%~-]*\.rrd")


def _listed_paths(value: object) -> list[str]:
    """The strings of a summary's "recordings": a list of paths (nuscenes, waymo) or an object
    of scene: path (kitti, compare); anything else none."""
    items = value.values() if isinstance(value, dict) else value
    return [v for v in items if isinstance(v, str)] if isinstance(items, Iterable) else []


def _recordings_listed(listing: object) -> list[str]:
    """The recordings (relative to the folder) a summary.json or compare.json (``listing``'s
    JSON) lists under "recordings", each taken by its name alone, and only as
    recordings/<safe name>.rrd of a path whose folder is recordings/ (the file is anyone's to
    edit; its paths were absolute, or relative to where the command ran)."""
    paths = _listed_paths(listing.get("recordings")) if isinstance(listing, dict) else []
    return sorted(
        {
            f"recordings/{PurePosixPath(p).name}"
            for p in paths
            if PurePosixPath(p).parent.name == "recordings"
            and _LISTED_RECORDING.fullmatch(PurePosixPath(p).name)
        }
    )


def compare_recordings(folder: Path) -> list[str]:
    """The recordings a `compare --record` wrote in ``folder``, as its compare.json there lists
    them (:func:`_recordings_listed`): what the next comparison there removes (a user's
    recordings/mine.rrd stays). None listed where it lists none, or is no comparison's."""
    return _recordings_listed(_json_file(folder / "compare.json"))


def run_recordings(folder: Path) -> list[str]:
    """The recordings the run in ``folder`` wrote, as its summary.json lists them (none where
    there is no run's summary): a comparison there leaves them alone."""
    return _recordings_listed(_run_summary(folder / "summary.json"))


def earlier_named_files(folder: Path) -> list[str] | None:
    """The files of :data:`NAMED` (relative to ``folder``) the run in ``folder`` wrote, as its
    summary.json says: the recordings its "recordings" lists (and those a `compare --record`
    there lists in its compare.json), a `waymo` run's results/<type>/<segment>.npz of its
    "segments". A listed recording is taken by its name alone, and only as
    recordings/<safe name>.rrd of a path whose folder is recordings/ (a summary is anyone's to
    edit; its paths were absolute, or relative to where the run ran). None when the run was
    cut short (its scene parts, no summary): then which files are its is not known."""
    summary = _run_summary(folder / "summary.json")
    if summary is None:
        return None
    # (compare.json goes with the run: its recordings too)
    named = set(_recordings_listed(summary)) | set(compare_recordings(folder))
    segments = summary.get("segments")
    if summary.get("command") == "waymo" and isinstance(segments, list):
        from tracker.io.waymo_writer import RESULT_TYPES

        names = [safe_filename(q) for q in segments if isinstance(q, str)]
        named |= {f"results/{t}/{n}.npz" for t in RESULT_TYPES for n in names}
    return sorted(named)


def holds_a_run(folder: Path) -> bool:
    """Whether a run has written ``folder``: its summary.json (:func:`_run_summary`), or its
    scene parts (:data:`RUN_PARTS`, a run cut short). Only then are the files there an earlier
    run's, which a new run removes (:func:`outputs_replaced_by`): a results.json or gt.json
    alone could be anyone's."""
    return _run_summary(folder / "summary.json") is not None or (folder / RUN_PARTS).is_dir()


def outputs_at_stake(
    command: str, folder: Path, scenes: Iterable[str] | None = None, *, record: bool = True
) -> tuple[str, ...]:
    """What a run of ``command`` into ``folder`` writes or removes there, once its inputs are
    accepted (an input among them is refused): in a folder holding a run
    (:func:`holds_a_run`), all it replaces of it (:func:`outputs_replaced_by`: of data/*.txt,
    the earlier run's files and its own); else only what it writes (:func:`outputs_of`, of
    ``scenes`` where known: data/<scene>.txt of its own scenes), which is all it may touch
    there. Called before any work: where the earlier run's files per scene are not known
    (:func:`earlier_scene_files`, :func:`earlier_named_files`), a data/*.txt (a
    recordings/*.rrd, results/*/*.npz) this run does not write is refused (InputError naming
    it), as it may be anyone's or the earlier run's. ``record``: whether the run writes its
    scenes' recordings (--record)."""
    if command not in RUN_COMMANDS or not holds_a_run(folder):
        return outputs_of(command, scenes, record=record)
    at_stake = outputs_replaced_by(command, folder, scenes, record=record)
    unknown = [
        *(PER_SCENE if earlier_scene_files(folder) is None else ()),
        *(NAMED if earlier_named_files(folder) is None else ()),
    ]
    _refuse_unknown_files(folder, at_stake, unknown)
    return at_stake


#: A Waymo run's result files (one of :data:`NAMED`): the submission step (pred_bin.py) reads
#: every file under results/, so one of no run's there would enter it unsaid
WAYMO_RESULTS = "results/*/*.npz"


def refuse_foreign_results(folder: Path, at_stake: tuple[str, ...]) -> None:
    """InputError naming a :data:`WAYMO_RESULTS` file in ``folder`` that is not ``at_stake``
    (:func:`outputs_at_stake`: the earlier run's segments', this run's own), and how many
    more: kept by design (a user's file), it would silently enter this run's submission.
    Called by `waymo` before any work."""
    _refuse_unknown_files(
        folder,
        at_stake,
        (WAYMO_RESULTS,),
        reason=(
            f"a result file of neither the run in {folder} nor this one, and the submission "
            "(pred_bin.py) reads every file under results/"
        ),
    )


def _refuse_unknown_files(
    folder: Path, at_stake: tuple[str, ...], patterns: Iterable[str], *, reason: str | None = None
) -> None:
    """InputError naming a file of ``patterns`` (:data:`PER_SCENE`, :data:`NAMED`) in
    ``folder`` that is not ``at_stake`` (this run's), and how many more there are (all fixed
    in one go): the earlier run there does not say which are its own, so that one may be
    anyone's (kept, the folder would mix two runs; removed, a user's file would be lost).
    ``reason``: why such a file is refused, instead (of one that is known not to be a run's)."""
    ours = {p for pattern in at_stake for p in folder.glob(pattern)}
    unknown: list[tuple[Path, str]] = []
    for pattern in patterns:
        if (folder / PurePosixPath(pattern).parent).is_symlink():
            continue  # (a linked data/ leads anywhere: no run removes a file through it)
        unknown += [
            (path, pattern)
            for path in sorted(folder.glob(pattern))
            if path not in ours and (path.is_file() or path.is_symlink())
        ]
    if not unknown:
        return
    path, pattern = unknown[0]
    more = f" (and {len(unknown) - 1} more)" if len(unknown) > 1 else ""
    which, them = ("these files", "them") if more else ("this file", "it")
    if reason is None:
        why = (
            f"its summary.json does not list its {pattern} files"
            if _run_summary(folder / "summary.json") is not None
            else f"it was cut short ({RUN_PARTS}/ is there, no summary.json)"
        )
        reason = f"{folder} holds an earlier run, and {why}: {which} may be anyone's"
    raise InputError(f"{path}{more}: {reason}; move or remove {them}, or give another --out")
