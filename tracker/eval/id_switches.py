"""ID switches and fragmentations as events, counted exactly as TrackEval's CLEAR metric does.

TrackEval reports only totals (IDSW, Frag). A debugger needs each one: the frame, the GT object,
the track ids before and after, and the similarity of the match that decided it. So this module
replays ``trackeval.metrics.CLEAR.eval_sequence`` step by step (same score matrix with the
1000 bonus for continuing the previous timestep's match, same 0.5 threshold, same
``linear_sum_assignment``, same bookkeeping of ``prev_tracker_id`` / ``prev_timestep_tracker_id``,
including its quirk that a timestep without GT or without tracks does not reset the latter) and
emits an event wherever CLEAR increments a counter. The event counts therefore equal TrackEval's
IDSW and Frag by construction, and tests/test_id_switches.py checks it on the sample sequence.

Two inputs:

* KITTI with label_02 files: :func:`kitti_id_events` replays TrackEval's own ``Kitti2DBox``
  loading and preprocessing (2D IoU, DontCare, occlusion/truncation, distractor classes; the
  same evaluation that gives the metrics, :func:`tracker.eval.kitti.evaluate_kitti_sequence`) on
  the tracker's KITTI result file, so the matching is the evaluator's, not a re-implementation.
* Anything else with 3D ground truth: :func:`bev_id_events`, the same CLEAR replay with rotated
  BEV IoU of the 3D boxes as similarity (one pass per category).

Both also return the per-frame GT <-> track matches, which the debugger uses to draw the matched
GT's velocity beside the track's.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import linear_sum_assignment

from tracker.boxes import FloatArray, IntArray
from tracker.categories import CATEGORIES, category_index
from tracker.events import TrackOutput
from tracker.frame import Frame

if TYPE_CHECKING:
    from tracker.config import ImageBoxes
    from tracker.eval.kitti import SequenceEvaluation

#: TrackEval's CLEAR default similarity threshold for a true positive.
CLEAR_THRESHOLD = 0.5
_EPS = np.finfo("float").eps


class IdEventKind(enum.Enum):
    ID_SWITCH = "id_switch"  # a GT is matched to a different track than the last time it was
    FRAGMENTATION = "fragmentation"  # a GT is matched again after an unmatched timestep


@dataclass(frozen=True, slots=True)
class IdEvent:
    """One counted ID switch or fragmentation.

    ``old_track_id`` is the track the GT was last matched to (any number of frames earlier; -1
    when none), ``last_frame_id`` the frame of that match. ``similarity`` is the evaluator's
    similarity (2D IoU for KITTI, BEV IoU otherwise) of the new match; its cost is ``1 - sim``.
    """

    kind: IdEventKind
    frame_id: int
    category: str
    gt_id: int
    old_track_id: int
    new_track_id: int
    similarity: float
    last_frame_id: int

    @property
    def cost(self) -> float:
        return 1.0 - self.similarity


@dataclass(frozen=True, slots=True)
class FrameMatches:
    """The CLEAR matches of one frame (all categories): GT ``gt_ids[k]`` <-> ``track_ids[k]``.

    ``present_gt_ids``: every GT id the evaluator had at this frame (after its preprocessing:
    occluded, truncated or ignored objects are absent), matched or not."""

    frame_id: int
    gt_ids: IntArray
    track_ids: IntArray
    similarity: FloatArray
    present_gt_ids: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))


@dataclass(frozen=True, slots=True)
class IdEvaluation:
    """Events sorted by (frame, category, GT id); ``counts[category]`` = {"IDSW": n, "Frag": n}."""

    method: str
    events: tuple[IdEvent, ...]
    matches: tuple[FrameMatches, ...]
    counts: dict[str, dict[str, int]]

    def of_kind(self, kind: IdEventKind) -> list[IdEvent]:
        return [e for e in self.events if e.kind is kind]

    @property
    def id_switches(self) -> list[IdEvent]:
        return self.of_kind(IdEventKind.ID_SWITCH)

    @property
    def fragmentations(self) -> list[IdEvent]:
        return self.of_kind(IdEventKind.FRAGMENTATION)


# ---------------------------------------------------------------------------------------------
# The CLEAR replay


def clear_id_events(
    gt_ids: Sequence[IntArray],
    track_ids: Sequence[IntArray],
    similarity: Sequence[FloatArray],
    *,
    frame_ids: Sequence[int],
    category: str,
    threshold: float = CLEAR_THRESHOLD,
) -> tuple[list[IdEvent], list[tuple[IntArray, IntArray, FloatArray, IntArray]]]:
    """Replay CLEAR's per-timestep matching and return its IDSW/Frag events and matches.

    Parameters
    ----------
    gt_ids, track_ids : per timestep, (G_t,) and (T_t,) non-negative ids (unique per timestep).
    similarity : per timestep, (G_t, T_t) similarity (rows GT, columns tracks).
    frame_ids : the frame id of each timestep (for the events).
    category : stored in the events.

    Returns
    -------
    events : in timestep order.
    matches : per timestep, matched (gt ids, track ids, similarity) and all GT ids present.
    """
    all_gt = np.concatenate([np.asarray(g, dtype=np.int64) for g in gt_ids] or [np.zeros(0)])
    num_gt = int(all_gt.max()) + 1 if all_gt.size else 0
    # CLEAR indexes arrays by (contiguous) GT id; any id works as an index as long as it fits.
    prev_tracker_id = np.full(num_gt, np.nan)
    prev_timestep_tracker_id = np.full(num_gt, np.nan)
    prev_frame = np.full(num_gt, -1, dtype=np.int64)
    events: list[IdEvent] = []
    matches: list[tuple[IntArray, IntArray, FloatArray, IntArray]] = []
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    for t, (gt_t, trk_t, sim) in enumerate(zip(gt_ids, track_ids, similarity, strict=True)):
        gt_t = np.asarray(gt_t, dtype=np.int64)
        trk_t = np.asarray(trk_t, dtype=np.int64)
        if len(gt_t) == 0 or len(trk_t) == 0:  # no reset of prev_timestep_tracker_id here
            matches.append((*empty, gt_t))
            continue
        score = trk_t[np.newaxis, :] == prev_timestep_tracker_id[gt_t[:, np.newaxis]]
        score = 1000 * score + sim
        score[sim < threshold - _EPS] = 0
        rows, cols = linear_sum_assignment(-score)
        ok = score[rows, cols] > 0 + _EPS
        rows, cols = rows[ok], cols[ok]
        m_gt, m_trk = gt_t[rows], trk_t[cols]
        m_sim = np.asarray(sim[rows, cols], dtype=np.float64)

        before = prev_tracker_id[m_gt]
        is_idsw = ~np.isnan(before) & (m_trk != before)
        not_previously_tracked = np.isnan(prev_timestep_tracker_id)
        was_ever_matched = ~np.isnan(prev_tracker_id)
        # Frag counts every (re)start of being tracked except a GT's first one
        is_frag = not_previously_tracked[m_gt] & was_ever_matched[m_gt]
        for kind, hits in ((IdEventKind.ID_SWITCH, is_idsw), (IdEventKind.FRAGMENTATION, is_frag)):
            for k in np.flatnonzero(hits):
                g = m_gt[k]
                old = -1 if np.isnan(before[k]) else int(before[k])
                events.append(
                    IdEvent(
                        kind,
                        int(frame_ids[t]),
                        category,
                        int(g),
                        old,
                        int(m_trk[k]),
                        float(m_sim[k]),
                        int(prev_frame[g]),
                    )
                )
        prev_tracker_id[m_gt] = m_trk
        prev_frame[m_gt] = frame_ids[t]
        prev_timestep_tracker_id[:] = np.nan
        prev_timestep_tracker_id[m_gt] = m_trk
        matches.append((m_gt, m_trk, m_sim, gt_t))
    return events, matches


def _assemble(
    method: str,
    frame_ids: Sequence[int],
    per_category: Iterable[
        tuple[str, list[IdEvent], list[tuple[IntArray, IntArray, FloatArray, IntArray]]]
    ],
) -> IdEvaluation:
    events: list[IdEvent] = []
    counts: dict[str, dict[str, int]] = {}
    parts: list[list[tuple[IntArray, IntArray, FloatArray, IntArray]]] = [[] for _ in frame_ids]
    for category, cat_events, cat_matches in per_category:
        events.extend(cat_events)
        counts[category] = {
            "IDSW": sum(e.kind is IdEventKind.ID_SWITCH for e in cat_events),
            "Frag": sum(e.kind is IdEventKind.FRAGMENTATION for e in cat_events),
        }
        for t, m in enumerate(cat_matches):
            parts[t].append(m)
    frames = tuple(
        FrameMatches(
            frame_id=int(f),
            gt_ids=np.concatenate([p[0] for p in ps]) if ps else np.zeros(0, np.int64),
            track_ids=np.concatenate([p[1] for p in ps]) if ps else np.zeros(0, np.int64),
            similarity=np.concatenate([p[2] for p in ps]) if ps else np.zeros(0),
            present_gt_ids=np.concatenate([p[3] for p in ps]) if ps else np.zeros(0, np.int64),
        )
        for f, ps in zip(frame_ids, parts, strict=True)
    )
    events.sort(key=lambda e: (e.frame_id, e.category, e.gt_id, e.kind.value))
    return IdEvaluation(method, tuple(events), frames, counts)


# ---------------------------------------------------------------------------------------------
# KITTI: TrackEval's own loading and preprocessing


def kitti_id_events(
    outputs: Sequence[TrackOutput],
    frames: Sequence[Frame],
    label_file: str | Path,
    *,
    classes: Sequence[str] = ("car", "pedestrian"),
    camera_name: str = "CAM_FRONT",
    result_file: str | Path | None = None,
    num_timesteps: int | None = None,
) -> IdEvaluation:
    """ID switches and fragmentations of one KITTI sequence, as TrackEval's CLEAR counts them.

    Parameters
    ----------
    outputs : the tracker's outputs for the sequence (what gets written to the result file).
    frames : the sequence's detection frames (for the camera model), in time order.
    label_file : the sequence's ``label_02/<seq>.txt``.
    classes : any of car, pedestrian, cyclist (cyclist as in :mod:`tracker.eval.kitti`).
    result_file : the KITTI result file of ``outputs`` when already written (saves writing it).
    num_timesteps : the sequence length; default from ``frames`` and the labels (see
        :func:`result_file_id_events` for a result file without its frames).
    """
    return kitti_evaluation_and_id_events(
        outputs, frames, label_file, classes=classes, camera_name=camera_name,
        result_file=result_file, num_timesteps=num_timesteps,
    )[1]  # fmt: skip


def kitti_evaluation_and_id_events(
    outputs: Sequence[TrackOutput],
    frames: Sequence[Frame],
    label_file: str | Path,
    *,
    classes: Sequence[str] = ("car", "pedestrian"),
    camera_name: str = "CAM_FRONT",
    result_file: str | Path | None = None,
    num_timesteps: int | None = None,
    width_scale: FloatArray | None = None,
    image_boxes: ImageBoxes | str = "projection",
    own_box_window: int = 0,
) -> tuple[SequenceEvaluation, IdEvaluation]:
    """One TrackEval evaluation of a sequence and its ID events from the same loading and
    preprocessing (:func:`tracker.eval.kitti.evaluate_kitti_sequence`). ``width_scale``: the
    config's 2D-box model (:func:`tracker.io.writers.kitti_lines`) and ``image_boxes`` its
    2D-box source, ``own_box_window`` its offline smoothing of own boxes
    (:func:`tracker.io.writers.write_kitti_sequence`; all three:
    ``TrackerConfig.kitti_writer_options()``), when the file is written here."""
    from tracker.eval.kitti import evaluate_kitti_sequence
    from tracker.io.fileio import work_folder
    from tracker.io.writers import write_kitti_sequence

    label_file = Path(label_file)
    unknown = [c for c in classes if c not in ("car", "pedestrian", "cyclist")]
    if unknown:
        raise ValueError(f"cannot evaluate classes {unknown} on KITTI labels")
    if num_timesteps is None:
        num_timesteps = kitti_num_timesteps(label_file, frames)
    with work_folder("idsw") as tmp:
        if result_file is None:
            result_file = tmp / f"{label_file.stem}.txt"
            write_kitti_sequence(
                result_file, outputs, frames, camera_name,
                image_boxes=image_boxes, width_scale=width_scale, own_box_window=own_box_window,
            )  # fmt: skip
        evaluation = evaluate_kitti_sequence(
            label_file=label_file,
            result_file=Path(result_file),
            num_timesteps=num_timesteps,
            classes=classes,
            keep_id_inputs=True,
        )
    return evaluation, id_events_of(evaluation)


def id_events_of(evaluation: SequenceEvaluation) -> IdEvaluation:
    """The CLEAR replay on an evaluation's kept id inputs (``keep_id_inputs=True``)."""
    if evaluation.id_inputs is None:
        raise ValueError("the evaluation was made without keep_id_inputs")
    n = evaluation.num_timesteps
    per_category = []
    for name, (gt_ids, trk_ids, sims) in evaluation.id_inputs.items():
        events, matches = clear_id_events(gt_ids, trk_ids, sims, frame_ids=range(n), category=name)
        per_category.append((name, events, matches))
    return _assemble("trackeval Kitti2DBox + CLEAR (2D IoU)", range(n), per_category)


