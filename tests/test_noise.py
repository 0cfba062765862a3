"""The detections' own position noise (tracker.noise): the second-difference estimator recovers
a known white noise, ignores the path's motion and a share of clutter, keeps categories apart,
skips uneven frame steps, and the tracker's r follows it where ``pose.r_scale`` asks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.categories import category_index
from tracker.config import load_config
from tracker.errors import InputError
from tracker.frame import Frame
from tracker.kalman import Axis
from tracker.mctracker import MCTracker
from tracker.noise import MIN_SAMPLES, PositionNoise, second_difference_variance

CAR, PED, CYC = category_index("car"), category_index("pedestrian"), category_index("cyclist")


def _scene(
    rng,
    n_objects=8,
    frames=60,
    sigma=0.2,
    category=CAR,
    clutter=0.0,
    spacing=30.0,
    speed=(5.0, 15.0),
    length=4.0,
):
    """(frames) lists of (xy, length, category): objects ``length`` long on curved paths (speed
    in ``speed`` m/s, slowly turning, side by side) seen with white noise ``sigma`` per axis, plus
    ``clutter`` false boxes per frame (expected) anywhere in a 200 m square."""
    t = 0.1 * np.arange(frames)
    start = np.column_stack([np.zeros(n_objects), np.arange(n_objects) * spacing])
    speed = rng.uniform(*speed, n_objects)[:, None]
    turn = rng.uniform(-0.02, 0.02, n_objects)  # rad/s: lanes 30 m apart never meet
    heading = turn[None, :] * t[:, None]
    vel = speed * np.stack([np.cos(heading), np.sin(heading)], axis=-1)  # (T, n, 2)
    path = start + np.cumsum(vel * 0.1, axis=0)
    out = []
    for k in range(frames):
        xy = path[k] + rng.normal(0, sigma, (n_objects, 2))
        cat = np.full(n_objects, category)
        n_fp = rng.poisson(clutter)
        if n_fp:
            xy = np.vstack([xy, rng.uniform(-100, 100, (n_fp, 2))])
            cat = np.r_[cat, np.full(n_fp, category)]
        out.append((xy, np.full(len(xy), length), cat))
    return t, out


def _feed(t, scene, estimator=None):
    est = estimator or PositionNoise(8)
    for time, (xy, length, cat) in zip(t, scene, strict=True):
        est.update(time, xy, length, cat)
    return est


@pytest.mark.parametrize("sigma", [0.05, 0.2, 0.4])
def test_recovers_a_known_white_noise(sigma: float) -> None:
    rng = np.random.default_rng(int(sigma * 100))
    t, scene = _scene(rng, sigma=sigma, frames=200)
    got = _feed(t, scene).variance()[CAR]
    assert got == pytest.approx(sigma**2, rel=0.12)


def test_noise_as_large_as_the_box_is_not_read_low(monkeypatch: pytest.MonkeyPatch) -> None:
    """Pedestrians (0.8 m boxes, walking) with 0.3 m of noise: a box's step from the frame
    before often exceeds its length, so links within the length alone keep the small steps and
    read the noise low; within 5 σ of the estimate so far they keep nearly all of them."""
    rng = np.random.default_rng(11)
    t, scene = _scene(rng, sigma=0.3, frames=300, category=PED, speed=(1.0, 1.5), length=0.8)
    sigma = np.sqrt(_feed(t, scene).variance()[PED])
    assert sigma == pytest.approx(0.3, rel=0.08)
    monkeypatch.setattr("tracker.noise.LINK_SIGMAS", 0.0)  # the box's length alone
    assert np.sqrt(_feed(t, scene).variance()[PED]) < 0.9 * 0.3


def test_the_histogram_median_equals_the_exact_one() -> None:
    """One object: the running estimate equals the exact-median reference to the bins' width."""
    rng = np.random.default_rng(1)
    t, scene = _scene(rng, n_objects=1, frames=400, sigma=0.1)
    exact = second_difference_variance(np.vstack([xy for xy, _, _ in scene]))
    assert _feed(t, scene).variance()[CAR] == pytest.approx(exact, rel=0.03)


