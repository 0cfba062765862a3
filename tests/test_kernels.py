"""The compiled per-frame kernels (tracker/kernels/) equal the numpy stages they
replace: on random inputs stage by stage (including the rare branches: heading flips, moving
objects, contested assignments, NaN boxes), and over whole scenes."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from tracker import kalman, mctracker
from tracker.boxes import Boxes
from tracker.camera import NEAR_PLANE_M, in_image_fraction
from tracker.config import load_config
from tracker.cost import ro_gdiou_bev_arrays
from tracker.events import LifecycleChanged, ListObserver, TrackStatus
from tracker.frame import Camera
from tracker.io.baseversion import read_baseversion
from tracker.kernels import load as load_kernels
from tracker.matching import hungarian
from tracker.mctracker import MCTracker
from tracker.pipeline import run_scene
from tracker.track import TrackTable
from tracker.velocity_baselines import WINDOW

from .test_mctracker_fast_paths import assert_same_tracking

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"

LIVE_STATUSES = [
    TrackStatus.TENTATIVE,
    TrackStatus.CONFIRMED,
    TrackStatus.COASTING,
    TrackStatus.LOST,
]
kernels = load_kernels()
pytestmark = pytest.mark.skipif(kernels is None, reason="numba not installed (numpy path only)")


def random_spd(rng: np.random.Generator, shape: tuple[int, ...], k: int) -> np.ndarray:
    a = rng.normal(size=(*shape, k, k))
    return a @ np.swapaxes(a, -1, -2) + 0.1 * np.eye(k)


def random_table(rng: np.random.Generator, n: int, k: int) -> TrackTable:
    """n tracks with random filter states: some fast (moving), some slow, some with votes."""
    table = TrackTable.empty(order=k)
    x = rng.normal(size=(n, 5, k))
    x[:, :2, 0] *= 20
    x[:, 2:4, 0] = rng.uniform(0.5, 5, size=(n, 2))
    x[:, 4, 0] = rng.uniform(-np.pi, np.pi, n)
    x[: n // 2, :2, 1] *= 10  # clearly moving
    P = random_spd(rng, (n, 5), k) * 0.01
    zeros = np.zeros(n, dtype=np.int64)
    # each track's last 1..W detection times (NaN before its first)
    det_t = np.cumsum(rng.uniform(0.05, 0.3, (n, WINDOW)), axis=1)
    det_t[np.arange(WINDOW) < WINDOW - rng.integers(1, WINDOW + 1, n)[:, None]] = np.nan
    return dataclasses.replace(
        table,
        track_id=np.arange(n, dtype=np.int64),
        category=rng.integers(0, 3, n),
        status=rng.choice(np.array(LIVE_STATUSES, dtype=np.int8), n),
        hits=rng.integers(1, 5, n),
        misses=rng.integers(0, 4, n),
        age=zeros,
        motion_x=x,
        motion_P=P,
        score=rng.uniform(0, 1, n),
        last_xyxy=np.zeros((n, 4)),
        last_camera=zeros - 1,
        last_det_xyz=np.zeros((n, 3)),
        last_det_lwh=np.ones((n, 3)),
        zh=np.ones((n, 2)),
        last_det_yaw=np.zeros(n),
        heading_votes=rng.integers(0, 3, n),
        evidence=rng.uniform(0.0, 8.0, n),
        log_odds=rng.normal(0.0, 3.0, n),
        matched_det=zeros - 1,
        matched_stage=np.zeros(n, dtype=np.int8),
        det_t=det_t,
        det_xy=rng.normal(0.0, 20.0, (n, WINDOW, 2)) + np.isnan(det_t)[..., None] * np.nan,
        baseline=rng.normal(size=(n, 2, 2)),
    )


def copy_table(table: TrackTable) -> TrackTable:
    return TrackTable(*[np.array(getattr(table, f.name)) for f in dataclasses.fields(table)])


def assert_tables_close(a: TrackTable, b: TrackTable) -> None:
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if x.dtype.kind == "f":
            np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-12, err_msg=f.name)
        else:
            np.testing.assert_array_equal(x, y, err_msg=f.name)


@pytest.mark.parametrize("k", [2, 3])
def test_predict_kernel_equals_numpy(k: int) -> None:
    rng = np.random.default_rng(k)
    n, dt = 40, 0.137
    x = rng.normal(size=(n, 5, k)) * 3  # yaw values beyond ±pi: wrapped
    P = random_spd(rng, (n, 5), k)
    category = rng.integers(0, 3, n)
    q = rng.uniform(0, 1, size=(3, 5, k))
    want_x, want_P = kalman.motion_predict(
        x, P, dt_secs=dt, q_diag=q[category], dt_nominal_secs=0.1
    )
    got_x, got_P = kernels.motion_predict_kernel(x, P, category, q, dt, dt / 0.1)
    np.testing.assert_allclose(got_x, want_x, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(got_P, want_P, rtol=1e-13, atol=1e-13)
    assert np.all(np.abs(got_x[:, 4, 0]) <= np.pi)
    np.testing.assert_array_equal(got_P, np.swapaxes(got_P, -1, -2))  # exactly symmetric


def test_bev_cost_kernel_equals_numpy() -> None:
    rng = np.random.default_rng(3)
    n_tracks, n_dets = 30, 25
    tracks = np.column_stack(
        [rng.uniform(0, 15, (n_tracks, 2)), rng.uniform(0.5, 5, (n_tracks, 2)),
         rng.uniform(-np.pi, np.pi, n_tracks)]
    )  # fmt: skip
    dets = np.column_stack(
        [rng.uniform(0, 15, (n_dets, 2)), rng.uniform(0.5, 5, (n_dets, 2)),
         rng.uniform(-np.pi, np.pi, n_dets)]
    )  # fmt: skip
    dets[3] = tracks[2]  # identical boxes
    tracks[5, 3] = np.nan  # a missing size: scored (inside the gate) but +inf
    dets[7, 4] = np.nan
    track_cat, det_cat = rng.integers(0, 3, n_tracks), rng.integers(0, 3, n_dets)
    det_cat[3] = track_cat[2]
    gate = np.array([6.0, 3.0, 4.0])
    w1, w2 = np.array([1.0, 0.0, 0.5]), np.array([1.0, 1.0, 0.0])  # a zero weight each
    cost, mask = kernels.bev_cost_kernel(tracks, track_cat, dets, det_cat, gate**2, w1, w2)

    delta = tracks[:, None, :2] - dets[None, :, :2]
    near = np.einsum("tdk,tdk->td", delta, delta) < gate[track_cat][:, None] ** 2
    want_mask = (track_cat[:, None] == det_cat[None, :]) & near
    sim = ro_gdiou_bev_arrays(tracks, dets, w1=w1[track_cat], w2=w2[track_cat], mask=want_mask)
    np.testing.assert_array_equal(mask, want_mask)
    assert 20 < mask.sum() < mask.size / 2  # both gated and scored pairs
    np.testing.assert_allclose(cost, 1.0 - sim, rtol=1e-12, atol=1e-12)
    assert cost[2, 3] == pytest.approx(0.0, abs=1e-12)
    assert np.isinf(cost[5]).all() and np.isinf(cost[:, 7]).all()


@pytest.mark.parametrize("k", [2, 3])
def test_update_kernel_equals_numpy(k: int) -> None:
    """Every branch of the heading logic: aligned, moving, flipped by votes, plain."""
    rng = np.random.default_rng(10 + k)
    cfg = load_config("kitti", overrides={"categories": ["car", "pedestrian", "cyclist"]})
    compiled, plain = MCTracker(cfg), MCTracker(cfg, compiled=False)
    assert compiled._kernels is not None and plain._kernels is None
    table = random_table(rng, 60, k)
    table.heading_votes[:] = 2  # the next disagreement flips a static track
    idx = np.sort(rng.choice(60, 45, replace=False))
    yaw = table.motion_x[idx, 4, 0] + rng.normal(0, 0.1, len(idx))
    yaw[::3] += np.pi  # disagree by ~180°
    dets = Boxes.create(
        xyz=np.column_stack([table.motion_x[idx, :2, 0], np.zeros(len(idx))])
        + rng.normal(0, 0.3, (len(idx), 3)),
        lwh=np.column_stack([table.motion_x[idx, 2:4, 0] + 0.2, np.ones(len(idx))]),
        yaw=(yaw + np.pi) % (2 * np.pi) - np.pi,
        category=table.category[idx],
        score=rng.uniform(0, 1, len(idx)),
    )
    det_rows = rng.permutation(len(idx))
    dets = dets[np.argsort(det_rows)]  # detection det_rows[j] belongs to track idx[j]
    compiled._tracks, plain._tracks = copy_table(table), copy_table(table)
    compiled._update(idx, dets, det_rows)
    plain._update(idx, dets, det_rows)
    assert_tables_close(compiled._tracks, plain._tracks)
    # the rare branches did run
    flipped = (table.heading_votes[idx] == 2) & (compiled._tracks.heading_votes[idx] == 0)
    assert flipped.sum() >= 3
    assert (compiled._tracks.heading_votes[idx] == 3).sum() == 0
    untouched = np.setdiff1d(np.arange(60), idx)
    np.testing.assert_array_equal(compiled._tracks.motion_x[untouched], table.motion_x[untouched])


def test_isolated_pairs_kernel_equals_hungarian() -> None:
    rng = np.random.default_rng(7)
    solved_seen = contested_seen = 0
    for trial in range(300):
        m, n = rng.integers(0, 7), rng.integers(0, 7)
        cost = rng.uniform(0, 2, (m, n))
        cost[rng.uniform(size=(m, n)) < 0.7] = np.inf
        if trial % 10 == 0 and m and n:
            cost[0, 0] = np.nan
        threshold = rng.uniform(0.5, 1.5, m)
        pairs, costs, rows, cols, solved = kernels.isolated_pairs_kernel(cost, threshold)
        if not solved:
            contested_seen += 1
            assert len(pairs) == len(rows) == len(cols) == 0
            continue
        solved_seen += 1
        want = hungarian(cost, max_cost_per_row=threshold)
        np.testing.assert_array_equal(pairs, want.pairs)
        np.testing.assert_array_equal(costs, want.costs)
        np.testing.assert_array_equal(rows, want.unmatched_rows)
        np.testing.assert_array_equal(cols, want.unmatched_cols)
    assert solved_seen > 100 and contested_seen > 20


@pytest.mark.parametrize("confirm_prob", [1.0, 0.99])
def test_lifecycle_kernel_equals_numpy(confirm_prob: float) -> None:
    rng = np.random.default_rng(11)
    overrides = {
        "categories": ["car", "pedestrian", "cyclist"],
        "defaults": {"lifecycle": {"confirm_prob": confirm_prob, "min_hits": 5}},
        "category": {"car": {"lifecycle": {"confirm_prob": confirm_prob, "min_hits": 5}}},
    }
    cfg = load_config("kitti", overrides=overrides)
    for _ in range(20):
        compiled, plain = (
            MCTracker(cfg, observer=lambda e: None),
            MCTracker(cfg, observer=lambda e: None, compiled=False),
        )
        table = random_table(rng, 50, 3)
        table.misses[:] = rng.integers(0, 25, 50)
        n_born = int(rng.integers(0, 4))
        born = table.track_id[50 - n_born :]
        matched = np.sort(rng.choice(50 - n_born, 20, replace=False))
        compiled._tracks, plain._tracks = copy_table(table), copy_table(table)
        got, want = compiled._lifecycle(matched, born), plain._lifecycle(matched, born)
        assert isinstance(got, LifecycleChanged) and isinstance(want, LifecycleChanged)
        for field in ("born", "confirmed", "lost", "reacquired", "deleted"):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field), field)
        assert_tables_close(compiled._tracks, plain._tracks)


@pytest.mark.parametrize("config_name", ["kitti", "kitti_reference"])
def test_record_hits_kernel_equals_numpy(config_name: str) -> None:
    """Scores across (0, 1), exactly 0 and 1, NaN, and near 0.5 (scipy's logit switches
    formula there); z/height smoothed (kitti) or copied (kitti_reference)."""
    rng = np.random.default_rng(3)
    cfg = load_config(config_name, overrides={"categories": ["car", "pedestrian", "cyclist"]})
    compiled, plain = MCTracker(cfg), MCTracker(cfg, compiled=False)
    assert compiled._cat.any_vertical_smoothing == (config_name == "kitti")
    n, d = 60, 40
    score = rng.uniform(0, 1, d)
    score[:8] = [0.0, 1.0, np.nan, 0.5, 0.3, 0.65, 0.2999999, 1e-12]
    dets = Boxes.create(
        xyz=rng.normal(size=(d, 3)) * 10,
        lwh=rng.uniform(0.5, 5, (d, 3)),
        yaw=rng.uniform(-np.pi, np.pi, d),
        category=rng.integers(0, 3, d),
        score=score,
        xyxy_image=rng.uniform(0, 500, (d, 4)),
        camera=rng.integers(-1, 1, d),
    )
    for _ in range(5):
        table = random_table(rng, n, 3)
        idx = np.sort(rng.choice(n, d, replace=False))
        det_rows = rng.permutation(d)
        compiled._tracks, plain._tracks = copy_table(table), copy_table(table)
        args = (idx, dets, det_rows, dets.xyz[det_rows], dets.lwh[det_rows])
        compiled._record_hits(*args)
        plain._record_hits(*args)
        assert_tables_close(compiled._tracks, plain._tracks)
        assert not np.array_equal(compiled._tracks.hits, table.hits)


def test_record_detections_kernel_equals_numpy() -> None:
    """The velocity baselines' windows move on and the baselines follow, for tracks with 1, 2
    and W or more detections behind them."""
    rng = np.random.default_rng(5)
    cfg = load_config("kitti", overrides={"categories": ["car", "pedestrian", "cyclist"]})
    compiled, plain = MCTracker(cfg), MCTracker(cfg, compiled=False)
    assert compiled._kernels is not None and plain._kernels is None
    n = 40
    for step in range(4):
        table = random_table(rng, n, 3)
        idx = np.sort(rng.choice(n, 25, replace=False))
        xy = rng.normal(0.0, 20.0, (25, 2))
        compiled._tracks, plain._tracks = copy_table(table), copy_table(table)
        compiled._record_detections(idx, 2.0 + step, xy)
        plain._record_detections(idx, 2.0 + step, xy)
        assert_tables_close(compiled._tracks, plain._tracks)
        np.testing.assert_array_equal(plain._tracks.det_xy[idx, -1], xy)
        one = idx[np.isnan(table.det_t[idx, -2])]  # a track's 2nd detection: no curve yet
        assert len(one) and (plain._tracks.baseline[one, 1] == 0).all()
        assert (plain._tracks.baseline[one, 0] != 0).all()


def test_in_image_fraction_kernel_equals_numpy() -> None:
    """Boxes in front of, across and behind the near plane of a KITTI-like camera; the kernel
    leaves NaN where a corner is behind the near plane (the tracker falls back to numpy)."""
    rng = np.random.default_rng(5)
    cam = Camera(
        "CAM2",
        np.array([[700.0, 0.0, 600.0, 40.0], [0.0, 700.0, 180.0, 0.2], [0.0, 0.0, 1.0, 0.003]]),
        np.array(
            [[0.0, -1.0, 0.0, 0.1], [0.0, 0.0, -1.0, 1.6], [1.0, 0.0, 0.0, -0.3], [0, 0, 0, 1]]
        ),
        1242,
        375,
    )
    n = 2000
    xyz = np.column_stack([rng.uniform(-5, 60, n), rng.uniform(-40, 40, n), rng.normal(0, 1, n)])
    lwh = rng.uniform(0.4, 6.0, (n, 3))
    yaw = rng.uniform(-np.pi, np.pi, n)
    assert kernels is not None
    got = kernels.in_image_fraction_kernel(
        xyz, lwh, yaw, cam.image_from_world, cam.width_px - 1.0, cam.height_px - 1.0, NEAR_PLANE_M
    )
    want = in_image_fraction(xyz, lwh, yaw, cam)
    front = ~np.isnan(got)
    np.testing.assert_allclose(got[front], want[front], rtol=0, atol=1e-12)
    assert 0.5 * n < front.sum() < n  # both paths exercised
    assert (want[front] == 0).sum() > 50 and (want[front] == 1).sum() > 50
    assert ((want[front] > 0) & (want[front] < 1)).sum() > 50


@pytest.fixture(scope="module")
def sample_frames():
    if not SAMPLE.is_dir():
        pytest.skip("sample_data/kitti-0001 missing")
    return read_baseversion(SAMPLE / "detections.json.gz")["0001"]


def _numpy_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mctracker, "load_kernels", lambda: None)


@pytest.mark.parametrize("config_name", ["kitti", "kitti_offline"])
def test_compiled_tracker_equals_numpy_on_the_sample(
    sample_frames, config_name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = load_config(config_name, overrides={"categories": ["car", "pedestrian", "cyclist"]})
    compiled = run_scene(sample_frames, cfg).outputs
    observed = ListObserver()
    compiled_observed = run_scene(sample_frames, cfg, observer=observed).outputs
    _numpy_only(monkeypatch)
    assert_same_tracking(compiled, run_scene(sample_frames, cfg).outputs, exact=False)
    assert_same_tracking(compiled, compiled_observed, exact=True)
    assert any(isinstance(e, LifecycleChanged) and len(e.deleted) for e in observed.events)


def test_numba_switch(monkeypatch: pytest.MonkeyPatch) -> None:
    """MCTRACK_NUMBA=0 selects the numpy stages."""
    monkeypatch.setenv("MCTRACK_NUMBA", "0")
    load_kernels.cache_clear()
    try:
        assert load_kernels() is None
        assert MCTracker(load_config("kitti"))._kernels is None
    finally:
        monkeypatch.delenv("MCTRACK_NUMBA")
        load_kernels.cache_clear()
    assert load_kernels() is not None
