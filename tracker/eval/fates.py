"""Detection fates: every input detection ends in exactly one fate, with a reason code.

:class:`FateCounter` is an observer (:mod:`tracker.events`): it derives each detection's fate
from the stage events the tracker emits anyway, so the tracker itself keeps no bookkeeping.

Fates, in the order a detection meets them:

* ``dropped_category`` / ``dropped_score`` / ``dropped_nms``: removed by the pre-filter;
* ``matched_bev`` / ``matched_rv``: updated a track in stage 1 (BEV) or stage 2 (image plane);
* ``born``: started a new (tentative) track;
* ``unused_rv_gate``: kept, but consumed by an image-plane pair that failed the yaw/distance
  gate (reference mode drops such detections, as the original code does);
* ``unused_below_birth``: kept, matched no track and scored too low to start one.

Unknown categories are skipped by the loader before the tracker sees them
(:class:`tracker.io.baseversion.LoadReport`); :meth:`FateCounter.summary` reports them beside.
Separately, ``in_unconfirmed_tracks`` counts matched/born detections whose track was never
confirmed by the end of the scene (they are not in the online output), and
``fed_not_output`` the matched/born detections whose track was not output in that frame
(tentative, or withheld by the online gate on its mean score, ``lifecycle.track_score_min``).
"""

from __future__ import annotations

import enum
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tracker.categories import CATEGORIES
from tracker.events import (
    DetectionsFiltered,
    DropReason,
    Event,
    FrameFinished,
    LifecycleChanged,
    Matched,
    Stage,
)


class Fate(enum.IntEnum):
    PENDING = -1  # internal: not decided yet (never in a summary)
    DROPPED_CATEGORY = 0
    DROPPED_SCORE = 1
    DROPPED_NMS = 2
    MATCHED_BEV = 3
    MATCHED_RV = 4
    BORN = 5
    UNUSED_RV_GATE = 6
    UNUSED_BELOW_BIRTH = 7


_NO_ROWS = np.zeros(0, dtype=np.int64)
FATE_NAMES: dict[Fate, str] = {f: f.name.lower() for f in Fate if f is not Fate.PENDING}
_FROM_DROP = {
    DropReason.CATEGORY: Fate.DROPPED_CATEGORY,
    DropReason.SCORE: Fate.DROPPED_SCORE,
    DropReason.NMS: Fate.DROPPED_NMS,
}
# fate by DropReason value (kept: not decided yet)
_FATE_OF_REASON = np.full(max(DropReason) + 1, Fate.PENDING, dtype=np.int8)
for _reason, _fate in _FROM_DROP.items():
    _FATE_OF_REASON[_reason] = _fate


@dataclass(slots=True)
class _FrameFates:
    """One frame's events as the counter needs them (references to the tracker's arrays)."""

    reason: np.ndarray
    category: np.ndarray
    assigned: list[tuple[np.ndarray, int]] = field(default_factory=list)  # (rows, fate)
    rv_rejected: np.ndarray = field(default_factory=lambda: _NO_ROWS)


