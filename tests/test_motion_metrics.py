"""Analytic tests of the motion metrics and velocity estimators (tracker/eval/motion_metrics.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import erf

from tracker.eval.motion_metrics import (
    MotionMetricParams,
    MotionMetrics,
    angle_error_rad,
    combine_motion_metrics,
    composite_key,
    gt_velocity_central,
    motion_metrics,
    static_gt_mask,
    velocity_curve_fit,
    velocity_delay_secs,
    velocity_differencing,
    vse_filter_shape,
)

# --------------------------------------------------------------------------------------------
# Synthetic tracks
# --------------------------------------------------------------------------------------------

#: Speed bumps (centre index, height m/s, width samples) on a 4 m/s base: clear, separated peaks.
BUMPS = ((30, 3.0, 6.0), (70, 2.5, 7.0), (110, 3.5, 8.0))


def bumpy_velocity(n: int = 200) -> np.ndarray:
    """(n, 2) velocity, gently turning, whose speed peaks at samples 30, 70 and 110."""
    i = np.arange(n, dtype=np.float64)
    speed = 4.0 + sum(h * np.exp(-(((i - c) / w) ** 2)) for c, h, w in BUMPS)
    heading = 0.3 + 0.004 * i
    return speed[:, None] * np.stack([np.cos(heading), np.sin(heading)], axis=1)


def delayed(velocity: np.ndarray, k: int) -> np.ndarray:
    """The velocity delayed by exactly k samples (the first sample held before the start)."""
    return velocity[np.maximum(np.arange(len(velocity)) - k, 0)]


def flat_samples(
    gt_velocity: np.ndarray,
    est_velocity: np.ndarray,
    *,
    dt_secs: float = 0.1,
    gt_key: int = 0,
    est_key: int = 0,
    t0_secs: float = 0.0,
) -> dict[str, np.ndarray]:
    """Keyword arguments of motion_metrics for one GT track matched to one output track."""
    n = len(gt_velocity)
    return {
        "gt_track_key": np.full(n, gt_key),
        "times_secs": t0_secs + dt_secs * np.arange(n),
        "gt_velocity": gt_velocity,
        "est_velocity": est_velocity,
        "est_track_key": np.full(n, est_key),
        "gt_xy": np.cumsum(gt_velocity * dt_secs, axis=0),
    }


def concat(*parts: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def take(samples: dict[str, np.ndarray], index: np.ndarray) -> dict[str, np.ndarray]:
    return {k: v[index] for k, v in samples.items()}


def unit(deg: float) -> np.ndarray:
    return np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg))])


def assert_metrics_equal(a: MotionMetrics, b: MotionMetrics) -> None:
    np.testing.assert_equal(a.as_dict(), b.as_dict())  # NaN == NaN here


def assert_metrics_close(a: MotionMetrics, b: MotionMetrics) -> None:
    da, db = a.as_dict(), b.as_dict()
    assert da.keys() == db.keys()
    for name in da:
        np.testing.assert_allclose(da[name], db[name], rtol=1e-12, atol=1e-12, err_msg=name)


# --------------------------------------------------------------------------------------------
# Velocity estimators
# --------------------------------------------------------------------------------------------

NON_UNIFORM_TIMES = np.array([0.0, 0.1, 0.25, 0.3, 0.5, 0.55, 0.7, 0.95, 1.0, 1.2, 1.35, 1.5])


@pytest.mark.parametrize("smooth_window", [3, 5, 7, 9, 21])
def test_gt_central_velocity_exact_for_constant_acceleration(smooth_window: int) -> None:
    t = NON_UNIFORM_TIMES
    p0, v0, a = np.array([3.0, -1.0]), np.array([2.0, 0.5]), np.array([-1.5, 0.8])
    xy = p0 + v0 * t[:, None] + 0.5 * a * t[:, None] ** 2
    velocity = gt_velocity_central(t, xy, smooth_window=smooth_window)
    # Exact in the interior (centred windows) and at the ends (second-order one-sided).
    np.testing.assert_allclose(velocity, v0 + a * t[:, None], rtol=0, atol=1e-9)


def test_gt_central_velocity_window_3_is_np_gradient() -> None:
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.05, 0.2, 30))
    xy = rng.normal(size=(30, 2))
    np.testing.assert_allclose(
        gt_velocity_central(t, xy, smooth_window=3),
        np.gradient(xy, t, axis=0, edge_order=2),
        rtol=1e-9,
        atol=1e-9,
    )


def test_gt_central_velocity_smoothing_reduces_label_noise() -> None:
    rng = np.random.default_rng(1)
    t = 0.1 * np.arange(400)
    v_true = np.array([5.0, -2.0])
    xy = v_true * t[:, None] + rng.normal(scale=0.05, size=(400, 2))
    rms = [
        np.sqrt(np.mean((gt_velocity_central(t, xy, smooth_window=w)[10:-10] - v_true) ** 2))
        for w in (3, 5, 9)
    ]
    assert rms[0] > rms[1] > rms[2]


def test_gt_central_velocity_has_zero_lag() -> None:
    # Analytic path: vx has speed bumps (x integrates them via erf), vy is constant.
    t = 0.1 * np.arange(200)
    centres, heights, widths = (3.0, 7.0, 11.0), (3.0, 2.5, 3.5), (0.6, 0.7, 0.8)
    vx = 4.0 + sum(
        h * np.exp(-(((t - c) / w) ** 2)) for c, h, w in zip(centres, heights, widths, strict=True)
    )
    x = 4.0 * t + sum(
        h * w * math.sqrt(math.pi) / 2 * erf((t - c) / w)
        for c, h, w in zip(centres, heights, widths, strict=True)
    )
    xy = np.stack([x, 1.0 * t], axis=1)
    v_true = np.stack([vx, np.ones_like(t)], axis=1)
    v_gt = gt_velocity_central(t, xy, smooth_window=5)
    # The ±2-sample fit flattens these sharp (±0.6 s) bumps a little, symmetrically.
    np.testing.assert_allclose(v_gt, v_true, atol=0.1)
    for k in (0, 4):
        est = delayed(v_true, k)
        delays = velocity_delay_secs(t, np.linalg.norm(v_gt, axis=1), np.linalg.norm(est, axis=1))
        assert len(delays) == 3
        np.testing.assert_allclose(delays, k * 0.1, atol=1e-12)


@pytest.mark.parametrize(
    ("n", "expected"),
    [(0, np.zeros((0, 2))), (1, np.full((1, 2), np.nan)), (2, np.array([[2.0, -1.0]] * 2))],
)
def test_gt_central_velocity_short_tracks(n: int, expected: np.ndarray) -> None:
    t = 0.5 * np.arange(n)
    xy = np.array([2.0, -1.0]) * t[:, None]
    np.testing.assert_array_equal(gt_velocity_central(t, xy), expected)


@pytest.mark.parametrize("bad_window", [1, 2, 4])
def test_gt_central_velocity_rejects_bad_window(bad_window: int) -> None:
    with pytest.raises(ValueError, match="smooth_window"):
        gt_velocity_central(np.arange(5.0), np.zeros((5, 2)), smooth_window=bad_window)


@pytest.mark.parametrize("fn", [gt_velocity_central, velocity_differencing, velocity_curve_fit])
def test_estimators_reject_unordered_times(fn) -> None:
    with pytest.raises(ValueError, match="strictly increasing"):
        fn(np.array([0.0, 0.2, 0.1]), np.zeros((3, 2)))


@pytest.mark.parametrize("times", [0.1 * np.arange(12), NON_UNIFORM_TIMES])
def test_differencing_exact_for_constant_velocity(times: np.ndarray) -> None:
    v = np.array([7.0, -3.0])
    velocity = velocity_differencing(times, 5.0 + v * times[:, None])
    np.testing.assert_array_equal(velocity[0], [0.0, 0.0])
    np.testing.assert_allclose(velocity[1:], np.broadcast_to(v, (len(times) - 1, 2)), atol=1e-9)


def test_differencing_is_velocity_at_the_previous_midpoint() -> None:
    t = NON_UNIFORM_TIMES
    a = np.array([2.0, -1.0])
    velocity = velocity_differencing(t, 0.5 * a * t[:, None] ** 2)
    midpoints = 0.5 * (t[1:] + t[:-1])
    np.testing.assert_allclose(velocity[1:], a * midpoints[:, None], atol=1e-9)


@pytest.mark.parametrize("window", [2, 3, 5])
@pytest.mark.parametrize("times", [0.1 * np.arange(12), 0.5 * np.arange(12), NON_UNIFORM_TIMES])
def test_curve_fit_is_metres_per_second(window: int, times: np.ndarray) -> None:
    v = np.array([7.0, -3.0])
    velocity = velocity_curve_fit(times, 5.0 + v * times[:, None], window=window)
    np.testing.assert_array_equal(velocity[: window - 1], 0.0)
    np.testing.assert_allclose(velocity[window - 1 :], np.broadcast_to(v, (12 - window + 1, 2)))


def test_curve_fit_is_causal_and_lags_half_its_window() -> None:
    t = 0.1 * np.arange(20)
    a = np.array([2.0, -1.0])
    velocity = velocity_curve_fit(t, 0.5 * a * t[:, None] ** 2, window=5)
    # A line fitted to a parabola over a symmetric window has the slope at the window centre.
    np.testing.assert_allclose(velocity[4:], a * t[2:-2, None], atol=1e-9)


def test_curve_fit_window_2_is_differencing() -> None:
    rng = np.random.default_rng(2)
    t, xy = np.cumsum(rng.uniform(0.05, 0.2, 15)), rng.normal(size=(15, 2))
    np.testing.assert_allclose(velocity_curve_fit(t, xy, window=2), velocity_differencing(t, xy))


def test_curve_fit_short_track_is_zero() -> None:
    np.testing.assert_array_equal(velocity_curve_fit([0.0, 0.1], [[0.0, 0.0], [1.0, 1.0]]), 0.0)


# --------------------------------------------------------------------------------------------
# Angle error, static tracks, filter shapes
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("gt_deg", "est_deg", "error_deg"),
    [
        (359.0, 1.0, 2.0),
        (1.0, 359.0, 2.0),
        (179.0, -179.0, 2.0),
        (10.0, -10.0, 20.0),
        (0.0, 90.0, 90.0),
        (0.0, 180.0, 180.0),
        (45.0, 45.0, 0.0),
    ],
)
def test_angle_error_is_wrapped_and_unsigned(
    gt_deg: float, est_deg: float, error_deg: float
) -> None:
    error = angle_error_rad(unit(gt_deg)[None], 3.0 * unit(est_deg)[None])
    np.testing.assert_allclose(np.degrees(error), [error_deg], atol=1e-9)


def test_angle_error_empty() -> None:
    assert angle_error_rad(np.zeros((0, 2)), np.zeros((0, 2))).shape == (0,)


def test_static_gt_mask_rules() -> None:
    t = 0.1 * np.arange(100)
    ones = np.ones_like(t)
    tracks = {
        # 0.9 m/s for 10 s: 9 m travelled, but slower than 1 m/s -> static by speed.
        10: (np.stack([0.9 * ones, 0 * ones], 1), np.stack([0.9 * t, 0 * t], 1), True),
        # 3 m/s peak, oscillating within ±1 m -> static by displacement.
        11: (np.stack([3 * np.cos(3 * t), 0 * t], 1), np.stack([np.sin(3 * t), 0 * t], 1), True),
        # 1.2 m/s for 10 s -> moving.
        12: (np.stack([1.2 * ones, 0 * ones], 1), np.stack([1.2 * t, 0 * t], 1), False),
    }
    keys = np.concatenate([np.full(len(t), k) for k in tracks])
    velocity = np.concatenate([v for v, _, _ in tracks.values()])
    xy = np.concatenate([p for _, p, _ in tracks.values()])
    expected = np.concatenate([np.full(len(t), s) for _, _, s in tracks.values()])
    perm = np.random.default_rng(3).permutation(len(keys))
    mask = static_gt_mask(keys[perm], velocity[perm], xy[perm])
    np.testing.assert_array_equal(mask, expected[perm])


@pytest.mark.parametrize(
    ("n", "shape"),
    [(0, None), (7, None), (8, (5, 3)), (12, (7, 3)), (29, (15, 3)), (30, (15, 3)), (500, (15, 3))],
)
def test_vse_filter_shape(n: int, shape: tuple[int, int] | None) -> None:
    assert vse_filter_shape(n) == shape


# --------------------------------------------------------------------------------------------
# Direction and norm metrics
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("offset_mps", [0.0, 0.5, 2.0, -1.5])
def test_constant_magnitude_offset_gives_vne_equal_to_offset(offset_mps: float) -> None:
    v = bumpy_velocity()
    speed = np.linalg.norm(v, axis=1, keepdims=True)
    m = motion_metrics(**flat_samples(v, v * (speed + offset_mps) / speed))
    assert m.vne_mps == pytest.approx(abs(offset_mps), abs=1e-12)
    assert m.vae_deg == pytest.approx(0.0, abs=1e-6)
    assert m.vir_ratio == 0.0
    assert math.isnan(m.vaie_deg)
    assert m.n_samples == m.n_direction_samples == 200
    assert m.n_inverted_samples == 0


def test_reversed_velocity_is_fully_inverted() -> None:
    v = bumpy_velocity()
    m = motion_metrics(**flat_samples(v, -v))
    assert m.vir_ratio == 1.0
    assert m.vaie_deg == pytest.approx(180.0, abs=1e-9)
    assert math.isnan(m.vae_deg)
    assert m.vne_mps == pytest.approx(0.0, abs=1e-12)
    assert m.n_inverted_samples == 200


def test_angle_metrics_split_at_90_degrees() -> None:
    v = bumpy_velocity(40)
    speed = np.linalg.norm(v, axis=1)
    heading = np.arctan2(v[:, 1], v[:, 0])
    # Half the samples rotated by +30°, half by -120°.
    rotation = np.radians(np.where(np.arange(40) % 2 == 0, 30.0, -120.0))
    est = speed[:, None] * np.stack([np.cos(heading + rotation), np.sin(heading + rotation)], 1)
    m = motion_metrics(**flat_samples(v, est))
    assert m.vae_deg == pytest.approx(30.0)
    assert m.vaie_deg == pytest.approx(120.0)
    assert m.vir_ratio == 0.5


def test_gt_at_359_and_estimate_at_1_degree() -> None:
    gt = np.tile(5.0 * unit(359.0), (30, 1))
    m = motion_metrics(**flat_samples(gt, np.tile(5.0 * unit(1.0), (30, 1))))
    assert m.vae_deg == pytest.approx(2.0)
    assert m.vir_ratio == 0.0


def test_static_tracks_are_excluded_from_direction_and_norm_metrics() -> None:
    rng = np.random.default_rng(4)
    v = bumpy_velocity(100)
    moving = flat_samples(v, v + rng.normal(scale=0.3, size=v.shape), gt_key=1, est_key=1)
    parked_v = rng.normal(scale=0.2, size=(60, 2))  # label noise of a parked car
    parked = flat_samples(parked_v, -10.0 * parked_v + 3.0, gt_key=2, est_key=2)
    parked["gt_xy"] = 20.0 + rng.normal(scale=0.05, size=(60, 2))
    both = motion_metrics(**concat(moving, parked))
    alone = motion_metrics(**moving)
    for name in ("vae_deg", "vne_mps", "vaie_deg", "vir_ratio", "n_direction_samples"):
        np.testing.assert_equal(getattr(both, name), getattr(alone, name), err_msg=name)
    assert both.n_direction_samples == 100
    assert both.n_samples == 160
    # VSE is over every output track, static GT or not.
    assert both.n_vse_sequences == 2


# --------------------------------------------------------------------------------------------
# VSE
# --------------------------------------------------------------------------------------------


def test_constant_velocity_has_zero_vse() -> None:
    v = np.tile([3.0, 4.0], (50, 1))
    assert motion_metrics(**flat_samples(v, v)).vse_mps == pytest.approx(0.0, abs=1e-12)


def test_noisy_velocity_has_larger_vse_than_its_smoothed_version() -> None:
    rng = np.random.default_rng(5)
    v = bumpy_velocity()
    noisy = v + rng.normal(scale=0.5, size=v.shape)
    kernel = np.ones(9) / 9
    smoothed = np.stack([np.convolve(noisy[:, d], kernel, mode="same") for d in range(2)], 1)
    vse_noisy = motion_metrics(**flat_samples(v, noisy)).vse_mps
    vse_smoothed = motion_metrics(**flat_samples(v, smoothed)).vse_mps
    assert vse_noisy > 2.0 * vse_smoothed > 0.0


def test_short_sequences_are_skipped_and_counted() -> None:
    rng = np.random.default_rng(6)
    v = 5.0 + rng.normal(size=(7, 2))
    m = motion_metrics(**flat_samples(v, v))
    assert math.isnan(m.vse_mps)
    assert (m.n_vse_sequences, m.n_vse_skipped_sequences, m.n_vse_samples) == (0, 1, 0)
    m8 = motion_metrics(**flat_samples(np.vstack([v, v[:1]]), np.vstack([v, v[:1]])))
    assert (m8.n_vse_sequences, m8.n_vse_skipped_sequences, m8.n_vse_samples) == (1, 0, 8)
    assert m8.vse_mps > 0.0


def test_vse_follows_output_tracks_not_gt_tracks() -> None:
    rng = np.random.default_rng(7)
    v = bumpy_velocity(60)
    est = v + rng.normal(scale=0.4, size=v.shape)
    # One GT track, the output id switches at sample 30: two VSE sequences of 30 samples.
    samples = flat_samples(v, est)
    samples["est_track_key"] = np.where(np.arange(60) < 30, 5, 6)
    m = motion_metrics(**samples)
    first = motion_metrics(**take(samples, np.arange(30)))
    second = motion_metrics(**take(samples, np.arange(30, 60)))
    assert m.n_vse_sequences == 2
    assert m.vse_mps == pytest.approx((first.vse_mps + second.vse_mps) / 2)


# --------------------------------------------------------------------------------------------
# VDE
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dt_secs", [0.1, 0.5])
@pytest.mark.parametrize("k", [0, 1, 3, 7, 15, 20])
def test_delayed_copy_has_vde_equal_to_the_delay(k: int, dt_secs: float) -> None:
    v = bumpy_velocity()
    m = motion_metrics(**flat_samples(v, delayed(v, k), dt_secs=dt_secs, t0_secs=12.3))
    assert m.n_vde_candidates == 3  # τ = 0 is a delay too: never dropped, never NaN
    assert m.vde_secs == pytest.approx(k * dt_secs, abs=1e-9)


def test_vde_time_step_is_the_tracks_median_step() -> None:
    v = bumpy_velocity()
    samples = flat_samples(v, delayed(v, 4), dt_secs=0.1)
    samples["times_secs"][150:] += 0.05  # one jittered step does not move the median
    assert motion_metrics(**samples).vde_secs == pytest.approx(0.4)


def test_vde_skips_short_and_flat_tracks() -> None:
    v = bumpy_velocity()
    t = 0.1 * np.arange(200)
    speed = np.linalg.norm(v, axis=1)
    assert velocity_delay_secs(t[:19], speed[:19], speed[:19]).shape == (0,)
    flat = np.full(200, 5.0) + 0.2 * np.sin(t)  # speed range 0.4 < 0.5 m/s
    assert velocity_delay_secs(t, flat, flat).shape == (0,)


def test_vde_skips_peaks_without_room_for_every_shift() -> None:
    v = bumpy_velocity()
    speed = np.linalg.norm(v, axis=1)
    t = 0.1 * np.arange(200)
    # Cut after sample 125: the peak at 110 cannot be followed by 20 shifts, so only 2 candidates.
    delays = velocity_delay_secs(t[:126], speed[:126], delayed(speed, 3)[:126])
    np.testing.assert_allclose(delays, [0.3, 0.3])


def test_vde_ignores_noise_wiggles() -> None:
    rng = np.random.default_rng(15)
    t = 0.1 * np.arange(200)
    gt = np.linalg.norm(bumpy_velocity(), axis=1) + rng.normal(scale=0.05, size=200)
    est = delayed(gt, 5) + rng.normal(scale=0.05, size=200)
    # Only the three real bumps are candidates, not the first wiggles of the cruising part.
    np.testing.assert_allclose(velocity_delay_secs(t, gt, est), [0.5, 0.5, 0.5])


def test_vde_max_candidates() -> None:
    v = bumpy_velocity()
    speed = np.linalg.norm(v, axis=1)
    params = MotionMetricParams(vde_max_candidates=1)
    delays = velocity_delay_secs(0.1 * np.arange(200), speed, speed, params=params)
    np.testing.assert_array_equal(delays, [0.0])


# --------------------------------------------------------------------------------------------
# Grouping, ordering, aggregation
# --------------------------------------------------------------------------------------------


def three_track_scene(seed: int, *, t0_secs: float = 0.0) -> dict[str, np.ndarray]:
    """Moving track with an id switch, a delayed noisy track and a parked car; raw ids 1, 2, 3."""
    rng = np.random.default_rng(seed)
    v = bumpy_velocity()
    a = flat_samples(v, v + rng.normal(scale=0.3, size=v.shape), gt_key=1, est_key=1)
    a["est_track_key"][120:] = 4
    w = bumpy_velocity(150)[:, ::-1]
    b = flat_samples(w, delayed(w, 5) + rng.normal(scale=0.1, size=w.shape), gt_key=2, est_key=2)
    c = flat_samples(
        rng.normal(scale=0.1, size=(40, 2)), rng.normal(size=(40, 2)), gt_key=3, est_key=3
    )
    scene = concat(a, b, c)
    scene["times_secs"] = scene["times_secs"] + t0_secs
    return scene


def test_shuffled_samples_give_identical_metrics() -> None:
    samples = three_track_scene(8)
    reference = motion_metrics(**samples)
    for seed in range(3):
        perm = np.random.default_rng(seed).permutation(len(samples["times_secs"]))
        assert_metrics_equal(motion_metrics(**take(samples, perm)), reference)
    assert reference.n_vde_candidates == 6
    assert reference.n_vse_sequences == 4


def test_colliding_raw_ids_with_distinct_keys_pool_like_separate_scenes() -> None:
    scene_a, scene_b = three_track_scene(9), three_track_scene(10)
    separate = [motion_metrics(**scene_a), motion_metrics(**scene_b)]
    both = concat(scene_a, scene_b)
    scene = np.repeat(["scene-a", "scene-b"], len(scene_a["times_secs"]))
    both["gt_track_key"] = composite_key(scene, both["gt_track_key"])
    both["est_track_key"] = composite_key(scene, both["est_track_key"])
    assert_metrics_close(motion_metrics(**both), combine_motion_metrics(separate))


def test_colliding_raw_ids_are_rejected() -> None:
    # The reference silently merged same-id tracks of different scenes.
    with pytest.raises(ValueError, match="two samples at time"):
        motion_metrics(**concat(three_track_scene(9), three_track_scene(10)))


def test_combine_ignores_empty_parts() -> None:
    part = motion_metrics(**three_track_scene(11))
    empty = motion_metrics(**take(three_track_scene(11), np.zeros(0, dtype=np.int64)))
    assert_metrics_equal(combine_motion_metrics([part, empty]), part)
    assert_metrics_equal(combine_motion_metrics([empty]), empty)


def test_empty_input_gives_nan_metrics_and_zero_counts() -> None:
    m = motion_metrics(**take(three_track_scene(12), np.zeros(0, dtype=np.int64)))
    values = m.as_dict()
    for name in ("vae_deg", "vne_mps", "vaie_deg", "vir_ratio", "vse_mps", "vde_secs"):
        assert math.isnan(values[name]), name
    assert all(v == 0 for k, v in values.items() if k.startswith("n_"))


def test_non_finite_velocities_are_dropped_and_counted() -> None:
    samples = three_track_scene(13)
    with_nan = concat(samples, take(samples, np.array([5])))
    with_nan["times_secs"][-1] += 1000.0
    with_nan["est_velocity"][-1] = np.nan
    dropped, clean = motion_metrics(**with_nan).as_dict(), motion_metrics(**samples).as_dict()
    assert dropped.pop("n_dropped_samples") == 1
    assert clean.pop("n_dropped_samples") == 0
    assert dropped["n_gt_velocity_unknown"] == 0
    np.testing.assert_equal(dropped, clean)


def test_an_unknown_gt_velocity_is_left_out_and_counted_apart() -> None:
    """A NaN GT velocity (unknown: nuScenes' single-annotation instances) leaves its row out of
    every metric, counted in n_gt_velocity_unknown, not in n_dropped_samples (an estimate's
    NaN); read as 0 it was scored as a measured standstill."""
    samples = three_track_scene(13)
    rows = np.array([5, 6, 7])
    with_nan = concat(samples, take(samples, rows))
    with_nan["times_secs"][-3:] += 1000.0
    with_nan["gt_velocity"][-3:] = np.nan
    with_nan["est_velocity"][-1] = np.nan  # (both unknown: the GT's count)
    unknown, clean = motion_metrics(**with_nan).as_dict(), motion_metrics(**samples).as_dict()
    assert unknown.pop("n_gt_velocity_unknown") == 3 and unknown["n_dropped_samples"] == 0
    assert clean.pop("n_gt_velocity_unknown") == 0
    np.testing.assert_equal(unknown, clean)
    as_zero = {**with_nan, "gt_velocity": np.nan_to_num(with_nan["gt_velocity"])}
    as_zero["est_velocity"] = np.nan_to_num(as_zero["est_velocity"])
    assert motion_metrics(**as_zero).n_samples == clean["n_samples"] + 3  # (what 0 did)


def test_shape_and_key_validation() -> None:
    samples = three_track_scene(14)
    with pytest.raises(ValueError, match="expected"):
        motion_metrics(**{**samples, "gt_xy": samples["gt_xy"][:-1]})
    with pytest.raises(ValueError, match="integers"):
        motion_metrics(**{**samples, "gt_track_key": samples["gt_track_key"].astype(float)})


def test_two_samples_of_one_output_track_at_one_time_are_rejected() -> None:
    samples = three_track_scene(16)
    samples["est_track_key"][:] = 1  # output track 1 now holds GT tracks 1, 2, 3 at equal times
    with pytest.raises(ValueError, match="output track 1 has two samples"):
        motion_metrics(**samples)


def test_params_validation() -> None:
    with pytest.raises(ValueError, match="vse_window_samples"):
        MotionMetricParams(vse_window_samples=14)
    with pytest.raises(ValueError, match="vde_max_shift_samples"):
        MotionMetricParams(vde_max_shift_samples=-1)


def test_composite_key_separates_scenes() -> None:
    keys = composite_key(["b", "a", "b", "a"], [1, 1, 1, 2])
    np.testing.assert_array_equal(keys, [2, 0, 2, 1])
    assert keys.dtype == np.int64
