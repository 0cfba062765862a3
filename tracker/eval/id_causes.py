"""Why each ID switch and fragmentation happened, from the tracker's own stage events and the GT.

:mod:`tracker.eval.id_switches` says *what* the evaluator counted (frame, GT id, old -> new track).
This module says *why*, from what the tracker did around that moment. :class:`StageLog` is an
observer that keeps, per frame, references to what the tracker computed anyway (which detections
were dropped and why, the live tracks, the BEV cost matrix and gates, the accepted pairs and their
stage, births and deletions; no copies). :func:`classify_events` then walks a fixed decision list
per event; the first rule that holds names the cause, and the evidence (costs, gates, gap frames)
goes with it. The causes are exhaustive by construction (the last one is :attr:`Cause.OTHER`).

ID switch (GT ``g`` last matched to the old track ``O`` at frame ``lf``, now to ``N`` at ``f``):

1. ``gt_id_changed``: ``N`` was matched to another GT id in the frames just before and that id
   is not labelled at ``f`` any more: the track stayed, the label changed.
2. ``box_off_target``: ``O`` took ``g``'s own detection at ``f``, but its output box did not
   overlap ``g`` enough for the evaluator (which then matched ``N``); ``not_output`` when ``O``
   took it but was not output at all (tentative, or withheld by the track score gate).
3. ``old_took_other``: ``O`` is alive and took another detection at ``f`` (evidence: its cost
   to that detection, its cost to ``g``'s, the margin).
4. ``image_plane``: ``N`` got ``g``'s detection in the image-plane (RV) stage.
5. ``deleted_reborn``: ``O`` was deleted before ``N`` was born (evidence: gap length, and per gap
   frame whether ``g`` had no detection, one below the score threshold, or one outside the gate).
6. ``duplicate_birth``: ``N`` was born (at or after ``lf``) while ``O`` was still alive
   (evidence: ``O``'s cost to the detection ``N`` was born from and ``O``'s gate: why they were
   not matched).
7. ``track_jump``: ``N`` existed before ``g`` was lost and came from elsewhere.

Fragmentation with the same track before and after: the most frequent reason over the gap
frames: ``gt_not_evaluated`` (the GT was not evaluated in the gap: occluded, truncated, outside
the image), ``missed_no_detection``, ``missed_below_score`` (dropped by the score threshold or
NMS), ``missed_outside_gate`` (kept, but the track did not take it), ``not_output`` (the track
took it but was not output: tentative, or withheld by the track score gate), ``box_off_target``
(the track took it and was output, but its box missed the GT) or ``old_took_other``. A
fragmentation that is also an ID switch gets the switch's cause.
"""

from __future__ import annotations

import enum
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from tracker.boxes import FloatArray, IntArray
from tracker.eval.id_switches import IdEvaluation, IdEvent, IdEventKind
from tracker.events import (
    CostComputed,
    DetectionsFiltered,
    DropReason,
    Event,
    FrameFinished,
    FrameStarted,
    LifecycleChanged,
    Matched,
    Predicted,
    Stage,
)
from tracker.frame import Frame

#: A detection belongs to a GT box when its centre is within this fraction of the GT's larger
#: footprint side (at least :data:`MIN_ASSOCIATION_M`): a car 4 m long -> 2 m, a pedestrian 1 m.
ASSOCIATION_FRACTION = 0.5
MIN_ASSOCIATION_M = 1.0
#: {class: {"IDSW"|"Frag": {cause: count}}}
CauseCounts = dict[str, dict[str, dict[str, int]]]
#: "Steady": the new track's previous GT match is at most this many frames before the event.
STEADY_FRAMES = 2


class Cause(enum.Enum):
    GT_ID_CHANGED = "gt_id_changed"
    BOX_OFF_TARGET = "box_off_target"
    OLD_TOOK_OTHER = "old_took_other"
    IMAGE_PLANE = "image_plane"
    DELETED_REBORN = "deleted_reborn"
    DUPLICATE_BIRTH = "duplicate_birth"
    TRACK_JUMP = "track_jump"
    GT_NOT_EVALUATED = "gt_not_evaluated"
    MISSED_NO_DETECTION = "missed_no_detection"
    MISSED_BELOW_SCORE = "missed_below_score"
    MISSED_OUTSIDE_GATE = "missed_outside_gate"
    NOT_OUTPUT = "not_output"
    OTHER = "other"


