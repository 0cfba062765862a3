"""tracker/exchange.py: two neighbours' exchanged tails given back offline, while tracks that
cross, overtake or are right stay as they are."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.categories import CATEGORIES, category_index
from tracker.config import load_config
from tracker.events import TrackOutput, TrackStatus
from tracker.exchange import (
    MIN_SIDE,
    NEAR_M,
    _neighbour_frames,
    exchange_gain,
    exchange_tails,
    window_gains,
)
from tracker.frame import Frame
from tracker.pipeline import offline_postprocess

PED = category_index("pedestrian")
SIGMA = 0.3  # m per axis: the robustness benchmark's double noise
FRAMES = 80
DT = 0.1


def _pair(
    start_b: tuple[float, float], velocity_b: tuple[float, float], seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """(2, F, 2) noisy centres of pedestrian A (from (0, 0) at 1.4 m/s along x) and B, and the
    (2, F, 2) true ones."""
    t = np.arange(FRAMES) * DT
    a = np.column_stack([1.4 * t, np.zeros(FRAMES)])
    b = np.column_stack([start_b[0] + velocity_b[0] * t, start_b[1] + velocity_b[1] * t])
    truth = np.stack([a, b])
    noise = np.random.default_rng(seed).normal(0.0, SIGMA, truth.shape)
    return truth + noise, truth


def _rows(centres: np.ndarray, exchanged_from: int | None) -> tuple[np.ndarray, ...]:
    """(track id, frame, xy, category) of both objects' rows: A as track 1 and B as track 2,
    the ids exchanged from frame ``exchanged_from`` on."""
    frame = np.tile(np.arange(FRAMES), 2)
    obj = np.repeat([0, 1], FRAMES)
    track = np.where(obj == 0, 1, 2)
    if exchanged_from is not None:
        track = np.where(frame >= exchanged_from, 3 - track, track)
    xy = centres.reshape(-1, 2)
    return track, frame, xy, np.full(2 * FRAMES, PED), obj


def _exchange(track: np.ndarray, frame: np.ndarray, xy: np.ndarray, cat: np.ndarray, **kw):
    variance = np.full(len(CATEGORIES), np.nan)
    variance[PED] = kw.pop("variance", SIGMA**2)
    return exchange_tails(
        track, frame, np.arange(FRAMES) * DT, xy, cat, np.arange(len(track)), variance,
        kw.pop("window", 3.0),
    )  # fmt: skip


def test_an_exchange_between_two_walking_together_is_given_back() -> None:
    """Side by side 0.6 m apart, σ 0.3 m: the ids exchanged at frame 40 come back, each object
    under one id again but in a frame or two where the noise puts the exchange (before: half
    and half), at any seed tried."""
    for seed in range(5):
        noisy, _ = _pair((0.0, 0.6), (1.4, 0.0), seed)
        track, frame, xy, cat, obj = _rows(noisy, exchanged_from=40)
        fixed = _exchange(track, frame, xy, cat)
        for k in (0, 1):
            ids, count = np.unique(fixed[obj == k], return_counts=True)
            assert count.max() >= FRAMES - 3, seed
            assert ids[count.argmax()] == (1, 2)[k]  # the id it had before the exchange


@pytest.mark.parametrize(
    ("start_b", "velocity_b"),
    [
        ((0.0, 0.6), (1.4, 0.0)),  # walking together, tracked right
        ((11.2, 0.5), (-1.4, 0.0)),  # walking toward each other, passing 0.5 m apart at 4 s
        ((-1.5, 0.5), (1.9, 0.0)),  # B overtakes A 0.5 m to its side
    ],
)
def test_right_tracks_are_left_alone(start_b: tuple, velocity_b: tuple) -> None:
    for seed in range(10):
        noisy, _ = _pair(start_b, velocity_b, seed)
        track, frame, xy, cat, _ = _rows(noisy, exchanged_from=None)
        assert np.array_equal(_exchange(track, frame, xy, cat), track), seed
        # and on clean boxes, judged with a tiny noise estimate
        _, truth = _pair(start_b, velocity_b, seed)
        track, frame, xy, cat, _ = _rows(truth, exchanged_from=None)
        assert np.array_equal(_exchange(track, frame, xy, cat, variance=1e-4), track)


def test_epoch_times_two_pairs_and_a_class_without_an_estimate() -> None:
    """Times in epoch seconds (nuScenes, Waymo) give the same exchange as times from 0; two
    exchanged pairs far apart are both given back in one call; cars beside them, with no noise
    estimate for their class, are left alone."""
    noisy, _ = _pair((0.0, 0.6), (1.4, 0.0), 2)
    track, frame, xy, cat, obj = _rows(noisy, exchanged_from=40)
    # a second pair 50 m away, exchanged at frame 30, and a third pair of cars, exchanged too
    far = noisy + np.array([0.0, 50.0])
    cars = noisy + np.array([0.0, -50.0])
    track = np.concatenate([track, track + 10, track + 20])
    track[2 * FRAMES : 4 * FRAMES] = np.where(
        (frame >= 30) & (frame < 40),
        3 - (track[2 * FRAMES : 4 * FRAMES] - 10) + 10,
        track[2 * FRAMES : 4 * FRAMES],
    )  # (the second pair: exchanged from frame 30 on)
    frame3 = np.tile(frame, 3)
    xy3 = np.concatenate([xy, far.reshape(-1, 2), cars.reshape(-1, 2)])
    cat3 = np.concatenate([cat, cat, np.full(2 * FRAMES, category_index("car"))])
    obj3 = np.concatenate([obj, obj + 2, obj + 4])
    variance = np.full(len(CATEGORIES), np.nan)
    variance[PED] = SIGMA**2
    results = []
    for t0 in (0.0, 1.5e9):
        times = t0 + np.arange(FRAMES) * DT
        fixed = exchange_tails(
            track, frame3, times, xy3, cat3, np.arange(len(track)), variance, 3.0
        )
        results.append(fixed)
        for k in range(4):  # both pedestrian pairs given back
            assert np.unique(fixed[obj3 == k], return_counts=True)[1].max() >= FRAMES - 3, (t0, k)
        assert np.array_equal(fixed[cat3 != PED], track[cat3 != PED])  # no car estimate
    assert np.array_equal(*results)


def test_the_config_refuses_a_negative_or_infinite_span() -> None:
    from tracker.errors import InputError

    for bad in (-1.0, float("inf"), float("nan")):
        with pytest.raises(InputError, match=r"offline\.exchange_seconds"):
            load_config("kitti_offline", overrides={"offline": {"exchange_seconds": bad}})


def test_off_or_without_a_noise_estimate_nothing_changes() -> None:
    noisy, _ = _pair((0.0, 0.6), (1.4, 0.0), 0)
    track, frame, xy, cat, _ = _rows(noisy, exchanged_from=40)
    assert np.array_equal(_exchange(track, frame, xy, cat, window=0.0), track)
    assert np.array_equal(_exchange(track, frame, xy, cat, variance=np.nan), track)


def test_the_gain_is_the_step_a_line_cannot_follow() -> None:
    t = np.arange(20.0)
    after = t >= 10
    d = np.where(after[:, None], [-0.6, 0.0], [0.6, 0.0])  # a clean exchange
    assert exchange_gain(t, d, after) > 0.6**2 * 20 * 0.2  # a line takes 3/4 of a step
    assert exchange_gain(t, -d * np.where(after, -1, 1)[:, None], after) < 0  # none: a constant
    crossing = np.column_stack([0.1 * (10 - t), np.zeros(20)])  # d through 0 at a steady rate
    assert exchange_gain(t, crossing, after) < 0


def test_window_gains_equal_the_line_fits_they_replace() -> None:
    """The prefix-sum gains at every start equal exchange_gain's least-squares fits over the
    same window (frames with gaps, uneven times), and are -inf where a side is short."""
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.08, 0.12, 300))
    frame = np.sort(rng.choice(300, 180, replace=False))
    d = rng.normal(0.0, 0.5, (180, 2)) + np.where(frame[:, None] > 150, [-0.6, 0.2], [0.6, 0.0])
    starts = np.arange(1, 300)
    got = window_gains(times[frame], d, frame, starts, times, 1.5)
    for k, start in enumerate(starts):
        lag = times[frame] - times[start]
        inside = (lag >= -1.5 - 1e-6) & (lag < 1.5 - 1e-6)
        after = frame >= start
        if (inside & ~after).sum() < MIN_SIDE or (inside & after).sum() < MIN_SIDE:
            assert got[k] == -np.inf
        else:
            want = exchange_gain(times[frame[inside]], d[inside], after[inside])
            assert got[k] == pytest.approx(want, rel=1e-9, abs=1e-9)
    assert np.isfinite(got).sum() > 200 and got.max() > 0


def test_neighbour_frames_equal_comparing_every_pair_of_a_frames_rows() -> None:
    rng = np.random.default_rng(5)
    track = rng.integers(0, 12, 400)
    frame = rng.integers(0, 40, 400)
    xy = rng.uniform(0.0, 6.0, (400, 2))
    want: dict[tuple[int, int], set[int]] = {}
    for p in range(400):
        for q in range(p + 1, 400):
            a, b = sorted((int(track[p]), int(track[q])))
            if frame[p] == frame[q] and a != b and np.linalg.norm(xy[p] - xy[q]) < NEAR_M:
                want.setdefault((a, b), set()).add(int(frame[p]))
    got = _neighbour_frames(track, frame, xy)
    assert [pair for pair, _ in got] == sorted(want)
    assert all(list(frames) == sorted(want[pair]) for pair, frames in got)
    assert _neighbour_frames(track[:1], frame[:1], xy[:1]) == []


def test_offline_mode_gives_the_tails_back() -> None:
    """Through offline_postprocess: with offline.exchange_seconds and the tracker's noise
    estimate, each pedestrian's rows end under one id; without the estimate, as written."""
    noisy, _ = _pair((0.0, 0.6), (1.4, 0.0), 1)
    frames, outputs = [], []
    for f in range(FRAMES):
        boxes = Boxes.create(
            xyz=[[*noisy[0, f], 0.9], [*noisy[1, f], 0.9]], lwh=[[0.8, 0.6, 1.7]] * 2,
            yaw=[0.0, 0.0], category=[PED, PED], score=[0.9, 0.9],
        )  # fmt: skip
        frames.append(Frame(scene="s", frame_id=f, timestamp_secs=f * DT, boxes=boxes))
        ids = [1, 2] if f < 40 else [2, 1]  # row k is detection k (object k)
        order = np.argsort(ids)
        written = boxes.replace(track_id=np.array(ids))[order]
        outputs.append(
            TrackOutput(
                "s", f, f * DT, written, np.zeros((2, 2)),
                np.full(2, TrackStatus.CONFIRMED, dtype=np.int8), order.astype(np.int64),
                np.ones(2, dtype=np.int8),
            )
        )  # fmt: skip
    config = load_config("kitti_offline", overrides={"offline": {"exchange_seconds": 3.0}})
    variance = np.full(len(CATEGORIES), np.nan)
    variance[PED] = SIGMA**2

    def ids_of_object_a(**kw) -> np.ndarray:
        result = offline_postprocess(outputs, config, frames=frames, **kw)
        # object A walks along y = 0, B along y = 0.6: the smoothed rows keep to their sides
        ids = np.concatenate([o.boxes.track_id[o.boxes.xyz[:, 1] < 0.3] for o in result])
        return np.unique(ids, return_counts=True)[1]

    assert (
        ids_of_object_a(noise_variance=variance).max() >= FRAMES - 3
    )  # one id, but a frame or two
    assert ids_of_object_a().max() <= 45  # as written: half under each id
