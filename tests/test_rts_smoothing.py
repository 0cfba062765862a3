"""The offline RTS smoother (tracker.smoothing.rts_smooth): the tracker's own pose filter run
forwards over each track's detections, then the Rauch-Tung-Striebel backward pass. It equals a
textbook one-track implementation, removes the online filter's lag, and offline mode writes it."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.categories import category_index
from tracker.config import load_config
from tracker.frame import Frame
from tracker.geometry import wrap_angle
from tracker.mctracker import motion_noise_tables
from tracker.pipeline import run_scene
from tracker.smoothing import rts_smooth, rts_smooth_heading


def _textbook(times, z, p0, q, r, dt0, *, smooth=True):
    """One chain [p, v, a], z (T,) with NaN where unmeasured: the Kalman filter (x̂ₜ per frame),
    or, with ``smooth``, the RTS smoother, written out step by step."""
    xs, Ps, xp, Pp, Fs = [], [], [], [], []
    x, P = np.array([z[0], 0.0, 0.0]), np.diag(p0)
    for t in range(len(z)):
        F = np.eye(3)
        if t:
            dt = times[t] - times[t - 1]
            F = np.array([[1, dt, dt * dt / 2], [0, 1, dt], [0, 0, 1]])
            x, P = F @ x, F @ P @ F.T + np.diag(q) * dt / dt0
        xp.append(x), Pp.append(P), Fs.append(F)
        if np.isfinite(z[t]):
            gain = P[:, 0] / (P[0, 0] + r)
            x, P = x + gain * (z[t] - x[0]), P - np.outer(gain, P[0])
        xs.append(x), Ps.append(P)
    if not smooth:
        return np.array(xs)
    out = [xs[-1]]
    for t in range(len(z) - 2, -1, -1):
        C = Ps[t] @ Fs[t + 1].T @ np.linalg.pinv(Pp[t + 1])
        out.insert(0, xs[t] + C @ (out[0] - xp[t + 1]))
    return np.array(out)


def _noise(config, name):
    pose = config.per_category[name].pose
    pose = pose.ca if pose.motion.value == "ca" else pose.cv
    k = len(pose.p) // 2
    pad = lambda v: np.pad(np.reshape(v, (k, 2)).T, ((0, 0), (0, 3 - k)))  # noqa: E731
    return pad(pose.p), pad(pose.q), np.asarray(pose.r[:2])


@pytest.mark.parametrize("config_name", ["kitti", "kitti_reference"])  # CA and CV poses
def test_equals_textbook_rts_per_track(config_name: str) -> None:
    """Interleaved tracks of three classes, missed frames, uneven frame times, a one-frame
    track: every track and axis equals the textbook smoother on its own."""
    rng = np.random.default_rng(3)
    config = load_config(config_name)
    times = np.cumsum(rng.uniform(0.08, 0.12, 60))
    spans = [(0, 40, "car"), (5, 59, "pedestrian"), (10, 13, "cyclist"), (30, 30, "car")]
    frame_index, track, xy, cat, names = [], [], [], [], []
    for k, (f0, f1, name) in enumerate(spans):
        f = np.arange(f0, f1 + 1)
        f = f[(rng.uniform(size=len(f)) > 0.25) | (f == f0) | (f == f1)]
        t = times[f]
        xy.append(np.column_stack([3 * t + 0.5 * t**2, -t]) + rng.normal(0, 0.3, (len(f), 2)))
        frame_index += list(f)
        track += [100 - 7 * k] * len(f)  # ids in any order
        cat += [category_index(name)] * len(f)
        names += [name] * len(f)
    frame_index, track, xy, cat = map(np.array, (frame_index, track, np.vstack(xy), cat))
    got = rts_smooth(times, frame_index, track, xy, cat, config)
    assert got.shape == (len(xy), 2, 3)
    for tid in np.unique(track):
        rows = np.flatnonzero(track == tid)
        f0, f1 = frame_index[rows].min(), frame_index[rows].max()
        p0, q, r = _noise(config, names[rows[0]])
        for axis in range(2):
            z = np.full(f1 - f0 + 1, np.nan)
            z[frame_index[rows] - f0] = xy[rows, axis]
            want = _textbook(times[f0 : f1 + 1], z, p0[axis], q[axis], r[axis], 0.1)
            np.testing.assert_allclose(got[rows, axis], want[frame_index[rows] - f0], atol=1e-8)


def test_removes_the_online_filters_lag() -> None:
    """A car speeding up and braking (speed 8 ± 3 m/s), seen with 0.15 m noise through the car
    filter trusting one box little (r 1.5 m², as under noisy boxes): the online estimate trails
    the car whenever its acceleration changes, the smoothed one does not."""
    pose = {"r_scale": 0.0, "ca": {"r": [1.5, 1.5]}}
    config = load_config("kitti", overrides={"category": {"car": {"pose": pose}}})
    rng = np.random.default_rng(0)
    times = 0.1 * np.arange(80)
    truth = np.column_stack([8 * times - 3 / 0.8 * np.cos(0.8 * times), np.zeros(80)])
    z = truth + rng.normal(0, 0.15, truth.shape)
    car = np.full(80, category_index("car"))
    smoothed = rts_smooth(times, np.arange(80), np.zeros(80, int), z, car, config)[..., 0]
    p0, q, r = _noise(config, "car")
    online = _textbook(times, z[:, 0], p0[0], q[0], r[0], 0.1, smooth=False)[:, 0]
    # the online filter's error is mostly its lag, which the noise does not average away
    online_err, smoothed_err = truth[10:, 0] - online[10:], truth[10:, 0] - smoothed[10:, 0]
    assert np.abs(online_err).mean() > 2.5 * np.abs(smoothed_err).mean()


def test_offline_mode_writes_the_smoothed_track() -> None:
    """kitti_offline (rts on): a detected row's x, y and velocity are the smoother's over the
    track's detections, its r offline.rts_r_multiple times the filter's; off, they are the online
    filter's."""
    car = category_index("car")
    rng = np.random.default_rng(5)
    t = 0.1 * np.arange(30)
    centres = np.column_stack([10 + 8 * t, 2 + 0.5 * t]) + rng.normal(0, 0.2, (30, 2))
    frames = [
        Frame(
            scene="s", frame_id=i, timestamp_secs=t[i],
            boxes=Boxes.create(
                xyz=[[*centres[i], 0.8]], lwh=[[4.2, 1.8, 1.6]], yaw=[0.05], category=[car],
                score=[0.99],
            ),
        )
        for i in range(30)
    ]  # fmt: skip

    pose = {"r_scale": 0.0, "ca": {"r": [1.0, 1.0]}}  # (one car: no noise estimate to scale)
    car_pose = {"car": {"pose": pose}}

    def run(rts: bool):
        overrides = {"categories": ["car"], "offline": {"rts": rts}, "category": car_pose}
        outputs = run_scene(frames, load_config("kitti_offline", overrides=overrides)).outputs
        assert [len(o) for o in outputs] == [1] * 30
        return np.vstack([o.boxes.xyz[:, :2] for o in outputs]), np.vstack(
            [o.boxes.velocity for o in outputs]
        )

    config = load_config("kitti_offline", overrides={"categories": ["car"], "category": car_pose})
    r = motion_noise_tables(config)[2] * config.offline.rts_r_multiple  # (kitti_offline: 3)
    want = rts_smooth(
        t, np.arange(30), np.zeros(30, int), centres, np.full(30, car), config, motion_r=r
    )
    xy_on, v_on = run(True)
    np.testing.assert_allclose(xy_on, want[..., 0], atol=1e-9)
    np.testing.assert_allclose(v_on, want[..., 1], atol=1e-9)
    assert np.abs(v_on[5:] - [8.0, 0.5]).max() < 1.0  # the smoothed velocity is the car's
    xy_off, _ = run(False)
    assert np.abs(xy_off - xy_on).max() > 0.05