def result_file_id_events(
    result_file: str | Path, label_file: str | Path, *, classes: Sequence[str]
) -> IdEvaluation:
    """:func:`kitti_id_events` of a finished run's KITTI result file (no frames at hand): the
    sequence length is :func:`result_file_timesteps`; a file TrackEval refuses is named
    (:func:`tracker.eval.kitti.naming_refused_result`)."""
    from tracker.eval.kitti import naming_refused_result

    with naming_refused_result(Path(result_file)):
        return kitti_id_events(
            (), (), label_file, classes=classes, result_file=result_file,
            num_timesteps=result_file_timesteps(result_file, label_file),
        )  # fmt: skip


def result_file_timesteps(result_file: str | Path, label_file: str | Path) -> int:
    """A finished run's sequence length for TrackEval: the last frame of the labels or the
    results, plus one (the frames after both hold nothing to score)."""
    from tracker.errors import InputError
    from tracker.io.fileio import read_text

    last = -1
    for path in (label_file, result_file):
        for n, line in enumerate(read_text(path).splitlines(), 1):
            if line.strip():
                head = line.split(maxsplit=1)[0]
                if not head.isdigit():
                    raise InputError(f"{path}: line {n}: frame {head!r} is not a frame number")
                last = max(last, int(head))
    return last + 1