def test_clutter_and_wrong_links_barely_move_it() -> None:
    """Two false boxes per frame (some linked to each other or to real boxes): the median
    keeps the estimate within 15 %; a plain variance would not."""
    rng = np.random.default_rng(2)
    t, scene = _scene(rng, sigma=0.15, frames=200, clutter=2.0)
    assert _feed(t, scene).variance()[CAR] == pytest.approx(0.15**2, rel=0.15)


def test_categories_are_kept_apart() -> None:
    """Cars with 0.3 m noise and pedestrians with 0.05 m on the same ground: each estimate is its
    own class's, and no chain crosses classes."""
    rng = np.random.default_rng(3)
    t, cars = _scene(rng, sigma=0.3, frames=150)
    _, peds = _scene(rng, sigma=0.05, frames=150, category=PED)
    scene = [
        (np.vstack([a[0], b[0] + [0.5, 0.0]]), np.r_[a[1], b[1]], np.r_[a[2], b[2]])
        for a, b in zip(cars, peds, strict=True)
    ]  # each pedestrian 0.5 m from a car: nearer than any other box
    var = _feed(t, scene).variance()
    assert var[CAR] == pytest.approx(0.09, rel=0.15)
    assert var[PED] == pytest.approx(0.0025, rel=0.15)


def test_no_estimate_before_enough_samples_and_none_across_uneven_steps() -> None:
    rng = np.random.default_rng(4)
    # one object: a triple (two samples, x and y) per frame from the third on
    t, scene = _scene(rng, n_objects=1, frames=MIN_SAMPLES // 2 + 2)
    assert np.isnan(_feed(t[:-1], scene[:-1]).variance()[CAR])
    assert np.isfinite(_feed(t, scene).variance()[CAR])
    # every other frame missing in time (steps 0.1, 0.2, 0.1, ...): no triple has even steps
    uneven = np.cumsum(np.where(np.arange(len(t)) % 2, 0.2, 0.1))
    est = _feed(uneven, scene)
    assert est.counts.sum() == 0


def _frames(t, scene):
    return [
        Frame(
            scene="s", frame_id=i, timestamp_secs=float(t[i]),
            boxes=Boxes.create(
                xyz=np.column_stack([xy, np.full(len(xy), 0.8)]),
                lwh=np.tile([4.2, 1.8, 1.6], (len(xy), 1)),
                yaw=np.zeros(len(xy)), category=cat, score=np.full(len(xy), 0.99),
            ),
        )
        for i, (xy, _, cat) in enumerate(scene)
    ]  # fmt: skip


@pytest.mark.parametrize("compiled", [False, True])
def test_the_trackers_r_follows_the_estimate(compiled: bool) -> None:
    """With ``pose.r_scale`` the car filter's x and y variances are r_scale × the estimate from
    the frames so far (the config's r until it exists); without, the config's r throughout;
    the compiled and numpy paths agree."""
    rng = np.random.default_rng(5)
    t, scene = _scene(rng, frames=40, sigma=0.2)
    frames = _frames(t, scene)
    fixed = load_config("kitti", overrides={"categories": ["car"], "category": {"car": {
        "pose": {"r_scale": 0.0, "ca": {"r": [0.5, 0.5]}}}}})  # fmt: skip
    scaled = load_config("kitti", overrides={"categories": ["car"], "category": {"car": {
        "pose": {"r_scale": 40.0, "ca": {"r": [0.5, 0.5]}}}}})  # fmt: skip
    a, b = MCTracker(fixed, compiled=compiled), MCTracker(scaled, compiled=compiled)
    est = PositionNoise(8)
    states = []
    for f in frames:
        a.step(f)
        b.step(f)
        est.update(f.timestamp_secs, f.boxes.xyz[:, :2], f.boxes.lwh[:, 0], f.boxes.category)
        var = est.variance()[CAR]
        assert a.motion_r[CAR, Axis.X, 0] == a.motion_r[CAR, Axis.Y, 0] == 0.5
        want = 0.5 if np.isnan(var) else 40.0 * var
        assert b.motion_r[CAR, Axis.X, 0] == pytest.approx(want, rel=1e-12)
        assert b.motion_r[CAR, Axis.Y, 0] == pytest.approx(want, rel=1e-12)
        states.append(b._tracks.motion_x[:, :2, 0].copy())
    assert 40.0 * 0.04 * 0.85 < b.motion_r[CAR, Axis.X, 0] < 40.0 * 0.04 * 1.15
    # the other axes (size, heading) keep the config's values
    np.testing.assert_array_equal(b.motion_r[:, 2:], a.motion_r[:, 2:])
    # the filter uses it: the two trackers' positions differ once it exists
    assert not np.allclose(a._tracks.motion_x[:, :2, 0], states[-1])


def test_compiled_and_numpy_paths_agree_with_r_scale() -> None:
    rng = np.random.default_rng(6)
    t, scene = _scene(rng, frames=30, sigma=0.2)
    config = load_config("kitti", overrides={"categories": ["car"]})
    assert config.per_category["car"].pose.r_scale > 0
    outs = []
    for compiled in (False, True):
        tracker = MCTracker(config, compiled=compiled)
        outs.append([tracker.step(f).boxes.xyz for f in _frames(t, scene)])
    for x, y in zip(*outs, strict=True):
        np.testing.assert_allclose(x, y, atol=1e-9)


@pytest.mark.parametrize("value", [-1.0, "inf"])
def test_a_negative_or_infinite_r_scale_is_refused(value) -> None:
    with pytest.raises(InputError, match=r"category\.car\.pose\.r_scale must be finite"):
        load_config("kitti", overrides={"category": {"car": {"pose": {"r_scale": value}}}})


def test_boxes_without_noise_give_no_estimate() -> None:
    """Noise-free boxes (the ground truth, a simulator): the median of |Δ²z| is below the
    histogram's resolution, so r keeps the config's value instead of vanishing."""
    parked = np.column_stack([np.arange(8) * 10.0, np.zeros(8)])
    t = 0.1 * np.arange(60)
    scene = [(parked, np.full(8, 4.0), np.full(8, CAR)) for _ in t]
    for est in (_feed(t, scene), _feed(t, scene, PositionNoise(8, _kernels_or_none()))):
        assert est.counts[CAR].sum() >= MIN_SAMPLES and np.isnan(est.variance()[CAR])


def _kernels_or_none():
    from tracker.kernels import load

    return load()


def test_a_new_scene_starts_a_new_estimate() -> None:
    rng = np.random.default_rng(10)
    t, scene = _scene(rng, frames=40, sigma=0.3)
    config = load_config("kitti", overrides={"categories": ["car"]})
    tracker = MCTracker(config)
    for f in _frames(t, scene):
        tracker.step(f)
    assert tracker.motion_r[CAR, Axis.X, 0] > 1.0
    other = [dataclasses.replace(f, scene="other") for f in _frames(t, scene)[:2]]
    tracker.step(other[0])
    assert tracker.motion_r[CAR, Axis.X, 0] == config.per_category["car"].pose.ca.r[0]


@pytest.mark.parametrize("multiple", [1.0, 30.0])
def test_offline_smooths_with_the_scenes_estimated_r(multiple: float) -> None:
    """Offline mode's position smoother uses offline.rts_r_multiple times the r the tracker
    ended the scene with (from the whole scene's detections), not the config's prior."""
    from tracker.pipeline import run_scene
    from tracker.smoothing import rts_smooth

    rng = np.random.default_rng(7)
    t, scene = _scene(rng, n_objects=4, frames=40, sigma=0.2)
    frames = _frames(t, scene)
    config = load_config(
        "kitti_offline",
        overrides={"categories": ["car"], "offline": {"rts_r_multiple": multiple}},
    )
    tracker = MCTracker(config)
    for f in frames:
        tracker.step(f)
    r_end = tracker.motion_r
    assert r_end[CAR, Axis.X, 0] != config.per_category["car"].pose.ca.r[0]
    outputs = run_scene(frames, config).outputs
    fi, tid, det_xy, got = [], [], [], []
    for i, o in enumerate(outputs):
        hit = np.flatnonzero(o.det_row >= 0)
        fi += [i] * len(hit)
        tid += o.boxes.track_id[hit].tolist()
        det_xy.append(frames[i].boxes.xyz[o.det_row[hit], :2])
        got.append(o.boxes.xyz[hit, :2])
    fi, tid, det_xy, got = np.array(fi), np.array(tid), np.vstack(det_xy), np.vstack(got)
    cat = np.full(len(fi), CAR)
    want = rts_smooth(t, fi, tid, det_xy, cat, config, motion_r=r_end * multiple)[..., 0]
    np.testing.assert_allclose(got, want, atol=1e-9)
    prior = rts_smooth(t, fi, tid, det_xy, cat, config)[..., 0]
    assert np.abs(prior - want).max() > 0.02


def test_a_larger_smoother_r_gives_smoother_paths() -> None:
    """offline.rts_r_multiple > 1 trusts each box less: the smoothed path of each track bends
    less (smaller second differences) than with the online filter's r."""
    from tracker.pipeline import run_scene

    rng = np.random.default_rng(11)
    t, scene = _scene(rng, n_objects=4, frames=40, sigma=0.2)
    frames = _frames(t, scene)
    bend = []
    for multiple in (1.0, 30.0):
        config = load_config(
            "kitti_offline",
            overrides={"categories": ["car"], "offline": {"rts_r_multiple": multiple}},
        )
        paths: dict[int, list] = {}
        for o in run_scene(frames, config).outputs:
            for tid, xy in zip(o.boxes.track_id, o.boxes.xyz[:, :2], strict=True):
                paths.setdefault(int(tid), []).append(xy)
        bend.append(sum(np.abs(np.diff(np.array(p), 2, axis=0)).sum() for p in paths.values()))
    assert bend[1] < 0.8 * bend[0]


@pytest.mark.parametrize("value", [0.0, -1.0, "inf"])
def test_a_non_positive_smoother_multiple_is_refused(value) -> None:
    with pytest.raises(InputError, match=r"offline\.rts_r_multiple must be finite and > 0"):
        load_config("kitti_offline", overrides={"offline": {"rts_r_multiple": value}})


def test_the_compiled_estimate_equals_numpy() -> None:
    """tracker.kernels.noise against the numpy reference: the same counts after every frame of
    scenes with clutter, three classes, empty frames and an uneven step, the same variance."""
    from tracker.kernels import load

    kernels = load()
    if kernels is None:
        pytest.skip("numba not available")
    rng = np.random.default_rng(8)
    t, a = _scene(rng, frames=80, sigma=0.2, clutter=3.0)
    _, b = _scene(rng, frames=80, sigma=0.05, category=PED, clutter=1.0)
    # noise larger than the boxes (0.8 m, σ 0.3 m): links beyond the length, at 5 σ̂
    _, c = _scene(
        rng, n_objects=16, frames=80, sigma=0.3, category=CYC, speed=(1.0, 1.5), length=0.8
    )
    scene = [
        (np.vstack([x[0], y[0], z[0]]), np.r_[x[1], y[1], z[1]], np.r_[x[2], y[2], z[2]])
        for x, y, z in zip(a, b, c, strict=True)
    ]
    scene[30] = (np.zeros((0, 2)), np.zeros(0), np.zeros(0, dtype=np.int64))  # an empty frame
    scene[40][0][0] = np.nan  # a box without a centre links to nothing in either
    t = t.copy()
    t[50:] += 0.05  # one uneven step
    numpy_est, compiled_est = PositionNoise(8), PositionNoise(8, kernels)
    for time, (xy, length, cat) in zip(t, scene, strict=True):
        numpy_est.update(time, xy, length, cat)
        compiled_est.update(time, xy, length, cat)
        np.testing.assert_array_equal(compiled_est.counts, numpy_est.counts)
        np.testing.assert_allclose(
            compiled_est.variance(), numpy_est.variance(), rtol=1e-12, equal_nan=True
        )
    assert numpy_est.counts[CAR].sum() > MIN_SAMPLES and numpy_est.counts[PED].sum() > MIN_SAMPLES
    assert np.sqrt(numpy_est.variance()[CYC]) > 0.27  # (within the length alone: 0.23)
