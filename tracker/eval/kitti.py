"""Static KITTI evaluation with the field's standard: TrackEval (PyPI ``trackeval``), KITTI 2D-box
protocol (HOTA, CLEAR, Identity): 2D IoU on image boxes, occlusion <= 2, truncation <= 0,
height >= 25 px, DontCare regions, Van a distractor for Car, Person_sitting for Pedestrian.

TrackEval's ``Kitti2DBox`` only accepts car and pedestrian. Cyclist is scored with the same
protocol and no distractor class (``_CyclistKitti2DBox``), reported separately and labelled so.
"""

from __future__ import annotations

import contextlib
import io
import shutil
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tracker.errors import InputError
from tracker.io.fileio import path_in, read_text, work_folder

if TYPE_CHECKING:
    from tracker.io.convert.kitti import KittiObjects

SUPPORTED_CLASSES = ("car", "pedestrian", "cyclist")
#: Kitti2DBox's defaults: ground truth more occluded or truncated than this is not scored.
_MAX_OCCLUSION, _MAX_TRUNCATION = 2, 0
#: The label types TrackEval's KITTI reader knows (lower-cased); any other stops it.
TRACKEVAL_TYPES = (
    "car", "van", "truck", "pedestrian", "person", "cyclist", "tram", "misc", "dontcare", "car_2"
)  # fmt: skip


#: The metrics computed per sequence (TrackEval's own classes, default settings).
METRIC_NAMES = ("HOTA", "CLEAR", "Identity")
_TRACKER_NAME = "mctrack"
#: Per class and sequence: (GT ids, track ids, similarity) per timestep, with the files' own ids
#: (TrackEval's preprocessed data, relabelled back); what the CLEAR replay of
#: :mod:`tracker.eval.id_switches` reads.
IdInputs = tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]


@dataclass
class SequenceEvaluation:
    """TrackEval's per-sequence results of one KITTI sequence, before combining.

    ``results[class][metric]`` is what ``metric.eval_sequence`` returned (small arrays, cheap to
    send back from a scene task); :func:`combine_sequences` turns a run's sequences into the
    combined metrics exactly as ``trackeval.Evaluator`` does. ``id_inputs`` (when asked for)
    feed the ID-switch replay from the same loading and preprocessing.
    """

    seq: str
    num_timesteps: int
    results: dict[str, dict[str, Any]]
    id_inputs: dict[str, IdInputs] | None = None

    @property
    def metrics(self) -> dict[str, dict[str, float]]:
        """Per class, the summary numbers of this sequence alone."""
        return {c: _summarise(r) for c, r in self.results.items()}

    def without_id_inputs(self) -> SequenceEvaluation:
        return SequenceEvaluation(self.seq, self.num_timesteps, self.results)


def check_label_file(
    path: Path,
    num_frames: int | None = None,
    length_source: str = "",
    *,
    all_rows: bool = False,
    classes: Sequence[str] = SUPPORTED_CLASSES,
) -> int:
    """Raise :class:`InputError` (file, line, field) unless TrackEval can score ``path``: a
    KITTI label file (:func:`~tracker.io.convert.kitti.read_kitti_labels`), of types TrackEval
    knows, with no object twice in one frame (:func:`repeated_track_id`) and no frame at or
    beyond ``num_frames`` (when known; ``length_source`` says where that length comes from).
    TrackEval itself fails on these with a traceback, a ValueError, "invalid timesteps" or
    "Ground-truth has the same ID more than once", and only once the tracking is done. Returns
    the frames the labels span (their last frame + 1). A repeated id is looked for where
    TrackEval looks, among the rows it scores for ``classes``, unless ``all_rows`` (the motion
    metrics' ground truth, which follows every labelled object by its id)."""
    from tracker.io.convert.kitti import read_kitti_labels

    labels = read_kitti_labels(path)
    known = np.isin(np.char.lower(labels.type_name.astype(str)), TRACKEVAL_TYPES)
    if not known.all():
        row = int(np.argmin(known))
        raise InputError(
            f"type {labels.type_name[row]!r} is not a KITTI tracking label type (Car, Van, Truck,"
            " Pedestrian, Person, Cyclist, Tram, Misc, DontCare)",
            path=path, line=labels.where(row)[1], field="type",
        )  # fmt: skip
    twice = repeated_track_id(labels, "any" if all_rows else "scored", classes)
    if twice is not None:
        row, earlier = twice
        raise InputError(
            f"frame {labels.frame[row]}: track id {labels.track_id[row]} ({labels.type_name[row]})"
            f" is also on line {labels.where(earlier)[1]}: one object twice in one frame",
            path=path, line=labels.where(row)[1], field="track_id",
        )  # fmt: skip
    if num_frames is not None and len(labels) and labels.frame.max() >= num_frames:
        row = int(np.argmax(labels.frame))
        source = f" ({length_source})" if length_source else ""
        raise InputError(
            f"frame {labels.frame[row]} is beyond the sequence's {num_frames} frames{source}:"
            " labels of another sequence?",
            path=path, line=labels.where(row)[1], field="frame",
        )  # fmt: skip
    return int(labels.frame.max(initial=-1)) + 1