def kitti_num_timesteps(label_file: str | Path, frames: Sequence[Frame]) -> int:
    """Sequence length for TrackEval's seqmap: it rejects label or result frames beyond it."""
    from tracker.io.fileio import read_text

    label_frames = [
        int(line.split(maxsplit=1)[0])
        for line in read_text(label_file).splitlines()
        if line.strip()
    ]
    last_frame = max([f.frame_id for f in frames] + label_frames, default=-1)
    return last_frame + 1


# ---------------------------------------------------------------------------------------------
# 3D ground truth without 2D labels: BEV IoU


def bev_id_events(
    outputs: Sequence[TrackOutput],
    gt_frames: Sequence[Frame],
    *,
    categories: Sequence[str] | None = None,
    threshold: float = CLEAR_THRESHOLD,
) -> IdEvaluation:
    """CLEAR ID switches and fragmentations with rotated BEV IoU of 3D boxes as similarity.

    Timesteps are the GT frames (in order); outputs are paired by ``frame_id``. Each category
    (default: those present in the outputs) is matched separately, as TrackEval does per class.
    """
    from tracker.cost import iou_bev

    by_frame = {o.frame_id: o for o in outputs}
    frame_ids = [f.frame_id for f in gt_frames]
    if categories is None:
        present = {int(c) for o in outputs for c in np.unique(o.boxes.category)}
        categories = [CATEGORIES[c] for c in sorted(present)]
    per_category = []
    for name in categories:
        cat = category_index(name)
        gt_ids, trk_ids, sims = [], [], []
        for f in gt_frames:
            gt = f.boxes[f.boxes.category == cat]
            out = by_frame.get(f.frame_id)
            trk = out.boxes[out.boxes.category == cat] if out is not None else gt[:0]
            sim = iou_bev(gt, trk) if len(gt) and len(trk) else np.zeros((len(gt), len(trk)))
            gt_ids.append(gt.track_id.astype(np.int64))
            trk_ids.append(trk.track_id.astype(np.int64))
            sims.append(np.where(np.isfinite(sim), sim, 0.0))
        events, matches = clear_id_events(
            gt_ids, trk_ids, sims, frame_ids=frame_ids, category=name, threshold=threshold
        )
        per_category.append((name, events, matches))
    return _assemble("CLEAR replay (BEV IoU of 3D boxes)", frame_ids, per_category)
