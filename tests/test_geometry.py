"""Angle wrapping and box corners (tracker.geometry), against the formulas they replaced."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.geometry import TWO_PI, corners_3d, corners_bev, wrap_angle


def reference_wrap(angle_rad: np.ndarray) -> np.ndarray:
    """The original three-step wrap: its results must be reproduced bit for bit."""
    a = np.asarray(angle_rad, dtype=np.float64)
    wrapped = np.mod(a + np.pi, TWO_PI) - np.pi
    wrapped = np.where(wrapped <= -np.pi, wrapped + TWO_PI, wrapped)
    return np.where((a > np.pi) | (a <= -np.pi), wrapped, a)


@pytest.mark.parametrize(
    ("angle", "expected"),
    [
        (0.0, 0.0),
        (np.pi, np.pi),
        (-np.pi, np.pi),
        (3 * np.pi, np.pi),
        (-3 * np.pi, np.pi),
        (np.pi + 0.5, -np.pi + 0.5),
        (-np.pi - 0.5, np.pi - 0.5),
        (2 * np.pi, 0.0),
        (1e-300, 1e-300),
    ],
)
def test_wrap_angle_known_values(angle: float, expected: float) -> None:
    assert wrap_angle(angle) == pytest.approx(expected, abs=1e-12)
    assert wrap_angle(np.array([angle]))[0] == pytest.approx(expected, abs=1e-12)


def test_wrap_angle_is_bit_exact_in_range_and_equals_the_reference_outside() -> None:
    rng = np.random.default_rng(3)
    inside = np.nextafter(rng.uniform(-np.pi, np.pi, 10_000), np.inf)
    inside[:3] = [np.pi, np.nextafter(-np.pi, 0.0), 1e-300]
    np.testing.assert_array_equal(wrap_angle(inside), inside)  # passthrough, bit for bit
    for scale in (4.0, 7.0, 50.0, 1e6):
        mixed = rng.uniform(-scale, scale, 10_000)
        got = wrap_angle(mixed)
        np.testing.assert_array_equal(got, reference_wrap(mixed))
        assert np.all((got > -np.pi) & (got <= np.pi))


def test_wrap_angle_shapes_nan_and_no_aliasing() -> None:
    assert wrap_angle(np.zeros(0)).shape == (0,)
    assert wrap_angle(np.zeros((2, 3))).shape == (2, 3)
    assert np.ndim(wrap_angle(0.5)) == 0
    got = wrap_angle(np.array([np.nan, 1.0, 4.0]))
    assert np.isnan(got[0]) and got[1] == 1.0
    source = np.array([0.1, 0.2])
    out = wrap_angle(source)
    out[0] = 9.0  # a new array even when nothing needed wrapping
    assert source[0] == 0.1


def reference_corners_bev(xy: np.ndarray, lw: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """The original stack-based corners (the vectorised rewrite must equal it bit for bit)."""
    half_l, half_w = lw[:, 0:1] / 2.0, lw[:, 1:2] / 2.0
    local = np.stack(
        [
            np.hstack([half_l, half_w]),
            np.hstack([-half_l, half_w]),
            np.hstack([-half_l, -half_w]),
            np.hstack([half_l, -half_w]),
        ],
        axis=1,
    )
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x = local[..., 0] * c - local[..., 1] * s
    y = local[..., 0] * s + local[..., 1] * c
    return np.stack([x, y], axis=-1) + xy[:, None, :]


@pytest.mark.parametrize("n", [0, 1, 7, 300])
def test_corners_equal_the_reference_bit_for_bit(n: int) -> None:
    rng = np.random.default_rng(n)
    xyz = rng.normal(size=(n, 3)) * 50
    lwh = rng.uniform(0.0, 6.0, (n, 3))
    yaw = rng.uniform(-4.0, 4.0, n)
    if n > 5:
        xyz[2, 0], lwh[4, 1] = np.nan, np.inf
    bev = corners_bev(xyz[:, :2], lwh[:, :2], yaw)
    np.testing.assert_array_equal(bev, reference_corners_bev(xyz[:, :2], lwh[:, :2], yaw))
    box = corners_3d(xyz, lwh, yaw)
    assert box.shape == (n, 8, 3)
    np.testing.assert_array_equal(box[:, :4, :2], bev)
    np.testing.assert_array_equal(box[:, 4:, :2], bev)
    np.testing.assert_array_equal(box[:, 0, 2], xyz[:, 2] - lwh[:, 2] / 2.0)
    np.testing.assert_array_equal(box[:, 7, 2], xyz[:, 2] + lwh[:, 2] / 2.0)