#: One line per cause for tables and legends.
CAUSE_HELP = {
    Cause.GT_ID_CHANGED: "the GT id changed under a steady track",
    Cause.BOX_OFF_TARGET: "the old track held the object's detection, its box missed the GT",
    Cause.OLD_TOOK_OTHER: "the old track took another object's detection",
    Cause.IMAGE_PLANE: "the new track got the detection in the image-plane stage",
    Cause.DELETED_REBORN: "the old track was deleted, a new one was born",
    Cause.DUPLICATE_BIRTH: "a new track was born while the old one was coasting",
    Cause.TRACK_JUMP: "an existing track jumped onto the object",
    Cause.GT_NOT_EVALUATED: "the GT was not evaluated in the gap (occluded/truncated)",
    Cause.MISSED_NO_DETECTION: "no detection of the object in the gap",
    Cause.MISSED_BELOW_SCORE: "its detections fell below the score threshold (or NMS)",
    Cause.MISSED_OUTSIDE_GATE: "kept detections the track did not take (gate/cost)",
    Cause.NOT_OUTPUT: "the old track held the object's detection but was not output "
    "(tentative, or below the track score gate)",
    Cause.OTHER: "none of the above",
}


@dataclass(slots=True)
class FrameStages:
    """What the tracker did in one frame (references to its own arrays)."""

    frame: Frame
    reason: np.ndarray | None = None  # DropReason per detection row
    pred_ids: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    bev: CostComputed | None = None
    matched: list[Matched] = field(default_factory=list)
    born: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    deleted: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    output_ids: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))

    def match_of(self, track_id: int) -> tuple[int, float, Stage] | None:
        """(detection row, cost, stage) the track took this frame, or None."""
        for m in self.matched:
            hit = np.flatnonzero(m.track_ids == track_id)
            if len(hit):
                k = hit[0]
                return int(m.det_rows[k]), float(m.costs[k]), m.stage
        return None

    def taker_of(self, det_row: int) -> int | None:
        for m in self.matched:
            hit = np.flatnonzero(m.det_rows == det_row)
            if len(hit):
                return int(m.track_ids[hit[0]])
        return None

    def bev_cost(self, track_id: int, det_row: int) -> tuple[float, float] | None:
        """(cost, the track's gate) in the BEV matrix; None when not in it."""
        c = self.bev
        if c is None:
            return None
        r, k = np.flatnonzero(c.track_ids == track_id), np.flatnonzero(c.det_rows == det_row)
        if not (len(r) and len(k)):
            return None
        return float(c.cost[r[0], k[0]]), float(np.asarray(c.max_cost_per_row)[r[0]])

    def alive(self, track_id: int) -> bool:
        return bool(np.any(self.pred_ids == track_id) or np.any(self.born == track_id))


class StageLog:
    """Observer keeping each frame's stage events for :func:`classify_events`.

    Memory: the arrays the tracker made anyway, kept alive (KITTI: ~1 MB per 100 frames, most of
    it the BEV cost matrices)."""

    wants_rv_costs = False  # only the BEV matrix is used (see tracker.eval.fates.Tee)

    def __init__(self) -> None:
        self.frames: dict[int, FrameStages] = {}
        self.born_frame: dict[int, int] = {}
        self.deleted_frame: dict[int, int] = {}
        self._cur: FrameStages | None = None

    def __call__(self, event: Event) -> None:
        if isinstance(event, FrameStarted):
            self._cur = FrameStages(event.frame)
            self.frames[event.frame.frame_id] = self._cur
            return
        cur = self._cur
        if cur is None:
            return
        if isinstance(event, DetectionsFiltered):
            cur.reason = event.reason
        elif isinstance(event, Predicted):
            cur.pred_ids = event.track_ids
        elif isinstance(event, CostComputed):
            if event.stage is Stage.BEV:
                cur.bev = event
        elif isinstance(event, Matched):
            if len(event.track_ids):
                cur.matched.append(event)
        elif isinstance(event, LifecycleChanged):
            cur.born, cur.deleted = event.born, event.deleted
            f = cur.frame.frame_id
            for t in event.born.tolist():
                self.born_frame[t] = f
            for t in event.deleted.tolist():
                self.deleted_frame[t] = f
        elif isinstance(event, FrameFinished):
            cur.output_ids = event.output.boxes.track_id


