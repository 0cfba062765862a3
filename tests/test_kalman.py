"""Batched Kalman filters (tracker.kalman): reference parity, hand-computed steps, oracles."""

from __future__ import annotations

import numpy as np
import pytest

from tracker import kalman as kf
from tracker.geometry import wrap_angle

# mctrack_reference.md §3: KITTI pose CV and nuScenes car pose CV, size and yaw noise.
KITTI_POSE = kf.DiagonalNoise(p0_diag=[1, 1, 500, 500], q_diag=[0.5, 0.5, 5, 5], r_diag=[0.1, 0.1])
NUSC_POSE = kf.DiagonalNoise(
    p0_diag=[1, 1, 10, 10], q_diag=[0.5, 0.5, 1.5, 1.5], r_diag=[0.7, 0.7, 0.5, 0.5]
)
SIZE = kf.DiagonalNoise(p0_diag=[1, 1, 10, 10], q_diag=[0.5, 0.5, 1.5, 1.5], r_diag=[2, 2])
HEADING = kf.DiagonalNoise(p0_diag=[0.1, 0.1], q_diag=[0.1, 0.1], r_diag=[0.2, 5.0])


def random_spd(rng: np.random.Generator, shape: tuple[int, ...], n: int) -> np.ndarray:
    """(*shape, n, n) well-conditioned symmetric positive definite matrices."""
    a = rng.normal(size=(*shape, n, n))
    return a @ a.mT + 0.5 * np.eye(n)


def assert_symmetric_psd(P: np.ndarray) -> None:
    np.testing.assert_array_equal(P, P.mT)
    assert np.linalg.eigvalsh(P).min() >= -1e-12


def reference_trace(
    *, noise: kf.DiagonalNoise, dt: float, with_velocity: bool, n_frames: int, miss: int
) -> tuple[np.ndarray, np.ndarray]:
    """Run the §8 pose trace with our filters: ([x, vx] per frame, P_xx per frame).

    Measurements x_f = 10·dt·f ∓ 0.05 (f0 −0.05, f1 +0.05, …), y = 2, detector v = (10, 0)
    when measured; frame ``miss`` gets the reference's pseudo-update.
    """
    z = [10.0 * dt * f + (0.05 if f % 2 else -0.05) for f in range(n_frames)]
    velocity = np.array([[10.0, 0.0]]) if with_velocity else np.zeros((1, 2))
    x, P = kf.pose_init([[z[0], 2.0]], p0_diag=noise.p0_diag, velocity_xy=velocity)
    H = kf.position_measurement_matrix(n_state=4, with_velocity=with_velocity)
    states, p_xx = [x[0, [0, 2]]], [P[0, 0, 0]]
    for f in range(1, n_frames):
        x, P = kf.pose_predict(
            x, P, dt_secs=np.array([dt]), q_diag=noise.q_diag, dt_nominal_secs=dt
        )
        if f == miss:
            x, P = kf.pseudo_update(x, P, H, kf.diagonal_covariance(noise.r_diag))
        else:
            x, P = kf.pose_update(
                x,
                P,
                xy=[[z[f], 2.0]],
                r_diag=noise.r_diag,
                velocity_xy=velocity if with_velocity else None,
            )
        states.append(x[0, [0, 2]])
        p_xx.append(P[0, 0, 0])
    return np.array(states), np.array(p_xx)


# ---------------------------------------------------------------------------------------------
# Reference parity (mctrack_reference.md §8)
# ---------------------------------------------------------------------------------------------


def test_kitti_golden_pose_trace() -> None:
    states, p_xx = reference_trace(
        noise=KITTI_POSE, dt=0.1, with_velocity=False, n_frames=6, miss=3
    )
    expected = [
        [-0.05, 0.0],
        [1.033333, 8.333333],
        [1.946055, 8.861191],
        [2.832174, 8.861191],  # miss: x = F x, v unchanged
        [3.928391, 9.593768],
        [5.033690, 10.038059],
    ]
    np.testing.assert_allclose(states, expected, atol=1e-6)
    np.testing.assert_allclose(p_xx, [1, 0.0985, 0.0953, 0.0922, 0.0907, 0.0899], atol=5e-5)


def test_nuscenes_golden_pose_trace() -> None:
    states, _ = reference_trace(noise=NUSC_POSE, dt=0.5, with_velocity=True, n_frames=6, miss=3)
    expected = [
        [-0.05, 10.0],
        [5.023248, 10.007962],
        [9.978860, 9.999214],
        [14.978467, 9.999214],
        [19.961485, 9.999097],
        [25.013655, 10.002149],
    ]
    np.testing.assert_allclose(states, expected, atol=1e-6)


