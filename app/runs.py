"""A finished run, read back for `mctrack compare` and `mctrack report`.

A run is either a `mctrack kitti` output folder (``summary.json``, ``data/<seq>.txt``, and with
``--record`` ``recordings/<seq>.rrd``) or a ``tracks.json`` (BaseVersion + velocity) evaluated
against a BaseVersion ground-truth file (``--gt``). Its ID events are recomputed from the
result files with TrackEval's own matching (:func:`tracker.eval.id_switches.result_file_id_events`,
the events the run's evaluation counted); where the run has a recording of a sequence, each
event gets its cause and its ``#K`` from the recording's ``summary/index``.

Everything read here is untrusted input: sequence names from ``summary.json`` only ever name
files inside the run folder (:func:`tracker.io.fileio.path_in`), and the absolute paths a
summary holds are not followed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.outputs import is_run_summary
from tracker.errors import InputError
from tracker.eval.compare import Event, event_record
from tracker.io.fileio import path_in, read_text


@dataclass
class Run:
    """One run: its summary (as written, plus "path"), events and recordings per sequence."""

    name: str
    path: Path
    summary: dict[str, Any]
    events: list[Event]
    recordings: dict[str, Path] = field(default_factory=dict)
    kind: str = "kitti"  # "kitti" (a run folder) or "tracks" (a tracks.json with --gt)
    label_dir: Path | None = None  # a kitti run's label_02 folder (as --labels or its summary)

    @property
    def folder(self) -> Path:
        return self.path if self.path.is_dir() else self.path.parent


def load_run(
    path: str | Path,
    *,
    labels: Path | None = None,
    gt: Path | None = None,
    name: str | None = None,
    command: str = "compare",
) -> Run:
    """Read a run folder or a tracks file (InputError naming the file and field when bad).
    ``command``: the one reading it ("compare", "report"), whose options an error advises."""
    path = Path(path)
    if path.is_dir():
        return _load_kitti_run(path, labels, name or path.name, command)
    if path.is_file():
        if gt is None:
            raise InputError(
                f"{path}: a tracks file needs its ground truth: pass --gt GT.json "
                "(or pass a `mctrack kitti --out` folder)"
            )
        return _load_tracks_run(path, gt, name or path.parent.name or path.name)
    raise InputError(f"{path}: not found (pass a `mctrack kitti --out` folder or a tracks.json)")


def read_summary(folder: Path, command: str = "compare") -> dict[str, Any]:
    """A run folder's summary.json, checked (InputError naming the file and field). ``command``:
    the one reading it ("compare", "report"), whose options an error advises."""
    file = folder / "summary.json"
    if not file.is_file():
        raise InputError(
            f"{folder}: no summary.json (not a finished `mctrack kitti --out` folder; an "
            "interrupted run has none)"
        )
    try:
        summary = json.loads(file.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{file}: malformed JSON ({exc})") from None
    if not isinstance(summary, dict):
        raise InputError(f"{file}: expected a JSON object")
    if not is_run_summary(summary):  # (the rule by which a run replaces its folder's files)
        raise InputError(
            f'{file}: not a run\'s summary.json (no "command" naming an mctrack run: another '
            "tool's file?): pass a `mctrack kitti --out` folder"
        )
    seqs = summary.get("sequences")
    if seqs is None and "input" in summary and "tracks" in summary:
        tracks = folder / "tracks.json"
        if command == "report":  # (report reads run folders alone: it has no --gt)
            advice = (
                "report reads `mctrack kitti --out` folders (compare its tracks file with "
                f"another: mctrack compare {tracks} OTHER_TRACKS --gt GT.json --out DIR)"
            )
        else:
            advice = (
                f"{command} reads `mctrack kitti --out` folders, or tracks files with their "
                f"ground truth ({tracks} --gt GT.json)"
            )
        raise InputError(f"{folder}: a `mctrack track` output folder; {advice}")
    if seqs is None:
        raise InputError(
            f"{file}: no field 'sequences': not the summary of a `mctrack kitti --out` folder"
        )
    if not isinstance(seqs, list) or not all(isinstance(s, str) for s in seqs):
        raise InputError(f"{file}: field 'sequences': expected a list of sequence names")
    scored = summary.get("evaluated_sequences", [])
    if not isinstance(scored, list) or not all(isinstance(s, str) for s in scored):
        raise InputError(f"{file}: field 'evaluated_sequences': expected a list of sequence names")
    classes = summary.get("classes")
    if not isinstance(classes, list) or not all(isinstance(c, str) for c in classes):
        raise InputError(f"{file}: field 'classes': expected a list of class names")
    for key in ("motion", "causes"):
        if key in summary and not isinstance(summary[key], dict | str):
            raise InputError(f"{file}: field {key!r}: expected an object")
    # the shapes compare and report index into (a string or a list there was 'unexpected
    # error'): {class: {...}}, {seq: {class: {...}}}, motion {"metrics": {estimator: {class:
    # {...}}}}, failed {seq: reason}, config {...}
    for key, depth in (
        ("metrics", 2),
        ("per_sequence", 3),
        ("per_sequence_metrics", 3),
        ("failed", 1),
        ("config", 1),
    ):
        if summary.get(key) is not None:
            _check_objects(file, repr(key), summary[key], depth)
            if key.startswith(("metrics", "per_sequence")):  # (shown, plotted, subtracted)
                _check_numbers(file, repr(key), summary[key], depth)
    if isinstance(summary.get("motion"), dict) and "metrics" in summary["motion"]:
        _check_objects(file, "'motion' 'metrics'", summary["motion"]["metrics"], 3)
        _check_numbers(file, "'motion' 'metrics'", summary["motion"]["metrics"], 3, ("note",))
    for key in ("labels", "kitti_root"):
        if summary.get(key) is not None and not isinstance(summary[key], str):
            raise InputError(f"{file}: field {key!r}: expected a folder path")
    # a name listed twice would count its sequence's events twice
    for key, names in (("sequences", seqs), ("evaluated_sequences", scored)):
        twice = sorted({s for s in names if names.count(s) > 1})
        if twice:
            raise InputError(f"{file}: field {key!r}: {', '.join(twice)} listed more than once")
    unknown = [s for s in scored if s not in seqs]
    if unknown:
        raise InputError(
            f"{file}: field 'evaluated_sequences': {', '.join(unknown)} not in 'sequences'"
        )
    return summary


def _check_objects(file: Path, field: str, value: Any, depth: int) -> None:
    """``value`` is a JSON object, and so are its values down to ``depth`` levels
    (InputError naming the field and the keys that lead to the first that is not)."""
    if not isinstance(value, dict):
        raise InputError(f"{file}: field {field}: expected an object")
    if depth > 1:
        for key, inner in value.items():
            _check_objects(file, f"{field} {key!r}", inner, depth - 1)


def _check_numbers(
    file: Path, field: str, value: dict[str, Any], depth: int, text: tuple[str, ...] = ()
) -> None:
    """The values ``depth`` levels down in ``value`` (checked by :func:`_check_objects`) are
    numbers or null (unknown), but those named in ``text`` (InputError naming the first that is
    not: a hand-edited "x" was shown as ``x → 79.177``)."""
    for key, inner in value.items():
        where = f"{field} {key!r}"
        if depth > 1:
            _check_numbers(file, where, inner, depth - 1, text)
        elif key not in text and (
            isinstance(inner, bool) or not isinstance(inner, int | float | None)
        ):
            raise InputError(f"{file}: field {where}: expected a number, got {inner!r}")


def scored_sequences(summary: dict[str, Any]) -> list[str]:
    """The sequences a run tracked and scored (whose events it has): the labelled ones of a
    run over labelled and unlabelled sequences (app.kitti), without the failed ones."""
    failed = summary.get("failed") or {}
    return [s for s in summary.get("evaluated_sequences", summary["sequences"]) if s not in failed]


def _label_dir(summary: dict[str, Any], labels: Path | None, file: Path) -> Path:
    if labels is not None:
        found = labels
    elif isinstance(summary.get("labels"), str):
        found = Path(summary["labels"])
    else:
        from app.inputs import default_kitti_root

        found = default_kitti_root() / "training" / "label_02"
    if not found.is_dir():
        raise InputError(
            f"{file}: labels folder {found} not found: pass --labels DIR (KITTI's label_02)"
        )
    return found


def _load_kitti_run(folder: Path, labels: Path | None, name: str, command: str) -> Run:
    from tracker.eval.id_switches import result_file_id_events

    summary = read_summary(folder, command)
    summary["path"] = str(folder)
    label_dir = _label_dir(summary, labels, folder / "summary.json")
    classes = [c for c in summary["classes"] if c in ("car", "pedestrian", "cyclist")]
    events: list[Event] = []
    recordings: dict[str, Path] = {}
    for seq in scored_sequences(summary):
        result = path_in(folder / "data", seq, ".txt")
        label = path_in(label_dir, seq, ".txt")
        if not result.is_file():
            raise InputError(f"{result}: missing (sequence {seq} of {folder / 'summary.json'})")
        if not label.is_file():
            raise InputError(f"{label}: missing: no labels for sequence {seq}; pass --labels DIR")
        rec = path_in(folder / "recordings", seq, ".rrd")
        index = _recording_index(rec) if rec.is_file() else None
        if index is not None:
            recordings[seq] = rec
        # The recording already holds this evaluation's events (made from the same result
        # file), 5x faster to read than TrackEval's replay; used when its counts agree.
        found = _events_from_index(seq, index, label, summary) if index is not None else None
        if found is not None:
            events += found
            continue
        evaluation = result_file_id_events(result, label, classes=classes)
        events += _with_causes(seq, evaluation.events, index)
    return Run(name, folder, summary, events, recordings, "kitti", label_dir)


_KITTI_CLASS = {"car": "car", "pedestrian": "pedestrian", "cyclist": "cyclist"}


def _events_from_index(
    seq: str, index: Any, label: Path, summary: dict[str, Any]
) -> list[Event] | None:
    """The recording's events, their class from the GT id's type in the label file; None when
    the index lacks anything or its counts differ from the summary's (then: TrackEval)."""
    n = len(index.event_frames)
    lists = (
        index.event_kinds,
        index.event_gt_ids,
        index.event_old_track_ids,
        index.event_new_track_ids,
        index.event_causes,
    )
    if any(len(x) != n for x in lists):
        return None
    types: dict[int, str] = {}
    for line in read_text(label).splitlines():
        parts = line.split()
        if len(parts) > 2 and parts[1].lstrip("-").isdigit():
            types[int(parts[1])] = parts[2].lower()
    out: list[Event] = []
    for k in range(n):
        cls = _KITTI_CLASS.get(types.get(index.event_gt_ids[k], ""))
        if cls is None:
            return None
        out.append(
            {
                "sequence": seq,
                "kind": "Frag" if index.event_kinds[k] else "IDSW",
                "frame": index.event_frames[k],
                "class": cls,
                "gt_id": index.event_gt_ids[k],
                "old_track": index.event_old_track_ids[k],
                "new_track": index.event_new_track_ids[k],
                "last_frame": None,
                "cause": index.event_causes[k],
                "event": k,
            }
        )
    counts = (summary.get("per_sequence") or {}).get(seq)
    if not isinstance(counts, dict):
        return None
    for cls, per in counts.items():
        for kind in ("IDSW", "Frag"):
            got = sum(e["class"] == cls and e["kind"] == kind for e in out)
            if not isinstance(per, dict) or per.get(kind) != got:
                return None
    return out