def repeated_track_id(
    objects: KittiObjects, scope: str = "type", classes: Sequence[str] = SUPPORTED_CLASSES
) -> tuple[int, int] | None:
    """(row, an earlier row) of the first row (in file order) whose frame and track id an
    earlier row has, DontCare regions (all id -1) aside; None if there is none. ``scope``:

    - ``"type"``: an earlier row of the same type (Car_2 is a Car); TrackEval refuses a file
      with one id twice in a frame within a class it scores;
    - ``"scored"``: the same, only among the ground-truth rows TrackEval scores for ``classes``
      (occluded at most 2, not truncated: Kitti2DBox's preprocessing), where it checks them, so
      that a label file TrackEval accepts for those classes is not refused;
    - ``"any"``: an earlier row of any type (the motion metrics' ground truth follows every
      labelled object by its id alone)."""
    kind = np.char.lower(objects.type_name.astype(str))
    kind = np.where(kind == "car_2", "car", kind)
    codes = np.unique(kind, return_inverse=True)[1].reshape(-1)
    if scope == "any":
        codes = np.zeros_like(codes)
    candidate = kind != "dontcare"
    if scope == "scored":
        candidate &= np.isin(kind, list(classes))
        candidate &= (objects.occluded <= _MAX_OCCLUSION) & (objects.truncated <= _MAX_TRUNCATION)
    rows = np.flatnonzero(candidate)
    frame, tid = objects.frame[rows], objects.track_id[rows]
    order = rows[np.lexsort((rows, codes[rows], tid, frame))]
    same = np.flatnonzero(
        (objects.frame[order[1:]] == objects.frame[order[:-1]])
        & (objects.track_id[order[1:]] == objects.track_id[order[:-1]])
        & (codes[order[1:]] == codes[order[:-1]])
    )
    if not len(same):
        return None
    k = same[np.argmin(order[same + 1])]  # the repeat that comes first in the file
    return int(order[k + 1]), int(order[k])


def check_kitti_labels(
    label_dir: Path,
    seq_lengths: Mapping[str, int | None],
    length_sources: Mapping[str, str] | None = None,
    *,
    all_rows: bool = False,
    classes: Sequence[str] = SUPPORTED_CLASSES,
) -> dict[str, int]:
    """The sequences of ``seq_lengths`` with a label file in ``label_dir``, each checked by
    :func:`check_label_file` (``all_rows`` and ``classes`` passed on) against its length (None:
    unknown), with the frames its labels span (0: an empty file). Run before tracking or
    evaluating, so that a bad label file stops the run at once with its file and line."""
    labelled: dict[str, int] = {}
    for seq, length in sorted(seq_lengths.items()):
        path = path_in(label_dir, seq, ".txt")
        if path.is_file():
            source = (length_sources or {}).get(seq, "")
            labelled[seq] = check_label_file(
                path, length, source, all_rows=all_rows, classes=classes
            )
    return labelled


def _window(source: Path, target: Path, first: int, count: int) -> None:
    """``target``: the rows of KITTI file ``source`` at frames first .. first+count-1, their
    frames shifted to start at 0 (TrackEval scores frames 0 .. n-1)."""
    rows = []
    for text in read_text(source).splitlines():
        frame, _, rest = text.strip().partition(" ")
        if frame and first <= int(float(frame)) < first + count:
            rows.append(f"{int(float(frame)) - first} {rest}\n")
    target.write_text("".join(rows))


