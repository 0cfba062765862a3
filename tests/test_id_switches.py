"""ID-switch and fragmentation events: exactly what TrackEval's CLEAR metric counts."""

from __future__ import annotations

import contextlib
import io
import tempfile
from pathlib import Path

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.categories import category_index
from tracker.config import load_config
from tracker.eval.id_switches import (
    IdEventKind,
    bev_id_events,
    clear_id_events,
    kitti_id_events,
    kitti_num_timesteps,
)
from tracker.events import TrackOutput
from tracker.frame import Frame
from tracker.io.baseversion import read_baseversion
from tracker.pipeline import run_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"
CAR = category_index("car")


def _trackeval_clear(gt_ids, trk_ids, sims):
    import trackeval

    all_gt = np.unique(np.concatenate(gt_ids)) if sum(map(len, gt_ids)) else np.zeros(0, int)
    all_trk = np.unique(np.concatenate(trk_ids)) if sum(map(len, trk_ids)) else np.zeros(0, int)
    data = {
        "gt_ids": [np.searchsorted(all_gt, g) for g in gt_ids],
        "tracker_ids": [np.searchsorted(all_trk, t) for t in trk_ids],
        "similarity_scores": sims,
        "num_gt_ids": len(all_gt),
        "num_tracker_ids": len(all_trk),
        "num_gt_dets": sum(map(len, gt_ids)),
        "num_tracker_dets": sum(map(len, trk_ids)),
        "num_timesteps": len(gt_ids),
    }
    with contextlib.redirect_stdout(io.StringIO()):
        metric = trackeval.metrics.CLEAR({"PRINT_CONFIG": False})
    return metric.eval_sequence(data)


def _random_sequence(seed: int) -> tuple[list, list, list]:
    """GT and tracker ids over time with overlapping similarities and frequent swaps."""
    rng = np.random.default_rng(seed)
    gt_ids, trk_ids, sims = [], [], []
    for _ in range(40):
        g = np.flatnonzero(rng.uniform(size=6) < 0.7) * 3 + 1  # sparse, non-contiguous ids
        t = np.flatnonzero(rng.uniform(size=8) < 0.6) * 5 + 2
        s = rng.uniform(0.0, 1.0, (len(g), len(t)))
        s[s < 0.45] = 0.0
        gt_ids.append(g)
        trk_ids.append(t)
        sims.append(s)
    if seed % 5 == 0:  # timesteps without GT or without tracks (CLEAR's special cases)
        gt_ids[3], sims[3] = gt_ids[3][:0], sims[3][:0]
        trk_ids[7], sims[7] = trk_ids[7][:0], sims[7][:, :0]
    return gt_ids, trk_ids, sims


@pytest.mark.parametrize("seed", range(40))
def test_counts_equal_trackeval_clear_on_random_sequences(seed: int) -> None:
    gt_ids, trk_ids, sims = _random_sequence(seed)
    events, matches = clear_id_events(
        gt_ids, trk_ids, sims, frame_ids=range(len(gt_ids)), category="car"
    )
    ref = _trackeval_clear(gt_ids, trk_ids, sims)
    assert sum(e.kind is IdEventKind.ID_SWITCH for e in events) == ref["IDSW"]
    assert sum(e.kind is IdEventKind.FRAGMENTATION for e in events) == ref["Frag"]
    assert sum(len(m[0]) for m in matches) == ref["CLR_TP"]


def test_a_hand_made_switch_and_fragmentation() -> None:
    one = np.ones((1, 1))
    gt_ids = [np.array([7])] * 5
    trk_ids = [np.array([5]), np.array([5]), np.array([9]), np.array([9]), np.array([9])]
    # frame 13: track 9 is there but overlaps too little: GT 7 is not tracked, then is again
    sims = [0.9 * one, 0.8 * one, 0.7 * one, 0.1 * one, 0.6 * one]
    events, _ = clear_id_events(
        gt_ids, trk_ids, sims, frame_ids=[10, 11, 12, 13, 14], category="car"
    )
    switch, frag = events
    assert switch.kind is IdEventKind.ID_SWITCH
    assert (switch.frame_id, switch.gt_id, switch.old_track_id, switch.new_track_id) == (
        12,
        7,
        5,
        9,
    )
    assert switch.last_frame_id == 11
    assert switch.similarity == pytest.approx(0.7) and switch.cost == pytest.approx(0.3)
    assert frag.kind is IdEventKind.FRAGMENTATION
    assert (frag.frame_id, frag.old_track_id, frag.new_track_id, frag.last_frame_id) == (
        14,
        9,
        9,
        12,
    )
    ref = _trackeval_clear(gt_ids, trk_ids, sims)
    assert (ref["IDSW"], ref["Frag"]) == (1, 1)


