"""Offline position smoothing (tracker.pipeline.smooth_positions): a centred local quadratic fit
per track that keeps constant-acceleration motion, averages box noise and never mixes tracks or
bridges gaps."""

from __future__ import annotations

import numpy as np

from tracker.pipeline import mean_size_per_track, smooth_positions


def _track(n: int, tid: int, start: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(n, dtype=float)
    xyz = np.column_stack([2.0 + 1.5 * t + 0.02 * t**2, -3.0 + 0.4 * t, np.full(n, 1.0)])
    return xyz, np.full(n, tid), start + np.arange(n)


def test_constant_acceleration_passes_unchanged() -> None:
    xyz, tid, frames = _track(40, 1)
    out = smooth_positions(xyz, tid, frames, np.ones(40, bool), 15)
    np.testing.assert_allclose(out, xyz, atol=1e-9)


def test_noise_averages_out() -> None:
    truth, tid, frames = _track(60, 1)
    rng = np.random.default_rng(0)
    noisy = truth + rng.normal(0.0, 0.15, truth.shape)
    out = smooth_positions(noisy, tid, frames, np.ones(60, bool), 15)
    before = np.sqrt(((noisy - truth)[:, :2] ** 2).mean())
    after = np.sqrt(((out - truth)[:, :2] ** 2).mean())
    assert after < 0.5 * before


def test_tracks_gaps_short_runs_and_dropped_rows_are_kept_apart() -> None:
    a, ta, fa = _track(20, 1)
    b, tb, fb = _track(20, 2)
    b = b + 100.0  # another object far away: mixing would pull it
    xyz = np.concatenate([a, b])
    tid = np.concatenate([ta, tb])
    frames = np.concatenate([fa, fb])
    rng = np.random.default_rng(1)
    noisy = xyz + rng.normal(0.0, 0.1, xyz.shape)
    keep = np.ones(len(xyz), bool)
    keep[5] = False  # a row offline removed: untouched
    order = rng.permutation(len(xyz))  # rows in any order
    out = smooth_positions(noisy[order], tid[order], frames[order], keep[order], 7)
    back = np.empty_like(out)
    back[order] = out
    assert np.array_equal(back[5], noisy[5])
    assert np.abs(back - xyz).max() < 1.0  # nothing pulled towards the other track
    # a gap splits the run: frames 0-1 (2 rows, too short) stay as they are
    gap_frames = np.array([0, 1, 5, 6, 7, 8, 9])
    pts = rng.normal(0.0, 1.0, (7, 3))
    out = smooth_positions(pts, np.ones(7, int), gap_frames, np.ones(7, bool), 5)
    assert np.array_equal(out[:2], pts[:2]) and not np.array_equal(out[2:], pts[2:])


def test_mean_size_per_track_is_one_size_per_track_over_kept_rows() -> None:
    lwh = np.array(
        [[4.0, 1.8, 1.5], [4.4, 2.0, 1.7], [0.8, 0.6, 1.7], [9.0, 9.0, 9.0], [0.6, 0.6, 1.9]]
    )
    tid = np.array([3, 3, 7, 3, 7])
    keep = np.array([True, True, True, False, True])  # row 3: removed offline, untouched
    out = mean_size_per_track(lwh, tid, keep)
    np.testing.assert_allclose(out[[0, 1]], [[4.2, 1.9, 1.6]] * 2)
    np.testing.assert_allclose(out[[2, 4]], [[0.7, 0.6, 1.8]] * 2)
    assert np.array_equal(out[3], lwh[3])
    assert np.array_equal(mean_size_per_track(lwh, tid, np.zeros(5, bool)), lwh)


def test_offline_mode_writes_one_size_per_track() -> None:
    """kitti_offline (constant_size on): a car whose detected length alternates 4.0 / 4.6 m is
    written with one size, the mean of its rows; with the switch off the sizes vary."""
    from tracker.boxes import Boxes
    from tracker.categories import category_index
    from tracker.config import load_config
    from tracker.frame import Frame
    from tracker.pipeline import run_scene

    car = category_index("car")
    frames = [
        Frame(
            scene="s", frame_id=i, timestamp_secs=0.1 * i,
            boxes=Boxes.create(
                xyz=[[10.0 + i, 0.0, 0.8]], lwh=[[4.0 + 0.6 * (i % 2), 1.8, 1.6]], yaw=[0.0],
                category=[car], score=[0.99],
            ),
        )
        for i in range(12)
    ]  # fmt: skip

    def lengths(constant_size: bool) -> np.ndarray:
        overrides = {"categories": ["car"], "offline": {"constant_size": constant_size}}
        outputs = run_scene(frames, load_config("kitti_offline", overrides=overrides)).outputs
        return np.concatenate([o.boxes.lwh[:, 0] for o in outputs])

    on, off = lengths(True), lengths(False)
    assert len(on) == 12 and np.ptp(on) < 1e-9 and 4.0 < on[0] < 4.6
    assert np.ptp(off) > 0.05


def test_a_class_can_ask_more_of_a_whole_track_offline() -> None:
    """lifecycle.offline_track_score_min: offline keeps a track of that class only if its mean
    log-odds also exceeds it; other classes keep offline.track_score_min alone."""
    from tracker.boxes import Boxes
    from tracker.categories import category_index
    from tracker.config import load_config
    from tracker.frame import Frame
    from tracker.pipeline import run_scene

    car, ped = category_index("car"), category_index("pedestrian")
    # two cars far apart (p 0.6 and 0.9: log-odds 0.41 and 2.2) and a pedestrian at p 0.6
    frames = [
        Frame(
            scene="s", frame_id=i, timestamp_secs=0.1 * i,
            boxes=Boxes.create(
                xyz=[[10.0 + 0.5 * i, 0.0, 0.8], [10.0 + 0.5 * i, 30.0, 0.8], [5.0, -20.0, 0.9]],
                lwh=[[4.0, 1.8, 1.6], [4.0, 1.8, 1.6], [0.8, 0.6, 1.7]], yaw=[0.0, 0.0, 0.0],
                category=[car, car, ped], score=[0.6, 0.9, 0.6],
            ),
        )
        for i in range(12)
    ]  # fmt: skip

    def kept(car_min: float) -> tuple[set[int], set[int]]:
        overrides = {
            "categories": ["car", "pedestrian"],
            "category": {"car": {"lifecycle": {"offline_track_score_min": car_min}}},
        }
        result = run_scene(frames, load_config("kitti_offline", overrides=overrides))
        rows = Boxes.concat([o.boxes for o in result.outputs])
        cars = {round(float(y)) for y in rows.xyz[rows.category == car, 1]}
        return cars, {int(c) for c in rows.category}

    assert kept(float("-inf")) == ({0, 30}, {car, ped})  # offline.track_score_min 0: all kept
    assert kept(1.0) == ({30}, {car, ped})  # the p 0.6 car goes, the p 0.6 pedestrian stays


def _walker_frames(*, others: bool) -> list:
    """A pedestrian walking at 1 m/s along x, seen in frames 0-14 and 40-54 (hidden 2.5 s: longer
    than the online tracker coasts), and, with ``others``, from frame 40 a pedestrian 1.5 m beside
    where the walker reappears and a car 0.3 m from it."""
    from tracker.boxes import Boxes
    from tracker.categories import category_index
    from tracker.frame import Frame

    car, ped = category_index("car"), category_index("pedestrian")
    frames = []
    for i in range(55):
        xyz, lwh, cat = [], [], []
        if i < 15 or i >= 40:
            xyz.append([8.0 + 0.1 * i, 0.0, 0.9])
            lwh.append([0.8, 0.6, 1.7])
            cat.append(ped)
        if others and i >= 40:
            xyz.append([8.0 + 0.1 * i, 1.5, 0.9])
            lwh.append([0.8, 0.6, 1.7])
            cat.append(ped)
            xyz.append([8.0 + 0.1 * i, -0.3, 0.8])
            lwh.append([4.0, 1.8, 1.6])
            cat.append(car)
        frames.append(
            Frame(
                scene="s", frame_id=i, timestamp_secs=0.1 * i,
                boxes=Boxes.create(
                    xyz=xyz, lwh=lwh, yaw=np.zeros(len(xyz)), category=cat,
                    score=np.full(len(xyz), 0.9),
                ),
            )
        )  # fmt: skip
    return frames


def test_offline_stitching_joins_a_track_hidden_longer_than_the_tracker_coasts() -> None:
    """offline.stitch_max_gap: the walker's two tracks become one, its hidden frames filled; off,
    or with a shorter gap, two ids. One track continues one other (the nearer pedestrian), and
    only of its class (not the car at the spot)."""
    from tracker.boxes import Boxes
    from tracker.categories import category_index
    from tracker.config import load_config
    from tracker.pipeline import run_scene

    def ids(frames: list, gap: int) -> dict[int, list[int]]:
        overrides = {"offline": {"stitch_max_gap": gap, "stitch_distance_m": 2.0}}
        result = run_scene(frames, load_config("kitti_offline", overrides=overrides))
        by_id: dict[int, list[int]] = {}
        for out in result.outputs:
            for t in out.boxes.track_id.tolist():  # (only the walker's rows here)
                by_id.setdefault(t, []).append(out.frame_id)
        return by_id

    walker = _walker_frames(others=False)
    assert len(ids(walker, 0)) == 2  # off: the tracker lost it, a new track took over
    (frames,) = ids(walker, 40).values()
    assert frames == list(range(55))  # one track, the hidden 25 frames interpolated
    assert len(ids(walker, 20)) == 2  # a gap longer than stitch_max_gap is not bridged
    overrides = {"offline": {"stitch_max_gap": 40, "stitch_distance_m": 2.0}}
    crowd = run_scene(
        _walker_frames(others=True), load_config("kitti_offline", overrides=overrides)
    )
    rows = Boxes.concat([o.boxes for o in crowd.outputs])
    ped = rows.category == category_index("pedestrian")
    on_walker = ped & (np.abs(rows.xyz[:, 1]) < 0.5)
    beside = ped & (np.abs(rows.xyz[:, 1] - 1.5) < 0.5)
    car = ~ped
    assert len(set(rows.track_id[on_walker].tolist())) == 1 and on_walker.sum() == 55
    for other in (beside, car):  # each keeps one id of its own
        assert other.sum() == 15 and len(set(rows.track_id[other].tolist())) == 1
        assert not set(rows.track_id[other].tolist()) & set(rows.track_id[on_walker].tolist())