def evaluate_kitti_sequence(
    *,
    label_file: Path,
    result_file: Path | None,
    num_timesteps: int,
    classes: Sequence[str] = ("car", "pedestrian"),
    keep_id_inputs: bool = False,
    first_frame: int | None = None,
    label_checked: bool = False,
    result_name: str | None = None,
) -> SequenceEvaluation:
    """Evaluate one sequence's result file (None: no tracks) against its ``label_02`` file.

    ``first_frame``: score only frames first_frame .. first_frame+num_timesteps-1 of both files
    (a tracks file of part of a sequence); None: the whole files, which must end before
    ``num_timesteps`` (else :class:`InputError`, as for a malformed label file).

    TrackEval loads the sequence once per dataset (car and pedestrian share one; cyclist is its
    own, see :func:`_cyclist_dataset`), preprocesses it once per class and runs HOTA, CLEAR and
    Identity on it. With ``keep_id_inputs`` the preprocessed ids are the files' own (see
    :func:`preprocess_keeping_ids`; the metrics are the same) and are kept for the ID-switch
    replay, so a recording needs no second evaluation.

    ``result_name``: what an error calls the result file instead of its path (a temporary
    copy's source, as `mctrack eval` names its tracks file and scene).
    """
    import trackeval  # heavy import: only when evaluating

    unknown = [c for c in classes if c not in SUPPORTED_CLASSES]
    if unknown:
        raise ValueError(f"cannot evaluate classes {unknown}; supported: {SUPPORTED_CLASSES}")
    if not label_checked:  # (evaluate_kitti checks every file first)
        check_label_file(
            label_file, None if first_frame is not None else num_timesteps, classes=classes
        )
    seq = label_file.stem
    results: dict[str, dict[str, Any]] = {}
    id_inputs: dict[str, IdInputs] = {}
    with work_folder("eval") as tmp:  # (a killed run's goes: its pid is in the name)
        gt_root, trackers_root = Path(tmp) / "gt", Path(tmp) / "trackers"
        (gt_root / "label_02").mkdir(parents=True)
        target = trackers_root / _TRACKER_NAME / "data" / f"{seq}.txt"
        target.parent.mkdir(parents=True)
        gt_file = gt_root / "label_02" / f"{seq}.txt"
        result = result_file if result_file is not None and result_file.is_file() else None
        if first_frame is not None:
            _window(label_file, gt_file, first_frame, num_timesteps)
            if result is not None:
                _window(result, target, first_frame, num_timesteps)
        else:
            shutil.copyfile(label_file, gt_file)
            if result is not None:
                shutil.copyfile(result, target)
        if result is None:
            target.write_text("")
        (gt_root / "evaluate_tracking.seqmap.val").write_text(
            f"{seq} empty 000000 {num_timesteps:06d}\n"
        )
        ds_config = {
            "GT_FOLDER": str(gt_root),
            "TRACKERS_FOLDER": str(trackers_root),
            "OUTPUT_FOLDER": str(Path(tmp) / "out"),
            "TRACKERS_TO_EVAL": [_TRACKER_NAME],
            "SPLIT_TO_EVAL": "val",
            "PRINT_CONFIG": False,
        }
        metrics = [
            trackeval.metrics.HOTA(),
            trackeval.metrics.CLEAR({"PRINT_CONFIG": False}),
            trackeval.metrics.Identity({"PRINT_CONFIG": False}),
        ]
        runs: list[tuple[Any, list[tuple[str, str]]]] = []
        with contextlib.redirect_stdout(io.StringIO()):  # TrackEval prints its configs
            standard = [c for c in classes if c in ("car", "pedestrian")]
            if standard:
                dataset = trackeval.datasets.Kitti2DBox({**ds_config, "CLASSES_TO_EVAL": standard})
                runs.append((dataset, [(c, c) for c in standard]))
            if "cyclist" in classes:
                runs.append((_cyclist_dataset(trackeval, ds_config), [("cyclist", "car")]))
            for dataset, names in runs:
                raw = _raw_seq_data(
                    trackeval, dataset, seq, label_file, result, result_name, first_frame or 0
                )
                for name, eval_cls in names:
                    try:
                        if keep_id_inputs:
                            data, id_inputs[name] = preprocess_keeping_ids(dataset, raw, eval_cls)
                        else:
                            data = dataset.get_preprocessed_seq_data(raw, eval_cls)
                    except trackeval.utils.TrackEvalException:
                        # an id twice in a frame: when the labels hold it, their file is named
                        # (file, line, frame, id), even if the caller had them checked
                        check_label_file(label_file)
                        raise
                    results[name] = {
                        m.get_name(): m.eval_sequence(data)
                        for m in metrics  # names: METRIC_NAMES
                    }
    ordered = {c: results[c] for c in classes}
    return SequenceEvaluation(seq, num_timesteps, ordered, id_inputs if keep_id_inputs else None)


