"""Fitting a detector's score calibration on labelled sequences (isotonic regression).

A detection is a *true positive* when it is matched to a ground-truth object of its class in
the BEV plane: per frame and class, detections in descending raw score take the nearest
unmatched ground-truth centre within ``MATCH_DISTANCE_M`` (the greedy matching of detection
benchmarks). Detections that match no object of their class but lie within that distance of an
evaluation distractor (van or truck for cars, a sitting person for pedestrians) or whose 2D box
lies mostly inside a DontCare region are left out of the fit: the evaluator counts them neither
way. The map raw → P(true positive) is scikit-learn's isotonic regression (monotone, no shape
assumed); its held-out quality comes from leave-one-sequence-out cross-fitting.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import cdist
from scipy.special import logit

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.calibration import (
    PROB_RANGE,
    RangeTerm,
    ScoreMap,
    ScoreProfile,
    box_ranges,
    fallback_scores,
)
from tracker.categories import category_index
from tracker.frame import Frame

#: BEV centre distance (m) under which a detection counts as its object found.
MATCH_DISTANCE_M: Mapping[str, float] = {"car": 2.0, "pedestrian": 1.0, "cyclist": 1.5}
#: Ground-truth classes that are neither a hit nor a miss for a class (KITTI's evaluation).
DISTRACTORS: Mapping[str, tuple[str, ...]] = {
    "car": ("van", "truck"),
    "pedestrian": ("person_sitting",),
    "cyclist": (),
}
DONTCARE_OVERLAP = 0.5  # fraction of a detection's 2D box inside DontCare regions to ignore it
MAX_KNOTS = 48  # knots stored per class (the map is read back with linear interpolation)
MIN_FIT_BOXES = 20  # boxes of a class (some true, some false) a labelled map needs
RANGE_SCALE_M = 50.0  # r = range / this in the range term (keeps its coefficients near 1)
#: held-out log-loss gain (nats per detection) a range term must bring to be kept
RANGE_MIN_GAIN = 0.002


@dataclass(frozen=True, slots=True)
class LabelledScores:
    """Per kept detection: category, raw score, 1 for a true positive, its sequence and its BEV
    range from the ego (NaN without an ego pose)."""

    category: IntArray
    raw: FloatArray
    label: IntArray
    scene: np.ndarray
    range_m: FloatArray

    def of_class(self, name: str) -> LabelledScores:
        rows = self.category == category_index(name)
        return LabelledScores(self.category[rows], self.raw[rows], self.label[rows],
                              self.scene[rows], self.range_m[rows])  # fmt: skip


def label_detections(
    detections: Mapping[str, Sequence[Frame]],
    gt: Mapping[str, Sequence[Frame]],
    classes: Sequence[str],
) -> LabelledScores:
    """Match every detection of ``classes`` to the ground truth; drop the ignored ones."""
    cats, raws, labels, scenes, ranges = [], [], [], [], []
    for scene, frames in detections.items():
        gt_frames = {f.frame_id: f for f in gt[scene]}
        for frame in frames:
            truth = gt_frames.get(frame.frame_id)
            if truth is None:
                continue
            for name in classes:
                label, keep = _label_frame(frame, truth, name)
                rows = np.nonzero(frame.boxes.category == category_index(name))[0][keep]
                cats.append(frame.boxes.category[rows])
                raws.append(frame.boxes.score_raw[rows])
                labels.append(label[keep])
                scenes.append(np.full(len(rows), scene, dtype=object))
                ranges.append(box_ranges(frame)[rows])
    if not cats:
        empty = np.zeros(0)
        return LabelledScores(empty.astype(np.int64), empty, empty.astype(np.int64),
                              empty.astype(object), empty)  # fmt: skip
    return LabelledScores(
        np.concatenate(cats), np.concatenate(raws), np.concatenate(labels).astype(np.int64),
        np.concatenate(scenes), np.concatenate(ranges),
    )  # fmt: skip


def _label_frame(frame: Frame, truth: Frame, name: str) -> tuple[IntArray, np.ndarray]:
    """(label, keep) for the detections of class ``name`` in one frame."""
    cat = category_index(name)
    dets = frame.boxes[frame.boxes.category == cat]
    n = len(dets)
    label = np.zeros(n, dtype=np.int64)
    keep = np.isfinite(dets.score_raw)
    if n == 0:
        return label, keep
    radius = MATCH_DISTANCE_M.get(name, 2.0)
    gt_xy = truth.boxes.xyz[truth.boxes.category == cat, :2]
    if len(gt_xy):
        dist = cdist(dets.xyz[:, :2], gt_xy)
        taken = np.zeros(len(gt_xy), dtype=bool)
        for i in np.argsort(-dets.score_raw, kind="stable"):
            d = np.where(taken, np.inf, dist[i])
            j = int(np.argmin(d))
            if d[j] <= radius:
                taken[j], label[i] = True, 1
    distractor = np.isin(
        truth.boxes.category, [category_index(c) for c in DISTRACTORS.get(name, ())]
    )
    if distractor.any():
        near = cdist(dets.xyz[:, :2], truth.boxes.xyz[distractor, :2]).min(axis=1) <= radius
        keep &= ~((label == 0) & near)
    if len(truth.ignore_xyxy_image):
        keep &= ~((label == 0) & (_inside_fraction(dets.xyxy_image, truth.ignore_xyxy_image)
                                  >= DONTCARE_OVERLAP))  # fmt: skip
    return label, keep


def _inside_fraction(boxes: FloatArray, regions: FloatArray) -> FloatArray:
    """Largest fraction of each box's area covered by one region (NaN boxes: 0)."""
    x1 = np.maximum(boxes[:, None, 0], regions[None, :, 0])
    y1 = np.maximum(boxes[:, None, 1], regions[None, :, 1])
    x2 = np.minimum(boxes[:, None, 2], regions[None, :, 2])
    y2 = np.minimum(boxes[:, None, 3], regions[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(area[:, None] > 0, inter / area[:, None], 0.0)
    return np.nan_to_num(frac).max(axis=1)


def fit_map(raw: FloatArray, label: IntArray) -> ScoreMap:
    """Isotonic regression of the label on the raw score, stored as at most MAX_KNOTS knots
    (quantiles of the raw scores, where the fitted function is evaluated)."""
    from sklearn.isotonic import IsotonicRegression

    iso = IsotonicRegression(y_min=0.0, y_max=1.0, increasing=True, out_of_bounds="clip")
    iso.fit(raw, label)
    knots = _knots(raw)
    return _score_map(knots, iso.predict(knots))


def _knots(raw: FloatArray) -> FloatArray:
    """At most MAX_KNOTS knots: quantiles of the raw scores, where a fitted map is stored."""
    return np.unique(np.round(np.quantile(raw, np.linspace(0, 1, MAX_KNOTS)), 4))


def _score_map(knots: FloatArray, prob: FloatArray) -> ScoreMap:
    """The stored map through ``knots``: probabilities clipped, made non-decreasing, rounded."""
    return ScoreMap(knots, np.round(np.maximum.accumulate(np.clip(prob, *PROB_RANGE)), 4))


def fit_range_term(p0: FloatArray, range_m: FloatArray, label: IntArray) -> RangeTerm | None:
    """Logistic regression of ``label`` on ``logit p0``, ``r``, ``r²`` (None when it cannot be
    fitted: no finite ranges, one-sided labels, or a non-positive logit coefficient)."""
    from sklearn.linear_model import LogisticRegression

    known = np.isfinite(range_m)
    if known.sum() < 20 or label[known].min() == label[known].max():
        return None
    r = range_m[known] / RANGE_SCALE_M
    features = np.column_stack([logit(np.clip(p0[known], *PROB_RANGE)), r, r * r])
    fit = LogisticRegression(C=1e4, max_iter=1000).fit(features, label[known])
    (a, b, c), d = fit.coef_[0], fit.intercept_[0]
    if not a > 0:
        return None
    lo, hi = float(range_m[known].min()), float(range_m[known].max())
    return RangeTerm(float(a), float(b), float(c), float(d), RANGE_SCALE_M, lo, hi)


def _log_loss(prob: FloatArray, label: IntArray) -> float:
    prob = np.clip(prob, *PROB_RANGE)
    return float(-np.mean(label * np.log(prob) + (1 - label) * np.log(1.0 - prob)))


def _quality(prob: FloatArray, label: IntArray) -> dict[str, float]:
    """Brier score, expected calibration error (10 equal-count bins) and log loss."""
    brier = float(np.mean((prob - label) ** 2))
    order = np.argsort(prob, kind="stable")
    ece = 0.0
    for part in np.array_split(order, 10):
        if len(part):
            ece += len(part) / len(prob) * abs(float(prob[part].mean() - label[part].mean()))
    return {
        "brier": round(brier, 4),
        "ece": round(ece, 4),
        "log_loss": round(_log_loss(prob, label), 4),
    }


def fit_profile(
    detector: str,
    detections: Mapping[str, Sequence[Frame]],
    gt: Mapping[str, Sequence[Frame]],
    classes: Sequence[str],
    *,
    dataset: str = "kitti",
) -> ScoreProfile:
    """Fit one map per class with detections (and its range term where it helps held out);
    quality in-sample and held out by sequence."""
    data = label_detections(detections, gt, classes)
    maps: dict[str, ScoreMap] = {}
    quality: dict[str, dict[str, object]] = {}
    for name in classes:
        part = data.of_class(name)
        if len(part.raw) < MIN_FIT_BOXES or part.label.min(initial=1) == part.label.max(initial=0):
            continue  # too little (or one-sided) evidence to fit: the class keeps the fallback
        raw, label, range_m = part.raw, part.label, part.range_m
        score_map = fit_map(raw, label)
        term = fit_range_term(score_map(raw), range_m, label)
        # held out by sequence: each sequence scored by maps fitted on the others
        held_iso, held_range = score_map(raw), np.full(len(raw), np.nan)
        held = np.zeros(len(raw), dtype=bool)  # the rows a map fitted without them scored
        for scene in np.unique(part.scene):
            test = part.scene == scene
            train = ~test
            if train.sum() >= MIN_FIT_BOXES and label[train].min() != label[train].max():
                held[test] = True
                iso = fit_map(raw[train], label[train])
                held_iso[test] = iso(raw[test])
                if term is not None:
                    t = fit_range_term(iso(raw[train]), range_m[train], label[train])
                    if t is not None:
                        held_range[test] = ScoreMap(iso.raw, iso.prob, t)(raw[test], range_m[test])
        held_range = np.where(np.isfinite(held_range), held_range, held_iso)
        gain = _log_loss(held_iso, label) - _log_loss(held_range, label)
        use_range = term is not None and gain >= RANGE_MIN_GAIN
        if use_range:
            score_map = ScoreMap(score_map.raw, score_map.prob, term)
        held_out = held_range if use_range else held_iso
        quality[name] = {
            "detections": len(raw),
            "true_positives": int(label.sum()),
            "in_sample": _quality(score_map(raw, range_m), label),
            "held_out_by_sequence": (
                _quality(held_out[held], label[held])
                if held.any()
                else "not measured: no sequence could be held out (one sequence, or too few "
                "boxes in the others)"
            ),
            "uncalibrated": _quality(fallback_scores(raw), label),
            "range_term": (
                f"kept: it lowers the held-out log loss by {gain:.4f} nats"
                if use_range
                else "not kept: "
                + (
                    "not fitted"
                    if term is None
                    else f"it changes the held-out log loss by {-gain:+.4f} nats"
                )
            ),
        }
        if len(score_map.raw) == 1:  # (the knots are the raw scores' quantiles, to 4 decimals)
            by_range = ", changed by its distance from the ego alone" if use_range else ""
            outcome = f"each gets P(true positive) {score_map.prob[0]:.4f}{by_range}"
            quality[name]["one_score"] = _one_score_note(raw, score_map.raw[0], outcome)
        maps[name] = score_map
    fitted_on = {
        "dataset": dataset,
        "sequences": sorted(detections),
        "match": "greedy by score, BEV centre distance <= "
        + ", ".join(f"{c} {MATCH_DISTANCE_M.get(c, 2.0)} m" for c in classes)
        + "; distractor classes and DontCare regions ignored",
        "fit": "sklearn IsotonicRegression; range term: sklearn LogisticRegression on "
        f"logit p, r, r^2 (r = range / {RANGE_SCALE_M:g} m), kept if it lowers the held-out "
        f"log loss by >= {RANGE_MIN_GAIN} nats",
    }
    return ScoreProfile(detector, maps, fitted_on, quality)


def _one_score_note(raw: FloatArray, knot: float, outcome: str) -> str:
    """What a map through one knot means: the class's raw scores are one value (a detector that
    writes a constant score), so every box gets the same score (``outcome`` says which)."""
    value = f"{knot:g} (raw" + (")" if np.ptp(raw) == 0 else ", to 4 decimals)")
    return (
        f"all {len(raw)} boxes it is fitted on score {value}: one value cannot rank them, {outcome}"
    )


def one_score_warning(detector: str, name: str, quality: Mapping[str, object]) -> str | None:
    """The warning for a class of a fitted profile (``quality``: the class's entry) whose boxes
    all score the same (its ``one_score`` note), or None: the profile is valid, but for this class
    it decides nothing. One wording for every command that fits a profile."""
    note = quality.get("one_score")
    if note is None:
        return None
    return (
        f"{detector} {name}: {note}; the tracker's score thresholds keep all of these boxes or "
        "none (its scores give nothing to calibrate)"
    )


# --- Without labels: calibration from the detections' own persistence ----------------------
#: Detections of a class needed to self-calibrate it (fewer: the class keeps the fallback).
SELF_MIN_DETECTIONS = 200
#: Raw-score quantiles whose persistence stands for "all false" and "all true" (see below).
SELF_BAND = (0.05, 0.95)
#: Least rise of the pseudo-label between those quantiles for the map to mean anything.
SELF_MIN_CONTRAST = 0.2
#: A box is confident where P(persistent | raw) reaches this fraction of its value at the top
#: SELF_BAND quantile; a persistent box is taken as real only if its frame-to-frame chain
#: reaches a confident box (None: persistence alone). Chosen by
#: leave-one-(detector, class)-out over the kit's detectors (docs/results.md, "A detector
#: without a profile").
SELF_CONFIDENT = 0.8


def _class_boxes(frames: Sequence[Frame], name: str) -> list[Boxes]:
    """Each frame's boxes of class ``name``."""
    cat = category_index(name)
    return [f.boxes[f.boxes.category == cat] for f in frames]


def _reach(boxes: Boxes) -> FloatArray:
    """How far a box's object is looked for in a neighbour frame: its own length (BEV)."""
    return np.max(boxes.lwh[:, :2], axis=1)


def persistence_labels(frames: Sequence[Frame], name: str) -> np.ndarray:
    """(N,) bool over the class's boxes of all ``frames`` (in frame order): the box has a box of
    its class within its own length (BEV, world frame) in the previous frame and in the next
    one (the first and last frames need only the neighbour they have). A real object is
    detected again where it was; most false positives flicker."""
    boxes = _class_boxes(frames, name)
    out = []
    for t, b in enumerate(boxes):
        ok = np.ones(len(b), dtype=bool)
        reach = _reach(b)
        for other in boxes[max(t - 1, 0) : t] + boxes[t + 1 : t + 2]:
            if not len(other):
                ok[:] = False
            elif len(b):
                ok &= cdist(b.xyz[:, :2], other.xyz[:, :2]).min(axis=1) <= reach
        out.append(ok)
    return np.concatenate(out) if out else np.zeros(0, dtype=bool)


def chain_ids(frames: Sequence[Frame], name: str) -> IntArray:
    """(N,) chain id of each of the class's boxes of all ``frames`` (in frame order, as
    :func:`persistence_labels`): every box is linked to the nearest box of its class in the
    previous frame when that lies within the box's own length (BEV, world frame), and a chain
    is a connected component of those links (scipy's ``connected_components``)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    boxes = _class_boxes(frames, name)
    offsets = np.cumsum([0] + [len(b) for b in boxes])
    rows, cols = [], []
    for t in range(1, len(boxes)):
        prev, cur = boxes[t - 1], boxes[t]
        if not len(prev) or not len(cur):
            continue
        d = cdist(cur.xyz[:, :2], prev.xyz[:, :2])
        nearest = d.argmin(axis=1)
        linked = np.flatnonzero(d[np.arange(len(cur)), nearest] <= _reach(cur))
        rows.append(offsets[t] + linked)
        cols.append(offsets[t - 1] + nearest[linked])
    n = int(offsets[-1])
    edges = (np.concatenate(rows), np.concatenate(cols)) if rows else ([], [])
    graph = coo_matrix((np.ones(len(edges[0])), edges), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def chance_labels(
    frames: Sequence[Frame], name: str, confirmed: np.ndarray | None = None
) -> tuple[int, int]:
    """(labelled, total) over the class's boxes of all ``frames``, each displaced by twice its
    length in each of the four world axis directions: how often the self-calibration's
    pseudo-label falls on a box where no box was detected, P(label | false) measured directly.
    A displaced box is persistent by the rule of :func:`persistence_labels`; with ``confirmed``
    ((N,) bool per box, as :func:`chain_ids` orders them: its chain reaches a confident box),
    it must also join a confirmed chain: that of its nearest box in the previous frame (the
    next one in the first frame)."""
    boxes = _class_boxes(frames, name)
    offsets = np.cumsum([0] + [len(b) for b in boxes])
    directions = np.array([[2.0, 0.0], [-2.0, 0.0], [0.0, 2.0], [0.0, -2.0]])
    labelled = total = 0
    for t, b in enumerate(boxes):
        neighbours = [boxes[o] for o in (t - 1, t + 1) if 0 <= o < len(boxes)]
        total += len(directions) * len(b)
        if not len(b) or not neighbours or any(not len(other) for other in neighbours):
            continue  # no box, or no box to persist into
        reach = np.tile(_reach(b), len(directions))
        moved = b.xyz[None, :, :2] + directions[:, None, :] * reach.reshape(-1, len(b), 1)
        moved = moved.reshape(-1, 2)
        dists = [cdist(moved, other.xyz[:, :2]) for other in neighbours]
        ok = np.logical_and.reduce([d.min(axis=1) <= reach for d in dists])
        if confirmed is not None:  # joins the chain of its nearest box in neighbours[0]
            link_frame = t - 1 if t > 0 else t + 1
            ok &= confirmed[offsets[link_frame] + dists[0].argmin(axis=1)]
        labelled += int(ok.sum())
    return labelled, total


def fit_self_profile(
    detector: str,
    detections: Mapping[str, Sequence[Frame]],
    classes: Sequence[str],
    confident: float | None = SELF_CONFIDENT,
) -> ScoreProfile:
    """A profile fitted without labels, on the detections to be tracked.

    Per class, the pseudo-label of a box is its persistence (:func:`persistence_labels`) and,
    with ``confident``, that its chain (:func:`chain_ids`) reaches a confident box: one whose
    raw score is at least where the isotonic fit of P(persistent | raw) reaches ``confident``
    times its value at the top SELF_BAND quantile. Static clutter (a wall, a parked trailer) is
    detected again where it was, frame after frame, but never confidently; a real object's
    chain is confident somewhere. Isotonic regression of the pseudo-label on the raw score gives
    P(label | raw) = a·P(real | raw) + b·(1 - P(real | raw)), with a = P(label | real) and
    b = P(label | false). a is read off the fit at the top SELF_BAND quantile of the raw score
    (boxes there taken as all real); b at the bottom one (taken as all false), or, where lower,
    as the label's rate on displaced boxes (:func:`chance_labels`). Inverting gives the map
    (P(label) - b) / (a - b). A class with too few boxes or too little contrast keeps the
    fallback score. Scenes of a single frame are left out."""
    from sklearn.isotonic import IsotonicRegression

    def isotonic(x: FloatArray, y: np.ndarray) -> IsotonicRegression:
        iso = IsotonicRegression(y_min=0.0, y_max=1.0, increasing=True, out_of_bounds="clip")
        return iso.fit(x, y.astype(np.float64))

    # a scene of one frame has no neighbour frame: its boxes would all count as persistent
    detections = {s: fs for s, fs in detections.items() if len(fs) >= 2}
    maps: dict[str, ScoreMap] = {}
    quality: dict[str, dict[str, object]] = {}
    for name in classes:
        cat = category_index(name)
        raw_parts, label_parts = [], []
        for fs in detections.values():
            raw_parts.append(
                np.concatenate([f.boxes.score_raw[f.boxes.category == cat] for f in fs] or [[]])
            )
            label_parts.append((persistence_labels(fs, name), chain_ids(fs, name)))
        all_raw = np.concatenate(raw_parts or [np.zeros(0)])
        persistent = np.concatenate([p for p, _ in label_parts] or [np.zeros(0, bool)])
        finite = np.isfinite(all_raw)
        raw = all_raw[finite]
        if len(raw) < SELF_MIN_DETECTIONS:
            quality[name] = {"detections": len(raw), "kept": "no: too few detections"}
            continue
        entry: dict[str, object] = {
            "detections": len(raw),
            "persistent": round(float(persistent[finite].mean()), 4),
        }
        label = persistent
        confirmed: list[np.ndarray | None] = [None] * len(raw_parts)
        if confident is not None:
            fit = isotonic(raw, persistent[finite])
            grid = np.sort(raw)
            top = float(np.quantile(raw, SELF_BAND[1]))
            high = float(grid[np.argmax(fit.predict(grid) >= confident * fit.predict([top])[0])])
            for i, (part_raw, (_, chains)) in enumerate(zip(raw_parts, label_parts, strict=True)):
                best = np.full(chains.max() + 1 if len(chains) else 0, -np.inf)
                np.fmax.at(best, chains, part_raw)  # fmax: a NaN score confirms nothing
                confirmed[i] = best[chains] >= high
            label = persistent & np.concatenate(confirmed or [np.zeros(0, bool)])
            entry["confident_raw"] = round(high, 4)
            entry["chain_confirmed"] = round(float(label[finite].mean()), 4)
        scenes = zip(detections.values(), confirmed, strict=True)
        counts = np.array([chance_labels(fs, name, c) for fs, c in scenes]).reshape(-1, 2)
        chance = counts[:, 0].sum() / max(counts[:, 1].sum(), 1)
        iso = isotonic(raw, label[finite])
        band_rate, true_rate = iso.predict(np.quantile(raw, SELF_BAND))
        # b: the bottom quantile's rate overstates it when real boxes are among the bottom (a
        # detector distributed above a score threshold); the displaced boxes measure it directly
        false_rate = min(float(band_rate), chance)
        entry["label_at_band"] = [round(float(band_rate), 4), round(float(true_rate), 4)]
        entry["label_displaced"] = round(float(chance), 4)
        knots = _knots(raw)
        if true_rate - band_rate < SELF_MIN_CONTRAST:
            quality[name] = {**entry, "kept": "no: the pseudo-label does not rise with the score"}
        else:
            prob = (iso.predict(knots) - false_rate) / (true_rate - false_rate)
            maps[name] = _score_map(knots, prob)
            quality[name] = {**entry, "kept": "yes"}
        if len(knots) == 1:  # one score (to 4 decimals) for every box: nothing for it to rank
            outcome = (
                f"each gets P(true positive) {maps[name].prob[0]:.4f}"
                if name in maps
                else "each keeps the fallback score (sigmoid(raw), or raw where in [0, 1])"
            )
            quality[name]["one_score"] = _one_score_note(raw, knots[0], outcome)
    chain = (
        ""
        if confident is None
        else ", whose frame-to-frame chain (nearest box of the class in the previous frame "
        "within the box's length) reaches a box scoring at least where P(persistent | raw) "
        f"reaches {confident:g} of its value at the raw-score quantile {SELF_BAND[1]:g}"
    )
    fitted_on = {
        "dataset": "the tracked detections themselves (no labels)",
        "sequences": sorted(detections),
        "match": "pseudo-label: a box of the class within the box's length in the previous and "
        f"the next frame (BEV, world frame){chain}",
        "fit": "sklearn IsotonicRegression of the pseudo-label on the raw score, rescaled so "
        f"that the raw-score quantile {SELF_BAND[1]:g} maps to 1 and the quantile "
        f"{SELF_BAND[0]:g}, or the label's rate on boxes displaced by twice their length where "
        "lower, to 0",
    }
    return ScoreProfile(detector, maps, fitted_on, quality)