@dataclass(frozen=True, slots=True)
class EventCause:
    """An ID event, its cause and the evidence (short keys, numbers or ids)."""

    event: IdEvent
    cause: Cause
    evidence: dict[str, float | int | str]

    def short_text(self) -> str:
        """One line that fits an event list: what, the cause, the deciding numbers."""
        e = self.event
        what = "IDSW" if e.kind is IdEventKind.ID_SWITCH else "Frag"
        ev = self.evidence
        detail = ", ".join(f"{k} {_fmt(ev[k])}" for k in _SHORT_KEYS.get(self.cause, ()) if k in ev)
        return (
            f"{what} f{e.frame_id} {e.category} GT{e.gt_id} T{e.old_track_id}->T{e.new_track_id}: "
            f"{self.cause.value}" + (f" ({detail})" if detail else "")
        )


_SHORT_KEYS: dict[Cause, tuple[str, ...]] = {
    Cause.OLD_TOOK_OTHER: ("cost_taken", "cost_to_gt_det", "margin"),
    Cause.BOX_OFF_TARGET: ("cost_taken",),
    Cause.IMAGE_PLANE: ("rv_cost",),
    Cause.DELETED_REBORN: ("gap_frames", "no_detection", "below_score", "outside_gate"),
    Cause.DUPLICATE_BIRTH: ("birth_frame", "old_cost_to_birth_det", "old_gate"),
    Cause.TRACK_JUMP: ("from_gt",),
    Cause.GT_ID_CHANGED: ("previous_gt",),
    Cause.MISSED_NO_DETECTION: ("gap_frames",),
    Cause.MISSED_BELOW_SCORE: ("gap_frames", "below_score"),
    Cause.MISSED_OUTSIDE_GATE: ("gap_frames", "outside_gate"),
    Cause.NOT_OUTPUT: ("gap_frames", "not_output"),
    Cause.GT_NOT_EVALUATED: ("gap_frames",),
}


def _fmt(v: float | int | str) -> str:
    return f"{v:.2f}" if isinstance(v, float) else str(v)


class _Gt:
    """GT boxes by (frame, GT id) and the evaluated GT ids per frame."""

    def __init__(self, gt_frames: Mapping[int, Frame], evaluation: IdEvaluation) -> None:
        self.frames = gt_frames
        self.present = {m.frame_id: m.present_gt_ids for m in evaluation.matches}
        self.clear_track: dict[int, list[tuple[int, int]]] = {}  # track -> [(frame, gt)]
        for m in evaluation.matches:
            for g, t in zip(m.gt_ids.tolist(), m.track_ids.tolist(), strict=True):
                self.clear_track.setdefault(t, []).append((m.frame_id, g))

    def box(self, frame_id: int, gt_id: int) -> tuple[FloatArray, float, int] | None:
        f = self.frames.get(frame_id)
        if f is None:
            return None
        hit = np.flatnonzero(f.boxes.track_id == gt_id)
        if not len(hit):
            return None
        k = hit[0]
        radius = max(MIN_ASSOCIATION_M, ASSOCIATION_FRACTION * float(f.boxes.lwh[k, :2].max()))
        return f.boxes.xyz[k, :2], radius, int(f.boxes.category[k])

    def evaluated(self, frame_id: int, gt_id: int) -> bool:
        ids = self.present.get(frame_id)
        return ids is not None and bool(np.any(ids == gt_id))


def _gt_detection(st: FrameStages, gt: _Gt, gt_id: int) -> int | None:
    """The frame's detection row nearest to the GT box (same category, within its radius)."""
    b = gt.box(st.frame.frame_id, gt_id)
    if b is None:
        return None
    xy, radius, cat = b
    dets = st.frame.boxes
    if not len(dets):
        return None
    d = np.hypot(*(dets.xyz[:, :2] - xy).T)
    d[dets.category != cat] = np.inf
    k = int(np.argmin(d))
    return k if d[k] <= radius else None


def _gap_reason(st: FrameStages | None, gt: _Gt, gt_id: int, track_id: int) -> str:
    """Why GT ``gt_id`` was not matched to ``track_id`` in this gap frame."""
    if st is None:
        return "no_frame"
    if not gt.evaluated(st.frame.frame_id, gt_id):
        return "gt_not_evaluated"
    det = _gt_detection(st, gt, gt_id)
    own = st.match_of(track_id)
    if det is None:
        return "took_other" if own is not None else "no_detection"
    if st.reason is not None and st.reason[det] != DropReason.KEPT:
        return "below_score"
    if own is not None:
        if own[0] != det:
            return "took_other"
        return "box_off" if np.any(st.output_ids == track_id) else "not_output"
    return "outside_gate"