def _raw_seq_data(
    trackeval: Any,
    dataset: Any,
    seq: str,
    label_file: Path,
    result_file: Path | None,
    result_name: str | None = None,
    first_frame: int = 0,
) -> Any:
    """TrackEval's loading, its own error report on stderr kept quiet (it prints a traceback
    before raising) and its error an :class:`InputError` naming the file that holds the row
    it could not read (else the result file, where there is one: the label file has passed
    :func:`check_label_file`); a result file by ``result_name`` when given, with the row's
    frame in it (TrackEval reads frames from ``first_frame`` on as 0, 1, ...)."""
    files = [f for f in (result_file, label_file) if f is not None]
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            return dataset.get_raw_seq_data(_TRACKER_NAME, seq)
    except (ValueError, IndexError):  # numpy on rows of unequal length: our reader says where
        from tracker.io.convert.kitti import read_kitti_labels

        for path in files:
            read_kitti_labels(path)
        raise
    except trackeval.utils.TrackEvalException as exc:
        why = " ".join(f"{exc} {exc.__context__ or ''}".split())
        row = why.partition("cannot be read correctly: ")[2].strip()
        culprit = next((f for f in files if row and row in " ".join(f.read_text().split())), None)
        culprit = culprit or files[0]
        if result_name is not None and culprit == result_file:  # (a temporary copy)
            head, _, rest = row.partition(" ")
            if head.isdigit():
                frame = int(head) + first_frame
                raise InputError(
                    f"{result_name} frame {frame}: TrackEval cannot read the KITTI row written"
                    f" for it: {frame} {rest}"
                ) from None
            raise InputError(f"{result_name}: TrackEval cannot read it: {why}") from None
        raise InputError(f"TrackEval cannot read it: {why}", path=culprit) from None


@contextlib.contextmanager
def naming_refused_result(result_file: Path, name: str | None = None) -> Iterator[None]:
    """TrackEval's refusal of a result file it has loaded (its preprocessing raises on a track
    id twice in one frame) as an :class:`InputError` naming that file, line, frame and id
    (TrackEval's own words give its frame 1-based and the id renumbered): for a finished run's
    own result files, which the user can open. ``name``: what to call the file instead, without
    a line (a temporary copy's source: `mctrack eval` names its tracks file and scene)."""
    try:
        yield
    except Exception as exc:
        if type(exc).__name__ != "TrackEvalException":  # (not imported: trackeval is heavy)
            raise
        raise _refused_result(result_file, name, str(exc)) from None


def _refused_result(result_file: Path, name: str | None, refusal: str) -> InputError:
    from tracker.io.convert.kitti import read_kitti_labels

    rows = read_kitti_labels(result_file) if result_file.is_file() else None
    twice = repeated_track_id(rows) if rows is not None else None
    if rows is None or twice is None:  # (not a repeated id: TrackEval's words, on one line)
        why = " ".join(refusal.split())
        return InputError(f"{name}: {why}") if name else InputError(why, path=result_file)
    row, earlier = twice
    what = f"frame {rows.frame[row]}: track id {rows.track_id[row]} ({rows.type_name[row]})"
    if name:
        return InputError(f"{name} {what} twice: one track twice in one frame")
    return InputError(
        f"{what} is also on line {rows.where(earlier)[1]}: one track twice in one frame",
        path=result_file, line=rows.where(row)[1], field="track_id",
    )  # fmt: skip


