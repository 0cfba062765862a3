"""Causes of ID switches and fragmentations, each on a hand-made scene that produces it.

A scripted scene feeds :class:`StageLog` the stage events a tracker would emit (which track
took which detection in which stage, births, deletions, outputs), the evaluator
(:func:`bev_id_events`) counts the events on the outputs against hand-made GT, and the
classifier must name the mechanism. Two more scenes run the real tracker.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.categories import category_index
from tracker.config import load_config
from tracker.eval.fates import Tee
from tracker.eval.id_causes import (
    Cause,
    StageLog,
    cause_counts,
    cause_table_markdown,
    classify_events,
    other_share,
)
from tracker.eval.id_switches import IdEventKind, bev_id_events
from tracker.events import (
    CostComputed,
    DetectionsFiltered,
    DropReason,
    FrameFinished,
    FrameStarted,
    LifecycleChanged,
    Matched,
    Predicted,
    Stage,
    TrackOutput,
)
from tracker.frame import Frame
from tracker.pipeline import run_scene

CAR = category_index("car")
A, B = (10.0, 0.0), (10.0, 6.0)  # two lanes
GATE = 1.0


def _boxes(xys: list[tuple[float, float]], ids: list[int] | None = None, score=None) -> Boxes:
    n = len(xys)
    return Boxes.create(
        xyz=[[x, y, 0.75] for x, y in xys] if n else np.zeros((0, 3)),
        lwh=[[4.0, 2.0, 1.5]] * n if n else np.zeros((0, 3)),
        yaw=[0.0] * n,
        category=[CAR] * n,
        track_id=ids if ids is not None else [-1] * n,
        score=score if score is not None else [0.99] * n,
    )


@dataclass
class F:
    """One scripted frame."""

    gt: dict[int, tuple[float, float]] = field(default_factory=dict)
    dets: list[tuple[tuple[float, float], DropReason]] = field(default_factory=list)
    live: dict[int, tuple[float, float]] = field(default_factory=dict)  # predicted tracks
    match: dict[int, tuple[int, Stage]] = field(default_factory=dict)  # track -> (det, stage)
    out: dict[int, tuple[float, float]] = field(default_factory=dict)
    born: list[int] = field(default_factory=list)
    deleted: list[int] = field(default_factory=list)


def _play(script: list[F]):
    log = StageLog()
    outputs, gt_frames = [], []
    for f_id, s in enumerate(script):
        dets = _boxes([xy for xy, _ in s.dets])
        frame = Frame(scene="s", frame_id=f_id, timestamp_secs=0.1 * f_id, boxes=dets)
        log(FrameStarted(frame, 0.1 * f_id))
        reason = np.array([int(r) for _, r in s.dets], dtype=np.int8)
        kept = np.flatnonzero(reason == DropReason.KEPT)
        log(DetectionsFiltered(frame, reason, kept))
        ids = np.array(sorted(s.live), dtype=np.int64)
        log(Predicted(ids, _boxes([s.live[i] for i in ids]), np.ones(len(ids), np.int8)))
        track_xy = np.array([s.live[i] for i in ids]).reshape(-1, 2)
        det_xy = dets.xyz[kept, :2]
        cost = np.hypot(*(track_xy[:, None, :] - det_xy[None, :, :]).transpose(2, 0, 1)) / 4.0
        log(CostComputed(Stage.BEV, cost, ids, kept, np.full(len(ids), GATE)))
        for stage in (Stage.BEV, Stage.RV):
            # a newborn takes its detection at birth, not in a matching stage
            pairs = sorted((t, d) for t, (d, st) in s.match.items() if st is stage and t in s.live)
            t_ids = np.array([t for t, _ in pairs], dtype=np.int64)
            d_rows = np.array([d for _, d in pairs], dtype=np.int64)
            c = np.array([cost[list(ids).index(t), list(kept).index(d)] for t, d in pairs])
            empty = np.zeros(0, np.int64)
            log(Matched(stage, t_ids, d_rows, c, empty, empty))
        empty = np.zeros(0, np.int64)
        log(
            LifecycleChanged(
                np.array(s.born, np.int64), empty, empty, empty, np.array(s.deleted, np.int64)
            )
        )
        out_ids = sorted(s.out)
        boxes = _boxes([s.out[i] for i in out_ids], out_ids)
        n = len(out_ids)
        output = TrackOutput(
            "s",
            f_id,
            0.1 * f_id,
            boxes,
            np.zeros((n, 2)),
            np.ones(n, np.int8),
            np.zeros(n, np.int64),
            np.ones(n, np.int8),
        )
        log(FrameFinished(output))
        outputs.append(output)
        gt_ids = sorted(s.gt)
        gt_frames.append(
            Frame(
                scene="s",
                frame_id=f_id,
                timestamp_secs=0.1 * f_id,
                boxes=_boxes([s.gt[g] for g in gt_ids], gt_ids),
            )
        )
    evaluation = bev_id_events(outputs, gt_frames, categories=["car"])
    return classify_events(evaluation, log, gt_frames)


K = DropReason.KEPT


def _steady(n: int = 3) -> list[F]:
    """GT 1 on lane A tracked by T0 for n frames."""
    return [F(gt={1: A}, dets=[(A, K)], live={0: A}, match={0: (0, Stage.BEV)}, out={0: A})] * n


def _two_lanes(**changes) -> F:
    """GT 1 on lane A tracked by T0, GT 2 on lane B by T1 (``changes`` override fields)."""
    both = F(
        gt={1: A, 2: B},
        dets=[(A, K), (B, K)],
        live={0: A, 1: B},
        match={0: (0, Stage.BEV), 1: (1, Stage.BEV)},
        out={0: A, 1: B},
    )
    return F(**{**both.__dict__, **changes})


def _switches(causes):
    return [c for c in causes if c.event.kind is IdEventKind.ID_SWITCH]


def test_deleted_then_reborn_with_the_gap_explained() -> None:
    gap = [F(gt={1: A}, live={0: A})] * 2 + [F(gt={1: A}, live={0: A}, deleted=[0])]
    reborn = F(gt={1: A}, dets=[(A, K)], match={1: (0, Stage.BEV)}, out={1: A}, born=[1])
    causes = _play([*_steady(), *gap, reborn])
    (sw,) = _switches(causes)
    assert sw.cause is Cause.DELETED_REBORN
    assert sw.evidence["gap_frames"] == 3 and sw.evidence["no_detection"] == 3
    assert sw.evidence["deleted_frame"] == 5
    # the fragmentation of the same moment gets the same cause
    assert {c.cause for c in causes} == {Cause.DELETED_REBORN}


def test_duplicate_birth_reports_the_gate_cost_that_kept_them_apart() -> None:
    far = (A[0] + 6.0, A[1])  # where T0 predicts: 6 m from the detection, cost 1.5 > gate 1
    dup = F(
        gt={1: A}, dets=[(A, K)], live={0: far}, match={1: (0, Stage.BEV)}, out={1: A}, born=[1]
    )
    (sw,) = _switches(_play([*_steady(), dup]))
    assert sw.cause is Cause.DUPLICATE_BIRTH
    assert sw.evidence["old_cost_to_birth_det"] == pytest.approx(1.5)
    assert sw.evidence["old_gate"] == GATE


def test_old_track_took_another_objects_detection() -> None:
    both = _two_lanes()
    mid = ((A[0] + B[0]) / 2, (A[1] + B[1]) / 2)
    swap = F(
        gt={1: A, 2: B},
        dets=[(A, K), (B, K)],
        live={0: mid, 1: mid},
        match={0: (1, Stage.BEV), 1: (0, Stage.BEV)},
        out={0: B, 1: A},
    )
    switches = _switches(_play([both, both, both, swap]))
    assert [c.cause for c in switches] == [Cause.OLD_TOOK_OTHER] * 2
    ev = switches[0].evidence
    assert ev["cost_taken"] == pytest.approx(0.75) and ev["cost_to_gt_det"] == pytest.approx(0.75)
    assert ev["margin"] == pytest.approx(0.0)


def test_box_off_target_the_old_track_held_the_detection() -> None:
    dup = (A[0] + 0.1, A[1])
    start = F(gt={1: A}, dets=[(A, K)], live={0: A}, match={0: (0, Stage.BEV)}, out={0: A})
    twin = F(
        gt={1: A},
        dets=[(A, K), (dup, K)],
        live={0: A, 1: dup},
        match={0: (0, Stage.BEV), 1: (1, Stage.BEV)},
        out={0: A, 1: dup},
        born=[],
    )
    off = F(
        gt={1: A},
        dets=[(A, K), (dup, K)],
        live={0: A, 1: dup},
        match={0: (0, Stage.BEV), 1: (1, Stage.BEV)},
        out={0: (A[0] + 3.5, A[1]), 1: dup},
    )
    born = F(**{**twin.__dict__, "live": {0: A}, "match": {0: (0, Stage.BEV)}, "born": [1]})
    (sw,) = _switches(_play([start, born, twin, off]))
    assert sw.cause is Cause.BOX_OFF_TARGET


def test_image_plane_stage_gave_the_detection_to_another_track() -> None:
    fp = (40.0, 20.0)  # a false-positive track far away, not near any GT
    frames = [
        F(
            gt={1: A},
            dets=[(A, K), (fp, K)],
            live={0: A, 1: fp},
            match={0: (0, Stage.BEV), 1: (1, Stage.BEV)},
            out={0: A, 1: fp},
        )
    ] * 3
    rv = F(gt={1: A}, dets=[(A, K)], live={0: A, 1: fp}, match={1: (0, Stage.RV)}, out={1: A})
    (sw,) = _switches(_play([*frames, rv]))
    assert sw.cause is Cause.IMAGE_PLANE
    assert sw.evidence["old_bev_cost"] == pytest.approx(0.0)


def test_an_existing_track_jumps_onto_the_object() -> None:
    both = _two_lanes()
    first = _two_lanes(live={}, born=[0, 1])
    jump = F(
        gt={1: A, 2: B}, dets=[(A, K)], live={0: A, 1: B}, match={1: (0, Stage.BEV)}, out={1: A}
    )
    (sw,) = _switches(_play([first, both, both, jump]))
    assert sw.cause is Cause.TRACK_JUMP
    assert sw.evidence["from_gt"] == 2


def test_gt_id_changed_under_a_steady_track() -> None:
    # object on lane B is labelled GT 2, then (label error) GT 1, which was on lane A before
    f01 = _two_lanes()
    f2 = _two_lanes(gt={2: B})
    f3 = _two_lanes(gt={1: B})
    (sw,) = _switches(_play([f01, f01, f2, f3]))
    assert sw.cause is Cause.GT_ID_CHANGED
    assert sw.evidence["previous_gt"] == 2


@pytest.mark.parametrize(
    ("gap", "cause"),
    [
        (F(gt={1: A, 2: B}, live={0: A}), Cause.MISSED_NO_DETECTION),
        (F(gt={1: A, 2: B}, dets=[(A, DropReason.SCORE)], live={0: A}), Cause.MISSED_BELOW_SCORE),
        (F(gt={1: A, 2: B}, dets=[(A, K)], live={0: A}), Cause.MISSED_OUTSIDE_GATE),
        (
            F(gt={2: B}, dets=[(A, K)], live={0: A}, match={0: (0, Stage.BEV)}),
            Cause.GT_NOT_EVALUATED,
        ),
        (
            F(
                gt={1: A, 2: B},
                dets=[(A, K)],
                live={0: A},
                match={0: (0, Stage.BEV)},
                out={0: (15.0, 0.0)},
            ),
            Cause.BOX_OFF_TARGET,
        ),
        (
            # T0 holds GT 1's detection but is not output (withheld by the track score gate)
            F(gt={1: A, 2: B}, dets=[(A, K)], live={0: A}, match={0: (0, Stage.BEV)}, out={}),
            Cause.NOT_OUTPUT,
        ),
    ],
    ids=lambda v: v.value if isinstance(v, Cause) else "",
)
def test_fragmentation_of_a_steady_track(gap: F, cause: Cause) -> None:
    """T0 keeps GT 1 before and after a 2-frame gap; GT 2 (lane B, its own track) keeps the
    evaluator's timesteps going, as CLEAR needs for a gap."""

    def with_b(f: F) -> F:
        dets = [*f.dets, (B, K)]
        live = {**f.live, 1: B}
        return F(f.gt, dets, live, {**f.match, 1: (len(dets) - 1, Stage.BEV)}, {**f.out, 1: B})

    before = [
        with_b(
            F(gt={1: A, 2: B}, dets=[(A, K)], live={0: A}, match={0: (0, Stage.BEV)}, out={0: A})
        )
    ] * 2
    causes = _play([*before, with_b(gap), with_b(gap), before[0]])
    (frag,) = causes
    assert frag.event.kind is IdEventKind.FRAGMENTATION and frag.event.old_track_id == 0
    assert frag.cause is cause
    assert frag.evidence["gap_frames"] == 2