def _recording_index(rec: Path) -> Any:
    """The recording's ``summary/index`` (None when unreadable: the events then lack causes)."""
    from viz.shots import read_shot_index

    try:
        return read_shot_index(rec)
    except (RuntimeError, OSError, ValueError):
        return None


def _with_causes(seq: str, evts: Any, index: Any) -> list[Event]:
    """Events as records; cause and ``#K`` from the recording index where its event matches
    (same frame, GT id, kind, old and new track)."""
    where: dict[tuple[int, int, int, int, int], int] = {}
    if index is not None:
        for k, f in enumerate(index.event_frames):
            key = (
                f,
                index.event_gt_ids[k],
                index.event_kinds[k],
                index.event_old_track_ids[k],
                index.event_new_track_ids[k],
            )
            where.setdefault(key, k)
    out = []
    for e in evts:
        kind = 0 if e.kind.value == "id_switch" else 1
        k = where.get((e.frame_id, e.gt_id, kind, e.old_track_id, e.new_track_id))
        cause = index.event_causes[k] if k is not None and k < len(index.event_causes) else None
        out.append(event_record(seq, e, cause=cause, index=k))
    return out


def _load_tracks_run(path: Path, gt: Path, name: str) -> Run:
    """A tracks.json against a BaseVersion GT: events by the CLEAR replay with BEV IoU."""
    import numpy as np

    from tracker.eval.id_switches import bev_id_events
    from tracker.events import TrackOutput
    from tracker.io.baseversion import read_baseversion

    tracks = read_baseversion(path)
    truth = read_baseversion(gt)
    events: list[Event] = []
    counts: dict[str, dict[str, dict[str, int]]] = {}
    for scene, frames in tracks.items():
        if scene not in truth:
            raise InputError(f"{gt}: no scene {scene!r} (it is in {path})")
        outputs = [
            TrackOutput(
                scene,
                f.frame_id,
                f.timestamp_secs,
                f.boxes,
                np.zeros((len(f.boxes), 2)),
                np.zeros(len(f.boxes), np.int8),
                np.full(len(f.boxes), -1, np.int64),
                np.zeros(len(f.boxes), np.int8),
            )
            for f in frames
        ]
        evaluation = bev_id_events(outputs, truth[scene])
        counts[scene] = evaluation.counts
        events += [event_record(scene, e) for e in evaluation.events]
    totals: dict[str, dict[str, int]] = {}
    for per in counts.values():
        for cls, c in per.items():
            t = totals.setdefault(cls, {"IDSW": 0, "Frag": 0})
            t["IDSW"] += c["IDSW"]
            t["Frag"] += c["Frag"]
    summary = {
        "path": str(path),
        "dataset": "tracks",
        "sequences": sorted(tracks),
        "classes": sorted(totals),
        "metrics": totals,
        "per_sequence": counts,
        "evaluator": "CLEAR replay with BEV IoU of the 3D boxes (IDSW, Frag only; no HOTA)",
    }
    return Run(name, path, summary, events, {}, "tracks")


def run_names(a: Path, b: Path) -> tuple[str, str]:
    """Short distinct names for two runs (their folder names, else their paths)."""
    na, nb = a.name if a.is_dir() else a.parent.name, b.name if b.is_dir() else b.parent.name
    if na and nb and na != nb:
        return na, nb
    return str(a), str(b)