def combine_sequences(
    evaluations: Sequence[SequenceEvaluation],
    classes: Sequence[str],
    per_sequence: dict[str, dict[str, dict[str, float]]] | None = None,
) -> dict[str, dict[str, float]]:
    """The combined metrics of several sequences (``trackeval.Evaluator``'s COMBINED_SEQ: each
    metric's ``combine_sequences`` over the per-sequence results), per class; a
    ``per_sequence`` dict given is filled with each sequence's own."""
    import trackeval

    metric_of = {
        "HOTA": trackeval.metrics.HOTA(),
        "CLEAR": trackeval.metrics.CLEAR({"PRINT_CONFIG": False}),
        "Identity": trackeval.metrics.Identity({"PRINT_CONFIG": False}),
    }
    ordered = sorted(evaluations, key=lambda e: e.seq)  # TrackEval's seqmap order
    out: dict[str, dict[str, float]] = {}
    for cls in classes:
        combined = {
            name: metric.combine_sequences({e.seq: e.results[cls][name] for e in ordered})
            for name, metric in metric_of.items()
        }
        out[cls] = _summarise(combined)
    if per_sequence is not None:
        for e in ordered:
            for cls in classes:
                per_sequence.setdefault(e.seq, {})[cls] = _summarise(e.results[cls])
    return out


def evaluate_kitti(
    *,
    label_dir: Path,
    result_dir: Path,
    seq_lengths: Mapping[str, int],
    classes: Sequence[str] = ("car", "pedestrian"),
    per_sequence: dict[str, dict[str, dict[str, float]]] | None = None,
    first_frames: Mapping[str, int] | None = None,
    labels_checked: bool = False,
    name_refused_results: bool | Mapping[str, str] = False,
) -> dict[str, dict[str, float]]:
    """Evaluate ``result_dir/<seq>.txt`` against ``label_dir/<seq>.txt``.

    Returns, per class, HOTA, DetA, AssA, LocA, MOTA, MOTP, IDF1 (percent), IDSW, Frag, FP, FN,
    TP (counts) over the combined sequences. A ``per_sequence`` dict given is filled with the
    same per sequence (``{seq: {class: metrics}}``; TrackEval computes them anyway). A sequence
    in ``first_frames`` is scored on its frames first .. first+length-1 alone
    (:func:`evaluate_kitti_sequence`). Every label file is checked before the first is scored,
    unless ``labels_checked`` (the caller ran :func:`check_label_file` on each, at least as
    strictly: it need not be parsed twice). With ``name_refused_results`` a result file
    TrackEval refuses is an :class:`InputError` naming it (:func:`naming_refused_result`); a
    mapping ``{seq: name}`` calls each sequence's file by its name instead (temporary copies:
    `mctrack eval` names its tracks file and scene, not a file that is gone).
    """
    unknown = [c for c in classes if c not in SUPPORTED_CLASSES]
    if unknown:
        raise ValueError(f"cannot evaluate classes {unknown}; supported: {SUPPORTED_CLASSES}")
    firsts = first_frames or {}
    if not labels_checked:
        for seq, length in sorted(seq_lengths.items()):
            length_or_none = None if seq in firsts else length
            check_label_file(path_in(label_dir, seq, ".txt"), length_or_none, classes=classes)
    names = name_refused_results if isinstance(name_refused_results, Mapping) else {}
    evaluations = []
    for seq, length in sorted(seq_lengths.items()):
        result = path_in(result_dir, seq, ".txt")
        naming = (
            naming_refused_result(result, names.get(seq))
            if name_refused_results
            else contextlib.nullcontext()
        )
        with naming:
            evaluations.append(
                evaluate_kitti_sequence(
                    label_file=path_in(label_dir, seq, ".txt"),
                    result_file=result,
                    num_timesteps=length,
                    classes=classes,
                    first_frame=firsts.get(seq),
                    label_checked=True,
                    result_name=names.get(seq),
                )
            )
    return combine_sequences(evaluations, classes, per_sequence)