def reference_kf_update(
    x: np.ndarray,
    P: np.ndarray,
    z: np.ndarray,
    F: np.ndarray,
    Q: np.ndarray,
    H: np.ndarray,
    R: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The official ``KF_Base.update`` (one track): predict inside, explicit inverse, P=(I−KH)P."""
    x = F @ x
    P = F @ P @ F.T + Q
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    x = x + K @ (z - H @ x)
    return x, (np.eye(len(x)) - K @ H) @ P


def test_joseph_update_matches_reference_standard_form_over_a_long_run() -> None:
    rng = np.random.default_rng(3)
    dt, noise = 0.5, NUSC_POSE
    F, Q = kf.cv_transition([dt])[0], np.diag(noise.q_diag)
    H, R = np.eye(4), np.diag(noise.r_diag)
    x_ref, P_ref = np.array([0.0, 0.0, 5.0, 1.0]), np.diag(noise.p0_diag)
    x, P = x_ref[None].copy(), P_ref[None].copy()
    for _ in range(50):
        z = rng.normal(size=4) * [3, 3, 1, 1] + x_ref
        x_ref, P_ref = reference_kf_update(x_ref, P_ref, z, F, Q, H, R)
        x, P = kf.pose_predict(x, P, dt_secs=[dt], q_diag=noise.q_diag, dt_nominal_secs=dt)
        x, P = kf.pose_update(x, P, xy=z[None, :2], velocity_xy=z[None, 2:], r_diag=noise.r_diag)
    np.testing.assert_allclose(x[0], x_ref, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(P[0], P_ref, rtol=1e-9, atol=1e-12)


def test_pseudo_update_keeps_the_state_and_shrinks_the_covariance() -> None:
    x, P = kf.pose_init([[1.0, 2.0]], p0_diag=KITTI_POSE.p0_diag, velocity_xy=[[3.0, 4.0]])
    H = kf.position_measurement_matrix(n_state=4, with_velocity=False)
    x2, P2 = kf.pseudo_update(x, P, H, kf.diagonal_covariance(KITTI_POSE.r_diag))
    np.testing.assert_array_equal(x2, x)
    assert P2[0, 0, 0] < P[0, 0, 0]
    assert P2[0, 2, 2] == P[0, 2, 2]  # the velocity is not observed and P has no x–v cross term


# ---------------------------------------------------------------------------------------------
# Hand-computed single steps
# ---------------------------------------------------------------------------------------------


def test_cv_predict_and_update_by_hand() -> None:
    x = np.array([[1.0, 2.0, 3.0, 4.0]])
    P = np.diag([1.0, 1.0, 10.0, 10.0])[None]
    x, P = kf.pose_predict(x, P, dt_secs=[0.5], q_diag=[0.5, 0.5, 1.5, 1.5], dt_nominal_secs=0.5)
    # x += 0.5·v; Pxx = 1 + 0.5²·10 + 0.5 = 4; Pxv = 0.5·10 = 5; Pvv = 10 + 1.5 = 11.5
    np.testing.assert_allclose(x[0], [2.5, 4.0, 3.0, 4.0])
    np.testing.assert_allclose(P[0, [0, 0, 2], [0, 2, 2]], [4.0, 5.0, 11.5])
    np.testing.assert_allclose(P[0, [1, 1, 3], [1, 3, 3]], [4.0, 5.0, 11.5])
    assert P[0, 0, 1] == P[0, 0, 3] == 0.0
    x, P = kf.pose_update(x, P, xy=[[3.5, 4.0]], r_diag=[1.0, 1.0])
    # S = 4 + 1 = 5, K = [4, 5] / 5 = [0.8, 1.0], y = 1:
    # x = 2.5 + 0.8 = 3.3, vx = 3 + 1 = 4; Pxx = 4 − 16/5, Pxv = 5 − 4·5/5, Pvv = 11.5 − 25/5
    np.testing.assert_allclose(x[0], [3.3, 4.0, 4.0, 4.0])
    np.testing.assert_allclose(P[0, [0, 0, 2], [0, 2, 2]], [0.8, 1.0, 6.5])


def test_ca_predict_and_update_by_hand() -> None:
    x = np.array([[0.0, 0.0, 1.0, 0.0, 2.0, 0.0]])  # [x, y, vx, vy, ax, ay]
    P = np.eye(6)[None]
    x, P = kf.pose_predict(x, P, dt_secs=[1.0], q_diag=np.zeros(6), dt_nominal_secs=0.1)
    # F per axis = [[1, 1, ½], [0, 1, 1], [0, 0, 1]], P = I → F Fᵀ
    np.testing.assert_allclose(x[0], [2.0, 0.0, 3.0, 0.0, 2.0, 0.0])
    np.testing.assert_allclose(
        P[0][np.ix_([0, 2, 4], [0, 2, 4])], [[2.25, 1.5, 0.5], [1.5, 2.0, 1.0], [0.5, 1.0, 1.0]]
    )
    x, P = kf.pose_update(x, P, xy=[[3.0, 0.0]], r_diag=[0.25, 0.25])
    # S = 2.5, y = 1, K = [2.25, 1.5, 0.5] / 2.5 = [0.9, 0.6, 0.2]
    np.testing.assert_allclose(x[0], [2.9, 0.0, 3.6, 0.0, 2.2, 0.0])
    np.testing.assert_allclose(
        [P[0, 0, 0], P[0, 0, 2], P[0, 4, 4]], [2.25 - 2.25**2 / 2.5, 1.5 - 2.25 * 1.5 / 2.5, 0.9]
    )


def test_heading_predict_and_update_by_hand() -> None:
    x, P = kf.heading_init([0.5], p0_diag=[0.1, 0.1])
    x[0, 1] = 0.2
    x, P = kf.heading_predict(x, P, dt_secs=[0.5], q_diag=[0.1, 0.1], dt_nominal_secs=0.5)
    # θ = 0.5 + 0.5·0.2; Pθθ = 0.1 + 0.25·0.1 + 0.1 = 0.225; Pθω = 0.05; Pωω = 0.2
    np.testing.assert_allclose(x[0], [0.6, 0.2])
    np.testing.assert_allclose(P[0], [[0.225, 0.05], [0.05, 0.2]])
    # both θ_det = 0.7 (R 0.2) and θ_vel = 0.7 (R 5.0) observe θ: one θ measurement with
    # R = 1 / (1/0.2 + 1/5) = 1/5.2, so K = [0.225, 0.05] / (0.225 + 1/5.2), y = 0.1
    x, P = kf.heading_update(x, P, yaw_det_rad=[0.7], yaw_vel_rad=[0.7], r_diag=[0.2, 5.0])
    s = 0.225 + 1 / 5.2
    np.testing.assert_allclose(x[0], [0.6 + 0.225 / s * 0.1, 0.2 + 0.05 / s * 0.1])
    np.testing.assert_allclose(P[0, 0, 0], 0.225 - 0.225**2 / s)


def test_process_noise_scales_with_elapsed_time() -> None:
    Q = kf.process_noise([0.5, 2.0], [0.1, 0.2, 0.05], dt_nominal_secs=0.1)
    np.testing.assert_allclose(np.diagonal(Q, axis1=1, axis2=2), [[0.5, 2], [1, 4], [0.25, 1]])
    per_row = kf.process_noise([[1.0, 1.0], [2.0, 3.0]], [0.1, 0.1], dt_nominal_secs=0.1)
    np.testing.assert_allclose(per_row, [np.diag([1.0, 1.0]), np.diag([2.0, 3.0])])


@pytest.mark.parametrize(
    ("build", "n", "entries"),
    [
        (kf.cv_transition, 4, {(0, 2): 0.3, (1, 3): 0.3}),
        (kf.ca_transition, 6, {(0, 2): 0.3, (1, 3): 0.3, (2, 4): 0.3, (3, 5): 0.3,
                               (0, 4): 0.045, (1, 5): 0.045}),
        (kf.heading_transition, 2, {(0, 1): 0.3}),
    ],
)  # fmt: skip
def test_transitions_per_row(build, n: int, entries: dict[tuple[int, int], float]) -> None:
    F = build(np.array([0.3, 0.0]))
    expected = np.eye(n)
    for (i, j), value in entries.items():
        expected[i, j] = value
    np.testing.assert_allclose(F[0], expected)
    np.testing.assert_array_equal(F[1], np.eye(n))  # dt = 0: identity


# ---------------------------------------------------------------------------------------------
# Generic update: batching, masks, wrap
# ---------------------------------------------------------------------------------------------


def test_batched_step_equals_per_row_step() -> None:
    rng = np.random.default_rng(0)
    b, n, m = 9, 5, 3
    x, P = rng.normal(size=(b, n)), random_spd(rng, (b,), n)
    F, Q = rng.normal(size=(b, n, n)), random_spd(rng, (b,), n)
    z, H, R = rng.normal(size=(b, m)), rng.normal(size=(b, m, n)), random_spd(rng, (b,), m)
    xp, Pp = kf.predict(x, P, F, Q)
    xu, Pu = kf.update(xp, Pp, z, H, R, innovation_wrap=[1])
    for i in range(b):
        xi, Pi = kf.predict(x[i : i + 1], P[i : i + 1], F[i], Q[i])
        xi, Pi = kf.update(xi, Pi, z[i : i + 1], H[i], R[i], innovation_wrap=[1])
        np.testing.assert_allclose(xu[i], xi[0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Pu[i], Pi[0], rtol=1e-12, atol=1e-12)
    assert_symmetric_psd(Pu)


def test_masked_components_equal_an_update_without_them() -> None:
    rng = np.random.default_rng(1)
    b, n, m = 12, 4, 3
    x, P = rng.normal(size=(b, n)), random_spd(rng, (b,), n)
    H, R = rng.normal(size=(m, n)), random_spd(rng, (), m)
    z = rng.normal(size=(b, m))
    mask = rng.random((b, m)) > 0.4
    mask[0] = False  # a fully masked row is left unchanged
    z[~mask] = np.nan  # masked measurements may be missing
    xu, Pu = kf.update(x, P, z, H, R, mask=mask)
    np.testing.assert_array_equal(xu[0], x[0])
    np.testing.assert_allclose(Pu[0], P[0], rtol=1e-15)
    for i in range(1, b):
        keep = np.flatnonzero(mask[i])
        xi, Pi = kf.update(
            x[i : i + 1], P[i : i + 1], z[i : i + 1, keep], H[keep], R[np.ix_(keep, keep)]
        )
        np.testing.assert_allclose(xu[i], xi[0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Pu[i], Pi[0], rtol=1e-12, atol=1e-12)


def test_empty_batch() -> None:
    x, P = np.zeros((0, 4)), np.zeros((0, 4, 4))
    xp, Pp = kf.pose_predict(
        x, P, dt_secs=np.zeros(0), q_diag=NUSC_POSE.q_diag, dt_nominal_secs=0.5
    )
    xu, Pu = kf.pose_update(
        xp, Pp, xy=np.zeros((0, 2)), velocity_xy=np.zeros((0, 2)), r_diag=NUSC_POSE.r_diag
    )
    assert xu.shape == (0, 4) and Pu.shape == (0, 4, 4)
    noise = kf.motion_noise(pose=NUSC_POSE, size=SIZE, heading=HEADING, model=kf.MotionModel.CV)
    mx, mP = kf.motion_init(
        xy=np.zeros((0, 2)), lw=np.zeros((0, 2)), yaw_rad=np.zeros(0), p0_diag=noise.p0_diag
    )
    mx, mP = kf.motion_predict(
        mx, mP, dt_secs=np.zeros(0), q_diag=noise.q_diag, dt_nominal_secs=0.5
    )
    mx, mP = kf.motion_update(
        mx,
        mP,
        xy=np.zeros((0, 2)),
        lw=np.zeros((0, 2)),
        yaw_det_rad=np.zeros(0),
        r_diag=noise.r_diag,
    )
    assert mx.shape == (0, 5, 2) and mP.shape == (0, 5, 2, 2)


def test_velocity_rows_without_velocity_get_the_position_only_update() -> None:
    rng = np.random.default_rng(2)
    x, P = kf.pose_init(
        rng.normal(size=(6, 2)), p0_diag=NUSC_POSE.p0_diag, velocity_xy=rng.normal(size=(6, 2))
    )
    xy, v = rng.normal(size=(6, 2)), rng.normal(size=(6, 2))
    v[::2] = np.nan
    xu, Pu = kf.pose_update(x, P, xy=xy, velocity_xy=v, r_diag=NUSC_POSE.r_diag)
    xp, Pp = kf.pose_update(x[::2], P[::2], xy=xy[::2], r_diag=NUSC_POSE.r_diag[:2])
    xv, Pv = kf.pose_update(
        x[1::2], P[1::2], xy=xy[1::2], velocity_xy=v[1::2], r_diag=NUSC_POSE.r_diag
    )
    np.testing.assert_allclose(xu[::2], xp, rtol=1e-13)
    np.testing.assert_allclose(Pu[::2], Pp, rtol=1e-13)
    np.testing.assert_allclose(xu[1::2], xv, rtol=1e-13)
    np.testing.assert_allclose(Pu[1::2], Pv, rtol=1e-13)


# ---------------------------------------------------------------------------------------------
# Heading: wrap, θ_vel mask, 180° alignment
# ---------------------------------------------------------------------------------------------


def test_yaw_wraps_across_pi() -> None:
    x, P = kf.heading_init([3.1], p0_diag=[0.1, 0.1])
    x_new, _ = kf.heading_update(x, P, yaw_det_rad=[-3.1], r_diag=[0.01, 5.0])
    innovation = 2 * np.pi - 6.2  # wrap(−3.1 − 3.1) = +0.0832, not −6.2
    gain = 0.1 / (0.1 + 0.01)
    np.testing.assert_allclose(wrap_angle(x_new[0, 0] - 3.1), gain * innovation, rtol=1e-12)
    assert x_new[0, 0] < -3.0  # crossed +pi and was wrapped into (−pi, pi]
    assert x_new[0, 1] == pytest.approx(0.0)  # P has no θ–ω cross term yet, ω is unchanged


def test_heading_predict_wraps_the_state() -> None:
    x = np.array([[3.0, 1.0], [-3.0, -1.0]])
    x_new, _ = kf.heading_predict(
        x, np.tile(np.eye(2), (2, 1, 1)), dt_secs=[0.5, 0.5], q_diag=[0.1, 0.1], dt_nominal_secs=0.5
    )
    np.testing.assert_allclose(x_new[:, 0], [3.5 - 2 * np.pi, -3.5 + 2 * np.pi])


def test_masked_velocity_heading_rows_equal_a_filter_without_it() -> None:
    rng = np.random.default_rng(4)
    n = 10
    x, P = kf.heading_init(rng.uniform(-np.pi, np.pi, n), p0_diag=HEADING.p0_diag)
    x[:, 1] = rng.normal(size=n)
    yaw_det = rng.uniform(-np.pi, np.pi, n)
    yaw_vel, moving = kf.velocity_heading(rng.normal(size=(n, 2)) * 2, min_speed_mps=1.5)
    assert moving.any() and not moving.all()
    xu, Pu = kf.heading_update(
        x, P, yaw_det_rad=yaw_det, yaw_vel_rad=yaw_vel, yaw_vel_valid=moving, r_diag=HEADING.r_diag
    )
    # oracle: θ_det only, H = [[1, 0]]
    xd, Pd = kf.update(
        x,
        P,
        yaw_det[:, None],
        np.array([[1.0, 0.0]]),
        np.array([[HEADING.r_diag[0]]]),
        innovation_wrap=[0],
    )
    xd[:, 0] = wrap_angle(xd[:, 0])
    np.testing.assert_allclose(xu[~moving], xd[~moving], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(Pu[~moving], Pd[~moving], rtol=1e-12, atol=1e-15)
    assert not np.allclose(xu[moving], xd[moving])


def test_heading_h_makes_both_measurements_observe_theta() -> None:
    """A car driving straight at heading 1.0: θ stays at 1.0 and ω at 0 (not the 2025 drift)."""
    x, P = kf.heading_init([1.0], p0_diag=HEADING.p0_diag)
    for _ in range(9):
        x, P = kf.heading_predict(x, P, dt_secs=[0.5], q_diag=HEADING.q_diag, dt_nominal_secs=0.5)
        x, P = kf.heading_update(x, P, yaw_det_rad=[1.0], yaw_vel_rad=[1.0], r_diag=HEADING.r_diag)
    np.testing.assert_allclose(x[0], [1.0, 0.0], atol=1e-12)


@pytest.mark.parametrize(
    ("measured", "predicted", "expected"),
    [
        (0.1, 0.0, 0.1),
        (0.1, 3.0, 0.1 + np.pi - 2 * np.pi),  # flipped by pi, then wrapped
        (-3.1, 3.1, -3.1),  # 0.083 apart across ±pi: same direction, not flipped
        (3.0, -0.2, 3.0 - np.pi),
        (np.pi / 2, 0.0, np.pi / 2),  # exactly pi/2 apart: kept ("more than pi/2" flips)
        (-np.pi, 0.5, 0.0),
    ],
)
def test_align_heading(measured: float, predicted: float, expected: float) -> None:
    result = kf.align_heading(np.array([measured]), np.array([predicted]))
    np.testing.assert_allclose(result, [expected], atol=1e-12)
    assert abs(wrap_angle(result - predicted)[0]) <= np.pi / 2 + 1e-12


def test_angles_wrap_like_geometry_wrap_angle() -> None:
    edges = np.array([np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 0.0, -0.0, 2 * np.pi, 7.0, -7.0])
    angles = np.concatenate([edges, np.random.default_rng(5).uniform(-20, 20, 200)])
    x, _ = kf.heading_init(angles, p0_diag=HEADING.p0_diag)
    np.testing.assert_allclose(x[:, 0], wrap_angle(angles), atol=1e-12)
    assert np.all(x[:, 0] > -np.pi) and np.all(x[:, 0] <= np.pi)


# ---------------------------------------------------------------------------------------------
# Variable dt and model behaviour
# ---------------------------------------------------------------------------------------------


def test_one_long_predict_equals_several_short_ones_in_the_mean() -> None:
    rng = np.random.default_rng(6)
    x, P = kf.pose_init(
        rng.normal(size=(5, 2)), p0_diag=KITTI_POSE.p0_diag, velocity_xy=rng.normal(size=(5, 2))
    )
    common = {"q_diag": KITTI_POSE.q_diag, "dt_nominal_secs": 0.1}
    x_long, P_long = kf.pose_predict(x, P, dt_secs=np.full(5, 0.3), **common)
    x_short, P_short = x, P
    for _ in range(3):
        x_short, P_short = kf.pose_predict(x_short, P_short, dt_secs=np.full(5, 0.1), **common)
    np.testing.assert_allclose(x_long, x_short, rtol=1e-12, atol=1e-12)
    # the same total process noise enters both, so the position variances are close
    assert np.all(P_long[:, 0, 0] > 0.9 * P_short[:, 0, 0])
    assert_symmetric_psd(P_long)
    assert_symmetric_psd(P_short)


def test_covariances_stay_symmetric_psd_under_random_dt_and_updates() -> None:
    rng = np.random.default_rng(7)
    n = 16
    x, P = kf.pose_init(rng.normal(size=(n, 2)), p0_diag=KITTI_POSE.p0_diag)
    for _ in range(40):
        x, P = kf.pose_predict(
            x, P, dt_secs=rng.uniform(0.0, 1.0, n), q_diag=KITTI_POSE.q_diag, dt_nominal_secs=0.1
        )
        hit = rng.random(n) > 0.3
        xu, Pu = kf.pose_update(
            x[hit], P[hit], xy=rng.normal(size=(hit.sum(), 2)), r_diag=[1e-3, 1e-3]
        )
        x[hit], P[hit] = xu, Pu
        assert_symmetric_psd(P)


def test_ca_estimates_a_constant_acceleration_from_noisy_positions() -> None:
    rng = np.random.default_rng(8)
    dt, accel = 0.1, np.array([1.5, -0.8])
    t = np.arange(200)[:, None] * dt
    positions = np.array([0.0, 5.0]) + np.array([3.0, 1.0]) * t + 0.5 * accel * t**2
    measured = positions + rng.normal(scale=0.05, size=positions.shape)
    x, P = kf.pose_init(measured[:1], p0_diag=[1, 1, 10, 10, 10, 10], n_state=6)
    estimates = []
    for z in measured[1:]:
        x, P = kf.pose_predict(
            x, P, dt_secs=[dt], q_diag=[1e-4] * 4 + [1e-3] * 2, dt_nominal_secs=dt
        )
        x, P = kf.pose_update(x, P, xy=z[None], r_diag=[0.05**2, 0.05**2])
        estimates.append(x[0, 4:6].copy())
    np.testing.assert_allclose(np.array(estimates[-50:]), np.tile(accel, (50, 1)), atol=0.2)


# ---------------------------------------------------------------------------------------------
# Fast path (motion_*) equals the three filters
# ---------------------------------------------------------------------------------------------


def test_motion_noise_layout() -> None:
    noise = kf.motion_noise(pose=NUSC_POSE, size=SIZE, heading=HEADING, model=kf.MotionModel.CV)
    np.testing.assert_array_equal(noise.p0_diag, [[1, 10], [1, 10], [1, 10], [1, 10], [0.1, 0.1]])
    np.testing.assert_array_equal(noise.r_diag, [[0.7, 0.5], [0.7, 0.5], [2, 1], [2, 1], [0.2, 5]])
    ca_pose = kf.DiagonalNoise(p0_diag=[1, 2, 3, 4, 5, 6], q_diag=[1] * 6, r_diag=[0.5, 0.6])
    ca = kf.motion_noise(pose=ca_pose, size=SIZE, heading=HEADING, model=kf.MotionModel.CA)
    np.testing.assert_array_equal(ca.p0_diag[:2], [[1, 3, 5], [2, 4, 6]])
    np.testing.assert_array_equal(ca.p0_diag[4], [0.1, 0.1, 0.0])  # no acceleration state
    np.testing.assert_array_equal(ca.r_diag[:2], [[0.5, 1.0], [0.6, 1.0]])
    with pytest.raises(ValueError, match="pose p0_diag needs 6"):
        kf.motion_noise(pose=NUSC_POSE, size=SIZE, heading=HEADING, model=kf.MotionModel.CA)


def test_diagonal_noise_stack_take_and_validation() -> None:
    other = kf.DiagonalNoise(p0_diag=[2, 2, 2, 2], q_diag=[1, 1, 1, 1], r_diag=[3, 3])
    stacked = kf.DiagonalNoise.stack([KITTI_POSE, other])
    rows = stacked.take([1, 0, 1])
    np.testing.assert_array_equal(rows.r_diag, [[3, 3], [0.1, 0.1], [3, 3]])
    with pytest.raises(ValueError, match="per-category"):
        KITTI_POSE.take([0])
    with pytest.raises(ValueError, match="r_diag must be > 0"):
        kf.DiagonalNoise(p0_diag=[1, 1], q_diag=[1, 1], r_diag=[0.0])
    with pytest.raises(ValueError, match="differ"):
        kf.DiagonalNoise(p0_diag=[1, 1], q_diag=[1], r_diag=[1.0])


@pytest.mark.parametrize("model", [kf.MotionModel.CV, kf.MotionModel.CA])
def test_motion_filter_equals_the_three_filters(model: kf.MotionModel) -> None:
    rng = np.random.default_rng(9)
    n, k = 11, model.order
    pose = kf.DiagonalNoise(
        p0_diag=rng.uniform(0.5, 5, 2 * k),
        q_diag=rng.uniform(0.1, 2, 2 * k),
        r_diag=rng.uniform(0.1, 1, 4),
    )
    noise = kf.motion_noise(pose=pose, size=SIZE, heading=HEADING, model=model)
    xy, v = rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    lw, yaw = rng.uniform(1, 4, (n, 2)), rng.uniform(-3.1, 3.1, n)
    x, P = kf.motion_init(xy=xy, lw=lw, yaw_rad=yaw, p0_diag=noise.p0_diag, velocity_xy=v)
    pose_x, pose_P = kf.pose_init(xy, p0_diag=pose.p0_diag, velocity_xy=v, n_state=2 * k)
    size_x, size_P = kf.size_init(lw, p0_diag=SIZE.p0_diag)
    head_x, head_P = kf.heading_init(yaw, p0_diag=HEADING.p0_diag)
    for step in range(8):
        dt = rng.uniform(0.05, 0.6, n)
        common = {"dt_secs": dt, "dt_nominal_secs": 0.1}
        x, P = kf.motion_predict(x, P, q_diag=noise.q_diag, **common)
        pose_x, pose_P = kf.pose_predict(pose_x, pose_P, q_diag=pose.q_diag, **common)
        size_x, size_P = kf.size_predict(size_x, size_P, q_diag=SIZE.q_diag, **common)
        head_x, head_P = kf.heading_predict(head_x, head_P, q_diag=HEADING.q_diag, **common)
        z_xy, z_v = rng.normal(size=(n, 2)) + step, rng.normal(size=(n, 2))
        z_v[::3] = np.nan
        z_lw, z_yaw = rng.uniform(1, 4, (n, 2)), rng.uniform(-np.pi, np.pi, n)
        yaw_vel, moving = kf.velocity_heading(z_v, min_speed_mps=0.5)
        align = step % 2 == 0
        x, P = kf.motion_update(
            x,
            P,
            xy=z_xy,
            lw=z_lw,
            yaw_det_rad=z_yaw,
            r_diag=noise.r_diag,
            velocity_xy=z_v,
            yaw_vel_rad=yaw_vel,
            yaw_vel_valid=moving,
            align_yaw_det=align,
        )
        pose_x, pose_P = kf.pose_update(
            pose_x, pose_P, xy=z_xy, velocity_xy=z_v, r_diag=pose.r_diag
        )
        size_x, size_P = kf.size_update(size_x, size_P, lw=z_lw, r_diag=SIZE.r_diag)
        yaw_det = kf.align_heading(z_yaw, head_x[:, 0]) if align else z_yaw
        head_x, head_P = kf.heading_update(
            head_x,
            head_P,
            yaw_det_rad=yaw_det,
            yaw_vel_rad=yaw_vel,
            yaw_vel_valid=moving,
            r_diag=HEADING.r_diag,
        )
    tol = {"rtol": 1e-9, "atol": 1e-12}
    np.testing.assert_allclose(kf.motion_xy(x), pose_x[:, :2], **tol)
    np.testing.assert_allclose(kf.motion_velocity_xy(x), pose_x[:, 2:4], **tol)
    np.testing.assert_allclose(kf.motion_lw(x), size_x[:, :2], **tol)
    np.testing.assert_allclose(kf.motion_yaw_rad(x), head_x[:, 0], **tol)
    np.testing.assert_allclose(x[:, kf.Axis.YAW, 1], head_x[:, 1], **tol)
    np.testing.assert_allclose(P[:, kf.Axis.X], pose_P[:, 0::2, 0::2], **tol)
    np.testing.assert_allclose(P[:, kf.Axis.Y], pose_P[:, 1::2, 1::2], **tol)
    np.testing.assert_allclose(P[:, kf.Axis.LENGTH, :2, :2], size_P[:, 0::2, 0::2], **tol)
    np.testing.assert_allclose(P[:, kf.Axis.YAW, :2, :2], head_P, **tol)
    # the axis split is exact: x and y never correlate in the reference layout either
    np.testing.assert_array_equal(pose_P[:, 0, 1::2], 0.0)
    if model is kf.MotionModel.CA:
        np.testing.assert_allclose(kf.motion_acceleration_xy(x), pose_x[:, 4:6], **tol)
        # size and heading get an acceleration state that stays exactly 0 (still CV filters)
        np.testing.assert_array_equal(x[:, kf.Axis.LENGTH :, 2], 0.0)
        np.testing.assert_array_equal(P[:, kf.Axis.LENGTH :, 2, :], 0.0)
    else:
        assert np.isnan(kf.motion_acceleration_xy(x)).all()  # CV estimates none
    assert np.all(np.linalg.eigvalsh(P) >= -1e-12)
    np.testing.assert_array_equal(P, P.mT)


def test_motion_batched_equals_per_row() -> None:
    rng = np.random.default_rng(10)
    n = 7
    noise = kf.motion_noise(pose=NUSC_POSE, size=SIZE, heading=HEADING, model=kf.MotionModel.CV)
    per_row = noise.r_diag * rng.uniform(0.5, 2.0, (n, 1, 1))  # per-category noise rows
    x, P = kf.motion_init(
        xy=rng.normal(size=(n, 2)),
        lw=rng.uniform(1, 4, (n, 2)),
        yaw_rad=rng.uniform(-3, 3, n),
        p0_diag=noise.p0_diag,
    )
    dt = rng.uniform(0.1, 1.0, n)
    meas = {
        "xy": rng.normal(size=(n, 2)),
        "lw": rng.uniform(1, 4, (n, 2)),
        "yaw_det_rad": rng.uniform(-3, 3, n),
        "velocity_xy": rng.normal(size=(n, 2)),
        "yaw_vel_rad": rng.uniform(-3, 3, n),
        "yaw_vel_valid": rng.random(n) > 0.5,
    }
    xb, Pb = kf.motion_predict(x, P, dt_secs=dt, q_diag=noise.q_diag, dt_nominal_secs=0.5)
    xb, Pb = kf.motion_update(xb, Pb, r_diag=per_row, **meas)
    for i in range(n):
        xi, Pi = kf.motion_predict(
            x[i : i + 1],
            P[i : i + 1],
            dt_secs=dt[i : i + 1],
            q_diag=noise.q_diag,
            dt_nominal_secs=0.5,
        )
        xi, Pi = kf.motion_update(
            xi,
            Pi,
            r_diag=per_row[i : i + 1],
            **{key: value[i : i + 1] for key, value in meas.items()},
        )
        np.testing.assert_allclose(xb[i], xi[0], rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(Pb[i], Pi[0], rtol=1e-14, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# Fast-path variants the tracker uses: one shared dt, position-only (KITTI) measurements,
# θ_vel fused with θ_det, and the pose/size axes updated before the heading
# ---------------------------------------------------------------------------------------------


def _kitti_like(model: kf.MotionModel, n: int, seed: int):
    rng = np.random.default_rng(seed)
    k = model.order
    pose = kf.DiagonalNoise(
        p0_diag=rng.uniform(0.5, 5, 2 * k), q_diag=rng.uniform(0.1, 2, 2 * k), r_diag=[0.2, 0.3]
    )
    noise = kf.motion_noise(pose=pose, size=SIZE, heading=HEADING, model=model)
    xy, lw, yaw = rng.normal(size=(n, 2)), rng.uniform(1, 4, (n, 2)), rng.uniform(-3.1, 3.1, n)
    x, P = kf.motion_init(xy=xy, lw=lw, yaw_rad=yaw, p0_diag=noise.p0_diag)
    three = (
        kf.pose_init(xy, p0_diag=pose.p0_diag, n_state=2 * k),
        kf.size_init(lw, p0_diag=SIZE.p0_diag),
        kf.heading_init(yaw, p0_diag=HEADING.p0_diag),
    )
    return rng, pose, noise, (x, P), three


@pytest.mark.parametrize("model", [kf.MotionModel.CV, kf.MotionModel.CA])
def test_position_only_updates_and_fused_heading_equal_the_three_filters(
    model: kf.MotionModel,
) -> None:
    n = 9
    rng, pose, noise, (x, P), ((px, pP), (sx, sP), (hx, hP)) = _kitti_like(model, n, 21)
    for step in range(10):
        dt = 0.1  # one elapsed time for every row, as in a tracker frame
        x, P = kf.motion_predict(x, P, dt_secs=dt, q_diag=noise.q_diag, dt_nominal_secs=0.1)
        common = {"dt_secs": np.full(n, dt), "dt_nominal_secs": 0.1}
        px, pP = kf.pose_predict(px, pP, q_diag=pose.q_diag, **common)
        sx, sP = kf.size_predict(sx, sP, q_diag=SIZE.q_diag, **common)
        hx, hP = kf.heading_predict(hx, hP, q_diag=HEADING.q_diag, **common)
        z_xy, z_lw = rng.normal(size=(n, 2)) + 0.3 * step, rng.uniform(1, 4, (n, 2))
        z_yaw, yaw_vel = rng.uniform(-np.pi, np.pi, n), rng.uniform(-np.pi, np.pi, n)
        moving = rng.uniform(size=n) < (0.5 if step % 3 else 0.0)  # some steps: nobody moves
        # the tracker's order: pose and size first, then the heading with θ_vel
        x, P = kf.motion_update(x, P, xy=z_xy, lw=z_lw, r_diag=noise.r_diag)
        x, P = kf.motion_update(
            x,
            P,
            yaw_det_rad=z_yaw,
            yaw_vel_rad=yaw_vel,
            yaw_vel_valid=moving,
            r_diag=noise.r_diag,
            align_yaw_det=step % 2 == 0,
        )
        px, pP = kf.pose_update(px, pP, xy=z_xy, r_diag=pose.r_diag)
        sx, sP = kf.size_update(sx, sP, lw=z_lw, r_diag=SIZE.r_diag)
        yaw_det = kf.align_heading(z_yaw, hx[:, 0]) if step % 2 == 0 else z_yaw
        hx, hP = kf.heading_update(
            hx, hP, yaw_det_rad=yaw_det, yaw_vel_rad=yaw_vel, yaw_vel_valid=moving,
            r_diag=HEADING.r_diag,
        )  # fmt: skip
        tol = {"rtol": 1e-9, "atol": 1e-11}
        np.testing.assert_allclose(kf.motion_xy(x), px[:, :2], **tol)
        np.testing.assert_allclose(kf.motion_velocity_xy(x), px[:, 2:4], **tol)
        np.testing.assert_allclose(kf.motion_lw(x), sx[:, :2], **tol)
        np.testing.assert_allclose(wrap_angle(kf.motion_yaw_rad(x) - hx[:, 0]), 0.0, atol=1e-11)
        np.testing.assert_allclose(P[:, kf.Axis.X], pP[:, 0::2, 0::2], **tol)
        np.testing.assert_allclose(P[:, kf.Axis.YAW, :2, :2], hP, **tol)
        np.testing.assert_array_equal(P, P.mT)
        assert np.all(np.linalg.eigvalsh(P) >= -1e-12)


@pytest.mark.parametrize("model", [kf.MotionModel.CV, kf.MotionModel.CA])
def test_shared_dt_predict_equals_per_row_predict(model: kf.MotionModel) -> None:
    _, _, noise, (x, P), _ = _kitti_like(model, 6, 22)
    x, P = kf.motion_update(x, P, xy=np.ones((6, 2)), lw=np.full((6, 2), 2.0), r_diag=noise.r_diag)
    q = np.broadcast_to(noise.q_diag, x.shape)
    shared = kf.motion_predict(x, P, dt_secs=0.25, q_diag=q, dt_nominal_secs=0.1)
    per_row = kf.motion_predict(x, P, dt_secs=np.full(6, 0.25), q_diag=q, dt_nominal_secs=0.1)
    np.testing.assert_allclose(shared[0], per_row[0], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(shared[1], per_row[1], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(shared[1], shared[1].mT)
    assert np.all(np.abs(kf.motion_yaw_rad(shared[0])) <= np.pi)


@pytest.mark.parametrize("with_velocity", [False, True])
def test_axis_groups_updated_apart_equal_one_update(with_velocity: bool) -> None:
    """The axes are independent: (xy, lw) then yaw, or xy then (lw, yaw), equal all at once."""
    rng = np.random.default_rng(23)
    n = 8
    noise = kf.motion_noise(pose=NUSC_POSE, size=SIZE, heading=HEADING, model=kf.MotionModel.CV)
    x, P = kf.motion_init(
        xy=rng.normal(size=(n, 2)), lw=rng.uniform(1, 4, (n, 2)), yaw_rad=rng.normal(size=n),
        p0_diag=noise.p0_diag,
    )  # fmt: skip
    meas = {
        "xy": rng.normal(size=(n, 2)),
        "lw": rng.uniform(1, 4, (n, 2)),
        "yaw_det_rad": rng.uniform(-3, 3, n),
        "velocity_xy": rng.normal(size=(n, 2)) if with_velocity else None,
        "yaw_vel_rad": rng.uniform(-3, 3, n),
        "yaw_vel_valid": rng.uniform(size=n) < 0.5,
    }
    together = kf.motion_update(x, P, r_diag=noise.r_diag, **meas)
    first = {k: meas[k] for k in ("xy", "lw", "velocity_xy")}
    second = {k: meas[k] for k in ("yaw_det_rad", "yaw_vel_rad", "yaw_vel_valid")}
    apart = kf.motion_update(
        *kf.motion_update(x, P, r_diag=noise.r_diag, **first), r_diag=noise.r_diag, **second
    )
    other = kf.motion_update(
        *kf.motion_update(
            x, P, r_diag=noise.r_diag, xy=meas["xy"], velocity_xy=meas["velocity_xy"]
        ),
        r_diag=noise.r_diag,
        lw=meas["lw"],
        **second,
    )
    for got in (apart, other):
        np.testing.assert_allclose(got[0], together[0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got[1], together[1], rtol=1e-12, atol=1e-12)
    untouched = kf.motion_update(x, P, r_diag=noise.r_diag, xy=meas["xy"])
    np.testing.assert_array_equal(untouched[0][:, kf.Axis.LENGTH :], x[:, kf.Axis.LENGTH :])
    np.testing.assert_array_equal(untouched[1][:, kf.Axis.LENGTH :], P[:, kf.Axis.LENGTH :])