def test_other_is_a_bucket_for_what_the_log_never_saw() -> None:
    """An event at frames the stage log has no record of cannot be explained: "other"."""
    from tracker.eval.id_switches import IdEvaluation, IdEvent

    frag = IdEvent(IdEventKind.FRAGMENTATION, 5, "car", 1, 0, 0, 0.9, 2)
    switch = IdEvent(IdEventKind.ID_SWITCH, 5, "car", 2, 0, 1, 0.9, 4)
    evaluation = IdEvaluation("x", (frag, switch), (), {})
    causes = classify_events(evaluation, StageLog(), [])
    assert [c.cause for c in causes] == [Cause.OTHER, Cause.OTHER]
    assert other_share({"s": cause_counts(causes)}) == 1.0


def _real_scene(gap: range) -> tuple[list[Frame], list[Frame]]:
    frames, gt = [], []
    for f in range(30):
        # a second car (lane B) keeps the evaluator's timesteps going through the gap
        xy = [(10.0 + 0.5 * f, 0.0), (10.0 + 0.5 * f, 8.0)]
        gt.append(Frame(scene="r", frame_id=f, timestamp_secs=0.1 * f, boxes=_boxes(xy, [7, 8])))
        dets = _boxes(xy[1:] if f in gap else xy)
        frames.append(Frame(scene="r", frame_id=f, timestamp_secs=0.1 * f, boxes=dets))
    return frames, gt