class FateCounter:
    """Counts detections per fate and category over any number of frames and scenes.

    Use as (or inside) the tracker's observer; ``summary()`` gives the counts. Pass
    ``rv_gate_consumes=config.rv_reference``. Per frame it only keeps references to the event
    arrays; the fates are assigned for many frames at once (every :data:`BATCH_FRAMES` frames,
    at a new scene and at ``summary()``), which makes it cheap enough to ride along with every
    run. Raises RuntimeError if a frame's detections do not each get exactly one fate (a
    tracker change that emits fewer events would otherwise lose detections silently).
    """

    wants_rv_costs = False  # the tracker may skip an image-plane stage that cannot match
    BATCH_FRAMES = 256

    def __init__(self, *, rv_gate_consumes: bool = False) -> None:
        # reference mode (config.rv_reference) drops detections of gated image-plane pairs;
        # otherwise they go back to the pool and only the birth score can leave them unused
        self.rv_gate_consumes = rv_gate_consumes
        # detections per (fate, category index)
        self._counts = np.zeros((len(FATE_NAMES), len(CATEGORIES)), dtype=np.int64)
        self.detections = 0
        self._cur: _FrameFates | None = None
        self._pending: list[_FrameFates] = []  # finished frames not counted yet
        # this scene's track ids fed a detection (one entry per detection) and confirmed ids
        self._track_dets: list[np.ndarray] = []
        self._confirmed: list[np.ndarray] = []
        self._scene: str | None = None
        self.in_unconfirmed_tracks = 0
        self.fed_not_output = 0

    def __call__(self, event: Event) -> None:
        kind = type(event)
        if kind is DetectionsFiltered:
            assert isinstance(event, DetectionsFiltered)
            if event.frame.scene != self._scene:
                self._close_scene()
                self._scene = event.frame.scene
            self._cur = _FrameFates(event.reason, event.frame.boxes.category)
        elif self._cur is None:
            return
        elif kind is Matched:
            assert isinstance(event, Matched)
            f = Fate.MATCHED_BEV if event.stage is Stage.BEV else Fate.MATCHED_RV
            self._cur.assigned.append((event.det_rows, int(f)))
            self._track_dets.append(event.track_ids)
            if event.stage is Stage.RV and self.rv_gate_consumes:
                self._cur.rv_rejected = event.rejected_det_rows
        elif kind is LifecycleChanged:
            assert isinstance(event, LifecycleChanged)
            self._cur.assigned.append((event.born_det_rows, int(Fate.BORN)))
            self._track_dets.append(event.born)
            self._confirmed.append(event.confirmed)
        elif kind is FrameFinished:
            assert isinstance(event, FrameFinished)
            fed = sum(len(rows) for rows, _ in self._cur.assigned)
            self.fed_not_output += fed - int(np.count_nonzero(event.output.det_row >= 0))
            self._pending.append(self._cur)
            self._cur = None
            if len(self._pending) >= self.BATCH_FRAMES:
                self._count_pending()

    def _count_pending(self) -> None:
        """The fates of the finished frames not counted yet, all at once."""
        frames, self._pending = self._pending, []
        if not frames:
            return
        lengths = np.array([len(f.reason) for f in frames], dtype=np.int64)
        offset = np.cumsum(lengths) - lengths
        fate = _FATE_OF_REASON[np.concatenate([f.reason for f in frames])]
        category = np.concatenate([np.asarray(f.category, dtype=np.int64) for f in frames])
        # matched and born rows (disjoint within a frame: a born detection matched nothing)
        rows = [r + offset[i] for i, f in enumerate(frames) for r, _ in f.assigned]
        if rows:
            codes = [np.full(len(r), c, np.int8) for f in frames for r, c in f.assigned]
            fate[np.concatenate(rows)] = np.concatenate(codes)
        gated = np.zeros(len(fate), dtype=bool)
        rejected = [f.rv_rejected + offset[i] for i, f in enumerate(frames) if len(f.rv_rejected)]
        if rejected:
            gated[np.concatenate(rejected)] = True
        pending = fate == Fate.PENDING
        fate[pending & gated] = Fate.UNUSED_RV_GATE
        fate[pending & ~gated] = Fate.UNUSED_BELOW_BIRTH
        if (fate == Fate.PENDING).any():  # cannot happen: every row was given a fate above
            raise RuntimeError("detection fates: a detection got no fate")
        n_cat = self._counts.shape[1]
        flat = fate.astype(np.int64) * n_cat + category
        self._counts += np.bincount(flat, minlength=self._counts.size).reshape(self._counts.shape)
        self.detections += len(fate)

    @property
    def counts(self) -> Counter[tuple[str, str]]:
        """(fate, category) -> detections, the pairs seen."""
        self._count_pending()
        f, c = np.nonzero(self._counts)
        return Counter(
            {
                (FATE_NAMES[Fate(int(i))], CATEGORIES[int(j)]): int(self._counts[i, j])
                for i, j in zip(f.tolist(), c.tolist(), strict=True)
            }
        )

    def _close_scene(self) -> None:
        self._count_pending()
        if self._track_dets:
            fed = np.concatenate(self._track_dets)
            confirmed = np.concatenate(self._confirmed) if self._confirmed else fed[:0]
            self.in_unconfirmed_tracks += int(np.count_nonzero(~np.isin(fed, confirmed)))
        self._track_dets.clear()
        self._confirmed.clear()

    def summary(self, skipped_unknown_categories: Counter[str] | None = None) -> dict[str, Any]:
        """``{"detections": N, "per_fate": {...}, "per_fate_and_class": {...}, ...}``.

        The per-fate counts sum to ``detections`` (the tracker's input). Skipped unknown
        categories are input the tracker never saw: listed separately, with the total.
        """
        self._close_scene()
        per_fate = Counter[str]()
        per_class: dict[str, dict[str, int]] = {}
        for (fate, cat), n in sorted(self.counts.items()):
            per_fate[fate] += n
            per_class.setdefault(fate, {})[cat] = n
        skipped = sum((skipped_unknown_categories or Counter()).values())
        return {
            "detections": self.detections,
            "per_fate": {name: per_fate.get(name, 0) for name in FATE_NAMES.values()},
            "per_fate_and_class": per_class,
            "in_unconfirmed_tracks": self.in_unconfirmed_tracks,
            "fed_not_output": self.fed_not_output,
            "skipped_unknown_category_at_load": skipped,
            "input_boxes": self.detections + skipped,
        }