def _heading_noise(config, name):
    h = config.per_category[name].heading.noise
    return np.r_[h.p, 0.0], np.r_[h.q, 0.0], h.r[0]


def test_heading_equals_textbook_rts_through_flips_and_wraps() -> None:
    """A car turning through ±π, its detected yaws noisy and half of them flipped by π (a box's
    axis has no direction): the smoothed heading equals the textbook smoother of the heading
    filter [θ, ω] on the continuous angle, in the direction the online heading gives."""
    config = load_config("kitti")
    rng = np.random.default_rng(4)
    n = 50
    times = 0.1 * np.arange(n)
    truth = 2.6 + 0.4 * times  # crosses π at t ≈ 1.35 s
    seen = np.flatnonzero((rng.uniform(size=n) > 0.2) | (np.arange(n) % 49 == 0))
    z = truth[seen] + rng.normal(0, 0.05, len(seen))
    flipped = rng.uniform(size=len(seen)) < 0.5
    yaw = wrap_angle(z + np.pi * flipped)
    heading = wrap_angle(truth[seen] + rng.normal(0, 0.2, len(seen)))  # the online direction
    car = np.full(len(seen), category_index("car"))
    got = rts_smooth_heading(times, seen, np.full(len(seen), 7), yaw, heading, car, config)
    p0, q, r = _heading_noise(config, "car")
    chain = np.full(n, np.nan)
    chain[seen] = z
    want = _textbook(times, chain, p0, q, r, 0.1)[seen, 0]
    np.testing.assert_allclose(got, wrap_angle(want), atol=1e-8)
    # against the opposite direction, the same axis turned by π
    back = rts_smooth_heading(times, seen, np.full(len(seen), 7), yaw, heading + np.pi, car,
                              config)  # fmt: skip
    np.testing.assert_allclose(wrap_angle(back - got - np.pi), 0.0, atol=1e-8)