def preprocess_keeping_ids(dataset: Any, raw: dict[str, Any], cls: str) -> tuple[Any, IdInputs]:
    """TrackEval preprocessing, also returning the original (file) ids instead of its
    contiguous ones.

    The preprocessing relabels ids 0..n-1. It carries ``tracker_confidences`` and ``gt_dets``
    row-aligned through every deletion without using them for the metrics, so the original ids
    ride along there: confidences are replaced by the tracker ids, and GT boxes get an id column
    (only similarity scores, computed before this, and the tracker boxes are ever measured).
    Returns the preprocessed data (for the metrics) and (GT ids, track ids, similarity).
    """
    raw = dict(raw)
    raw["tracker_confidences"] = [ids.astype(np.float64) for ids in raw["tracker_ids"]]
    raw["gt_dets"] = [
        np.column_stack([np.asarray(d, dtype=np.float64).reshape(-1, 4), ids.astype(np.float64)])
        for d, ids in zip(raw["gt_dets"], raw["gt_ids"], strict=True)
    ]
    data = dataset.get_preprocessed_seq_data(raw, cls)
    gt_ids = [
        np.asarray(d, dtype=np.float64).reshape(-1, 5)[:, 4].astype(np.int64)
        for d in data["gt_dets"]
    ]
    trk_ids = [
        np.asarray(c, dtype=np.float64).astype(np.int64) for c in data["tracker_confidences"]
    ]
    sims = [np.asarray(s, dtype=np.float64) for s in data["similarity_scores"]]
    # the recovered ids must be a relabelling of TrackEval's, else the replay would differ
    for ours, theirs in ((gt_ids, data["gt_ids"]), (trk_ids, data["tracker_ids"])):
        for a, b in zip(ours, theirs, strict=True):
            if len(a) != len(b):
                raise RuntimeError("TrackEval preprocessing changed; cannot recover ids")
    return data, (gt_ids, trk_ids, sims)


def absent_classes(metrics: Mapping[str, Mapping[str, float]]) -> list[str]:
    """Classes with no ground-truth object in the evaluated frames (TP + FN = 0): their scores
    only count false positives (MOTA -21200) and mean nothing, so reports show them as absent."""
    return [c for c, m in metrics.items() if m["TP"] + m["FN"] == 0]


def absent_class_notes(metrics: Mapping[str, Mapping[str, float]]) -> dict[str, str]:
    """{class: why it is absent} of :func:`absent_classes`: the wording every report of KITTI
    metrics uses (`mctrack kitti`'s ``metrics_absent``, `mctrack eval`'s ``static_absent``)."""

    def why(c: str) -> str:
        fp = int(metrics[c]["FP"])
        tracked = f"{fp} tracked boxes, all false positives" if fp else f"no tracked {c} either"
        return f"no ground-truth {c} in these sequences; {tracked}"

    return {c: why(c) for c in absent_classes(metrics)}


def _summarise(res: dict[str, dict[str, Any]]) -> dict[str, float]:
    hota, clear, ident = res["HOTA"], res["CLEAR"], res["Identity"]
    pct = lambda v: round(float(np.mean(v)) * 100.0, 3)  # noqa: E731
    return {
        "HOTA": pct(hota["HOTA"]),
        "DetA": pct(hota["DetA"]),
        "AssA": pct(hota["AssA"]),
        "LocA": pct(hota["LocA"]),
        "MOTA": pct(clear["MOTA"]),
        "MOTP": pct(clear["MOTP"]),
        "IDF1": pct(ident["IDF1"]),
        "IDSW": int(clear["IDSW"]),
        "Frag": int(clear["Frag"]),
        "FP": int(clear["CLR_FP"]),
        "FN": int(clear["CLR_FN"]),
        "TP": int(clear["CLR_TP"]),
    }


def _cyclist_dataset(trackeval: Any, ds_config: dict[str, Any]) -> Any:
    """Kitti2DBox scoring Cyclist: ids are remapped so that the 'car' code path (the only
    evaluatable one besides pedestrian) reads the cyclist class and has no distractor."""

    class _CyclistKitti2DBox(trackeval.datasets.Kitti2DBox):  # type: ignore[misc]
        def get_preprocessed_seq_data(self, raw_data: Any, cls: str) -> Any:
            original = self.class_name_to_class_id
            self.class_name_to_class_id = {**original, "car": original["cyclist"], "van": -1}
            try:
                return super().get_preprocessed_seq_data(raw_data, "car")
            finally:
                self.class_name_to_class_id = original

    return _CyclistKitti2DBox({**ds_config, "CLASSES_TO_EVAL": ["car"]})