@pytest.mark.parametrize(
    ("gap", "kinds", "cause"),
    [
        (range(8, 10), [IdEventKind.FRAGMENTATION], Cause.MISSED_NO_DETECTION),
        (range(8, 22), [IdEventKind.FRAGMENTATION, IdEventKind.ID_SWITCH], Cause.DELETED_REBORN),
    ],
)
def test_the_real_tracker_short_and_long_gaps(gap: range, kinds, cause: Cause) -> None:
    """Car config: a 2-frame detector gap is bridged (fragmentation), a 14-frame one outlives
    max_misses = 10 (deleted, reborn: an ID switch)."""
    config = load_config(  # the gaps are measured against test-owned lifecycle numbers
        "kitti",
        overrides={
            "categories": ["car"],
            "category": {"car": {"lifecycle": {"max_misses": 10, "max_misses_output": 0}}},
        },
    )
    frames, gt = _real_scene(gap)
    log = StageLog()
    seen: list[object] = []
    outputs = run_scene(frames, config, observer=Tee(log, seen.append)).outputs
    assert seen  # Tee calls every observer
    evaluation = bev_id_events(outputs, gt, categories=["car"])
    causes = classify_events(evaluation, log, gt)
    assert [c.event.kind for c in causes] == kinds
    assert {c.cause for c in causes} == {cause}
    counts = {"r": cause_counts(causes)}
    assert counts["r"]["car"]["Frag"][cause.value] == 1
    table = "\n".join(cause_table_markdown(counts))
    assert f"| {cause.value} |" in table and "| other |" in table
    assert other_share(counts) == 0.0