def test_heading_tracks_are_independent() -> None:
    """Interleaved tracks (one of a single row), rows shuffled, smoothed together: each equals
    itself smoothed alone, in the input order; a missing yaw is refused."""
    config = load_config("kitti")
    rng = np.random.default_rng(1)
    times = 0.1 * np.arange(30)
    frame_index = np.r_[np.arange(0, 20), np.arange(8, 30), 4]
    track = np.r_[np.full(20, 3), np.full(22, 1), -6]
    yaw = wrap_angle(np.r_[np.full(20, 1.0), np.full(22, -3.0), 2.0] + rng.normal(0, 0.1, 43))
    shuffle = rng.permutation(43)
    frame_index, track, yaw = frame_index[shuffle], track[shuffle], yaw[shuffle]
    cat = np.full(43, category_index("car"))
    both = rts_smooth_heading(times, frame_index, track, yaw, yaw, cat, config)
    assert both[track == -6] == pytest.approx(yaw[track == -6])  # one row: its own yaw
    with pytest.raises(ValueError, match="finite"):
        rts_smooth_heading(times, frame_index, track, np.r_[yaw[:-1], np.nan], yaw, cat, config)
    for tid in (1, 3):
        rows = track == tid
        alone = rts_smooth_heading(
            times, frame_index[rows], track[rows], yaw[rows], yaw[rows], cat[rows], config
        )
        np.testing.assert_allclose(both[rows], alone, atol=1e-12)


def test_offline_mode_writes_the_smoothed_heading() -> None:
    """kitti_offline: with rts_heading a detected row's heading is the heading smoother's over
    the track's detected yaws, closer to a turning car's than the online filter's; off, it is
    the online filter's."""
    car = category_index("car")
    rng = np.random.default_rng(2)
    t = 0.1 * np.arange(40)
    truth = 0.3 * t  # a steady left turn
    centres = np.column_stack([20 + 8 * t, 2 + t])
    yaw = truth + rng.normal(0, 0.08, 40)
    frames = [
        Frame(
            scene="s", frame_id=i, timestamp_secs=t[i],
            boxes=Boxes.create(
                xyz=[[*centres[i], 0.8]], lwh=[[4.2, 1.8, 1.6]], yaw=[yaw[i]], category=[car],
                score=[0.99],
            ),
        )
        for i in range(40)
    ]  # fmt: skip

    def run(on: bool) -> np.ndarray:
        overrides = {"categories": ["car"], "offline": {"rts_heading": on}}
        outputs = run_scene(frames, load_config("kitti_offline", overrides=overrides)).outputs
        assert [len(o) for o in outputs] == [1] * 40
        return np.concatenate([o.boxes.yaw for o in outputs])

    config = load_config("kitti_offline", overrides={"categories": ["car"]})
    online, smoothed = run(False), run(True)
    want = rts_smooth_heading(t, np.arange(40), np.zeros(40, int), yaw, online,
                              np.full(40, car), config)  # fmt: skip
    np.testing.assert_allclose(smoothed, want, atol=1e-9)
    err = lambda h: np.abs(wrap_angle(h[5:] - truth[5:])).mean()  # noqa: E731
    assert err(smoothed) < 0.9 * err(online)