_GAP_CAUSE = {
    "gt_not_evaluated": Cause.GT_NOT_EVALUATED,
    "no_detection": Cause.MISSED_NO_DETECTION,
    "below_score": Cause.MISSED_BELOW_SCORE,
    "outside_gate": Cause.MISSED_OUTSIDE_GATE,
    "not_output": Cause.NOT_OUTPUT,
    "box_off": Cause.BOX_OFF_TARGET,
    "took_other": Cause.OLD_TOOK_OTHER,
}


def _gap_counts(log: StageLog, gt: _Gt, e: IdEvent) -> Counter[str]:
    first = e.last_frame_id + 1 if e.last_frame_id >= 0 else e.frame_id
    return Counter(
        _gap_reason(log.frames.get(t), gt, e.gt_id, e.old_track_id)
        for t in range(first, e.frame_id)
    )


def _classify_switch(e: IdEvent, log: StageLog, gt: _Gt) -> tuple[Cause, dict]:
    f, g, old, new = e.frame_id, e.gt_id, e.old_track_id, e.new_track_id
    st = log.frames.get(f)
    if st is None:
        return Cause.OTHER, {"reason": "frame not observed"}
    ev: dict[str, float | int | str] = {"gap_frames": f - e.last_frame_id - 1}
    # 1. the new track was on another GT id just before, and that id is gone
    before = [(fr, gg) for fr, gg in gt.clear_track.get(new, []) if fr < f]
    if before and before[-1][1] != g and before[-1][0] >= f - STEADY_FRAMES:
        prev_gt = before[-1][1]
        if not gt.evaluated(f, prev_gt) and gt.box(f, prev_gt) is None:
            return Cause.GT_ID_CHANGED, {**ev, "previous_gt": prev_gt}
    det_g = _gt_detection(st, gt, g)
    own = st.match_of(old) if st.alive(old) else None
    # 2./3. the old track is alive and took a detection this frame
    if own is not None:
        ev["cost_taken"] = own[1]
        if det_g is not None and own[0] == det_g:
            output = bool(np.any(st.output_ids == old))
            return (Cause.BOX_OFF_TARGET if output else Cause.NOT_OUTPUT), ev
        to_g = st.bev_cost(old, det_g) if det_g is not None else None
        if to_g is not None:
            ev["cost_to_gt_det"], ev["old_gate"] = to_g
            ev["margin"] = to_g[0] - own[1]
        ev["taken_det"] = own[0]
        return Cause.OLD_TOOK_OTHER, ev
    # 4. the new track's match came from the image-plane stage
    theirs = st.match_of(new)
    if theirs is not None and theirs[2] is Stage.RV:
        ev["rv_cost"] = theirs[1]
        if det_g is not None and (c := st.bev_cost(old, det_g)) is not None:
            ev["old_bev_cost"], ev["old_gate"] = c
        return Cause.IMAGE_PLANE, ev
    born = log.born_frame.get(new)
    deleted = log.deleted_frame.get(old)
    if born is not None and born >= e.last_frame_id:
        # 5./6. a new track since the GT was last tracked (or born beside it in that frame): was
        # the old one still there?
        if deleted is not None and deleted <= born:
            gap = _gap_counts(log, gt, e)
            ev.update({k: gap.get(k, 0) for k in ("no_detection", "below_score", "outside_gate")})
            ev["deleted_frame"] = deleted
            return Cause.DELETED_REBORN, ev
        ev["birth_frame"] = born
        bst = log.frames.get(born)
        birth_det = _gt_detection(bst, gt, g) if bst is not None else None
        if bst is not None and birth_det is not None:
            c = bst.bev_cost(old, birth_det)
            if c is not None:
                ev["old_cost_to_birth_det"], ev["old_gate"] = c
            else:
                ev["old_cost_to_birth_det"] = "not comparable"
        return Cause.DUPLICATE_BIRTH, ev
    if before:
        # 7. an older track came over from another object (or from nowhere in the GT)
        ev["from_gt"] = before[-1][1]
        return Cause.TRACK_JUMP, ev
    if born is not None:
        return Cause.TRACK_JUMP, {**ev, "from_gt": "none", "birth_frame": born}
    return Cause.OTHER, ev