def add_summaries(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """The summary of two disjoint runs (e.g. per-scene recordings): counts added key by key."""
    out: dict[str, Any] = dict(a)
    for key, value in b.items():
        if isinstance(value, dict):
            out[key] = add_summaries(a.get(key, {}), value)
        else:
            out[key] = a.get(key, 0) + value
    return out


def combine_fates(
    summaries: list[dict[str, Any]], skipped_unknown_categories: Counter[str] | None = None
) -> dict[str, Any]:
    """One summary from per-scene ones (scene tasks run apart), with the loader's skips."""
    out = FateCounter().summary()  # all keys, zero counts
    for s in summaries:
        out = add_summaries(out, s)
    skipped = sum((skipped_unknown_categories or Counter()).values())
    out["skipped_unknown_category_at_load"] = skipped
    out["input_boxes"] = out["detections"] + skipped
    return out


def format_fates(summary: dict[str, Any]) -> str:
    """One line for ``mctrack track``: the counts per fate (zeros left out)."""
    parts = [f"{name} {n}" for name, n in summary["per_fate"].items() if n]
    text = f"detections {summary['detections']}: " + ", ".join(parts)
    if summary["skipped_unknown_category_at_load"]:
        text += (
            f"; skipped at load (unknown category) {summary['skipped_unknown_category_at_load']}"
        )
    return text + (
        f"; {summary['in_unconfirmed_tracks']} in tracks never confirmed, "
        f"{summary['fed_not_output']} in tracks not output that frame"
    )


class Tee:
    """One observer calling several (None entries are skipped)."""

    def __init__(self, *observers: Any) -> None:
        self.observers = [o for o in observers if o is not None]
        wanting = [o for o in self.observers if getattr(o, "wants_rv_costs", True)]
        self.wants_rv_costs = bool(wanting)
        # deferred only if every observer that wants the costs takes them so
        self.rv_costs_deferred = bool(wanting) and all(
            getattr(o, "rv_costs_deferred", False) for o in wanting
        )

    def __call__(self, event: Event) -> None:
        for o in self.observers:
            o(event)