def test_a_frame_without_tracks_is_not_a_gap_for_clear() -> None:
    """CLEAR skips a timestep without any track box without forgetting the last match, so the
    GT is not fragmented by it (a quirk we reproduce, not fix)."""
    one = np.ones((1, 1))
    gt_ids = [np.array([7])] * 3
    trk_ids = [np.array([5]), np.zeros(0, int), np.array([5])]
    sims = [0.9 * one, np.zeros((1, 0)), 0.9 * one]
    events, _ = clear_id_events(gt_ids, trk_ids, sims, frame_ids=[0, 1, 2], category="car")
    assert events == []
    assert _trackeval_clear(gt_ids, trk_ids, sims)["Frag"] == 0


def test_kitti_events_equal_trackeval_on_the_sample() -> None:
    """The reference config switches ids on sequence 0001; every one is an event."""
    if not (SAMPLE / "detections.json.gz").is_file():
        pytest.skip("sample data missing")
    from tracker.eval.kitti import evaluate_kitti
    from tracker.io.writers import write_kitti_sequence

    frames = read_baseversion(SAMPLE / "detections.json.gz", fallback_frame_rate_hz=10.0)["0001"]
    outputs = run_scene(frames, load_config("kitti_reference")).outputs
    label = SAMPLE / "raw" / "training" / "label_02" / "0001.txt"
    classes = ("car", "pedestrian")
    evaluation = kitti_id_events(outputs, frames, label, classes=classes)
    with tempfile.TemporaryDirectory() as tmp:
        write_kitti_sequence(Path(tmp) / "0001.txt", outputs, frames)
        with contextlib.redirect_stdout(io.StringIO()):
            metrics = evaluate_kitti(
                label_dir=label.parent,
                result_dir=Path(tmp),
                seq_lengths={"0001": kitti_num_timesteps(label, frames)},
                classes=classes,
            )
    for cls in classes:
        assert evaluation.counts[cls]["IDSW"] == metrics[cls]["IDSW"]
        assert evaluation.counts[cls]["Frag"] == metrics[cls]["Frag"]
    assert metrics["car"]["IDSW"] > 0
    switches = evaluation.id_switches
    assert len(switches) == sum(metrics[c]["IDSW"] for c in classes)
    output_ids = {int(t) for o in outputs for t in o.boxes.track_id}
    for e in switches:
        assert e.old_track_id != e.new_track_id
        assert {e.old_track_id, e.new_track_id} <= output_ids
        assert e.similarity >= 0.5 and e.last_frame_id < e.frame_id
    # matches carry original ids: the matched track is in the output of that frame
    by_frame = {o.frame_id: o for o in outputs}
    for m in evaluation.matches[:200]:
        if len(m.track_ids):
            assert set(m.track_ids.tolist()) <= set(by_frame[m.frame_id].boxes.track_id.tolist())


def _frame(frame_id: int, xyz: list[list[float]], ids: list[int]) -> Frame:
    boxes = Boxes.create(
        xyz=xyz,
        lwh=[[4.0, 2.0, 1.5]] * len(ids),
        yaw=[0.0] * len(ids),
        category=[CAR] * len(ids),
        track_id=ids,
    )
    return Frame(scene="s", frame_id=frame_id, timestamp_secs=frame_id * 0.1, boxes=boxes)


def _output(frame: Frame) -> TrackOutput:
    n = len(frame.boxes)
    return TrackOutput(
        "s",
        frame.frame_id,
        frame.timestamp_secs,
        frame.boxes,
        np.zeros((n, 2)),
        np.ones(n, np.int8),
        np.zeros(n, np.int64),
        np.ones(n, np.int8),
    )


def test_bev_variant_sees_two_tracks_swap_objects() -> None:
    """Two cars side by side; the tracker swaps their ids at frame 3: one ID switch each."""
    gt, out = [], []
    for f in range(6):
        xyz = [[10.0 + f, 0.0, 0.75], [10.0 + f, 5.0, 0.75]]
        gt.append(_frame(f, xyz, [1, 2]))
        out.append(_output(_frame(f, xyz, [100, 200] if f < 3 else [200, 100])))
    evaluation = bev_id_events(out, gt)
    switches = evaluation.id_switches
    assert [(e.frame_id, e.gt_id, e.old_track_id, e.new_track_id) for e in switches] == [
        (3, 1, 100, 200),
        (3, 2, 200, 100),
    ]
    assert evaluation.counts == {"car": {"IDSW": 2, "Frag": 0}}
    assert all(e.similarity == pytest.approx(1.0) for e in switches)