def _classify_fragmentation(e: IdEvent, log: StageLog, gt: _Gt) -> tuple[Cause, dict]:
    gap = _gap_counts(log, gt, e)
    ev: dict[str, float | int | str] = {"gap_frames": e.frame_id - e.last_frame_id - 1}
    ev.update(sorted(gap.items()))
    known = [(n, k) for k, n in gap.items() if k in _GAP_CAUSE]
    if not known:
        return Cause.OTHER, ev
    # most frequent reason; ties go to the earlier entry of _GAP_CAUSE (the upstream one)
    order = list(_GAP_CAUSE)
    _, reason = max(known, key=lambda nk: (nk[0], -order.index(nk[1])))
    return _GAP_CAUSE[reason], ev


def classify_events(
    evaluation: IdEvaluation,
    log: StageLog,
    gt_frames: Sequence[Frame] | Mapping[int, Frame],
) -> list[EventCause]:
    """The cause of every event of ``evaluation`` (same order)."""
    by_frame = (
        dict(gt_frames) if isinstance(gt_frames, Mapping) else {f.frame_id: f for f in gt_frames}
    )
    gt = _Gt(by_frame, evaluation)
    switch_cause = {
        (e.frame_id, e.gt_id): _classify_switch(e, log, gt)
        for e in evaluation.events
        if e.kind is IdEventKind.ID_SWITCH
    }
    out: list[EventCause] = []
    for e in evaluation.events:
        key = (e.frame_id, e.gt_id)
        if key in switch_cause and (
            e.kind is IdEventKind.ID_SWITCH or e.old_track_id != e.new_track_id
        ):
            cause, ev = switch_cause[key]
        else:
            cause, ev = _classify_fragmentation(e, log, gt)
        out.append(EventCause(e, cause, ev))
    return out


def cause_counts(causes: Iterable[EventCause]) -> CauseCounts:
    """{class: {"IDSW"|"Frag": {cause: n}}} with every cause key present (zeros included)."""
    out: CauseCounts = {}
    for c in causes:
        kind = "IDSW" if c.event.kind is IdEventKind.ID_SWITCH else "Frag"
        per = out.setdefault(c.event.category, {})
        for k in ("IDSW", "Frag"):
            per.setdefault(k, {x.value: 0 for x in Cause})
        per[kind][c.cause.value] += 1
    return out


def cause_table_markdown(
    counts: Mapping[str, Mapping[str, Mapping[str, Mapping[str, int]]]],
) -> list[str]:
    """Markdown table: one row per cause, a column per (sequence or total, class, IDSW/Frag).

    ``counts``: {sequence: :func:`cause_counts`}; a "total" column group is added when there is
    more than one sequence. Causes that never occur are left out; "other" is always shown."""
    classes = sorted({c for per in counts.values() for c in per})
    total: dict[str, dict[str, Counter[str]]] = {
        c: {"IDSW": Counter(), "Frag": Counter()} for c in classes
    }
    for per in counts.values():
        for c, kinds in per.items():
            for k, n in kinds.items():
                total[c][k].update(n)
    cols = [(c, k) for c in classes for k in ("IDSW", "Frag")]
    header = ["cause", *[f"{c} {k}" for c, k in cols], "meaning"]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * len(cols) + "---|"]
    for cause in Cause:
        row = [total[c][k][cause.value] for c, k in cols]
        if not any(row) and cause is not Cause.OTHER:
            continue
        lines.append(
            f"| {cause.value} | " + " | ".join(str(n) for n in row) + f" | {CAUSE_HELP[cause]} |"
        )
    sums = [sum(total[c][k].values()) for c, k in cols]
    lines.append("| **all** | " + " | ".join(f"**{n}**" for n in sums) + " | |")
    return lines


def other_share(counts: Mapping[str, CauseCounts]) -> float:
    """Fraction of all events whose cause is "other" (0 without events)."""
    n_all = n_other = 0
    for per in counts.values():
        for kinds in per.values():
            for n in kinds.values():
                n_all += sum(n.values())
                n_other += n.get(Cause.OTHER.value, 0)
    return n_other / n_all if n_all else 0.0


__all__ = [
    "CAUSE_HELP",
    "Cause",
    "CauseCounts",
    "EventCause",
    "StageLog",
    "cause_counts",
    "cause_table_markdown",
    "classify_events",
    "other_share",
]
