"""The noise floor's oracle filter (tracker/eval/noise_floor.py): a constant-velocity Kalman
filter and RTS smoother batched over independent series."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.eval.noise_floor import DT, cv_filter, jitter_only
from tracker.eval.perturb import NOISE_LEVELS


def test_a_noiseless_constant_velocity_series_is_followed_exactly_after_two_points() -> None:
    t = np.arange(30) * DT
    z = np.stack([3.0 + 1.4 * t, -2.0 - 0.5 * t])
    z[1, 10:14] = np.nan  # a gap: predicted through
    for smooth in (False, True):
        est = cv_filter(z, q=0.01, r=0.0225, smooth=smooth)
        truth = np.stack([3.0 + 1.4 * t, -2.0 - 0.5 * t])
        start = 0 if smooth else 8  # the filter needs a few points to learn the velocity
        assert np.allclose(est[:, start:], truth[:, start:], atol=0.05)


def test_filter_and_smoother_shrink_the_jitter_in_that_order() -> None:
    rng = np.random.default_rng(0)
    n, steps, sigma = 200, 60, 0.15
    t = np.arange(steps) * DT
    truth = rng.normal(0, 5, (n, 1)) + rng.normal(0, 1.5, (n, 1)) * t
    z = truth + rng.normal(0, sigma, truth.shape)
    z[rng.random(z.shape) < 0.1] = np.nan
    z[:, 0] = truth[:, 0] + rng.normal(0, sigma, n)
    rms = {
        name: float(np.sqrt(np.nanmean((est[:, 10:] - truth[:, 10:]) ** 2)))
        for name, est in (
            ("raw", z),
            ("online", cv_filter(z, 0.01, sigma**2, smooth=False)),
            ("offline", cv_filter(z, 0.01, sigma**2, smooth=True)),
        )
    }
    assert rms["raw"] == pytest.approx(sigma, rel=0.1)
    assert rms["online"] < 0.6 * rms["raw"]
    assert rms["offline"] < 0.7 * rms["online"]


def test_series_in_one_batch_do_not_interact_and_start_at_their_first_measurement() -> None:
    rng = np.random.default_rng(1)
    z = rng.normal(0, 1, (3, 20)).cumsum(axis=1)
    z[2, :5] = np.nan  # starts late
    batch = cv_filter(z, 0.1, 0.04, smooth=True)
    for i in range(3):
        alone = cv_filter(z[i : i + 1], 0.1, 0.04, smooth=True)
        assert np.allclose(batch[i], alone[0], equal_nan=True)
    assert np.isnan(batch[2, :5]).all() and np.isfinite(batch[2, 5:]).all()


def test_the_floor_jitters_only_what_the_level_jitters() -> None:
    spec = jitter_only("double")
    level = NOISE_LEVELS["double"]
    assert (spec.centre_sigma_m, spec.yaw_sigma_deg) == (level.centre_sigma_m, level.yaw_sigma_deg)
    assert spec.drop_rate == spec.fp_rate == spec.score_sigma == 0
