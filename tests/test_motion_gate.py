"""The BEV distance gate that follows the detections' noise (``bev.gate_motion_m``): its radius
is √(gate_motion_m² + (4σ)²) once the scene's centre noise σ is estimated, so a track whose own
detection is missing leaves a neighbour's alone on clean boxes and still follows its object on
noisy ones; the compiled and numpy paths agree."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.test_noise import PED, _feed, _scene
from tracker.boxes import Boxes
from tracker.config import load_config
from tracker.errors import InputError
from tracker.frame import Frame
from tracker.mctracker import GATE_NOISE_SIGMAS, MCTracker
from tracker.noise import PositionNoise


def _config(gate_motion_m: float, **bev: float):
    return load_config(
        "kitti",
        overrides={
            "categories": ["pedestrian"],
            "category": {
                "pedestrian": {
                    "bev": {"gate_motion_m": gate_motion_m, **bev},
                    "lifecycle": {"min_hits": 1, "max_misses_output": 3},
                }
            },
        },
    )


def _frame(i: int, xy: np.ndarray) -> Frame:
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    return Frame(
        scene="s",
        frame_id=i,
        timestamp_secs=0.1 * i,
        boxes=Boxes.create(
            xyz=np.column_stack([xy, np.full(len(xy), 0.9)]),
            lwh=np.tile([0.9, 0.6, 1.7], (len(xy), 1)),
            yaw=np.zeros(len(xy)),
            category=np.full(len(xy), PED),
            score=np.full(len(xy), 0.99),
        ),
    )


@pytest.mark.parametrize("compiled", [False, True])
def test_the_radius_follows_the_noise_estimate(compiled: bool) -> None:
    rng = np.random.default_rng(1)
    _, scene = _scene(rng, frames=40, sigma=0.1, category=PED, spacing=3.0)
    frames = [_frame(i, xy) for i, (xy, _, _) in enumerate(scene)]
    config = _config(0.5)
    tracker, est = MCTracker(config, compiled=compiled), PositionNoise(8)
    gate_sq = config.per_category["pedestrian"].bev.gate_distance_m ** 2
    seen = 0
    for f in frames:
        tracker.step(f)
        est.update(f.timestamp_secs, f.boxes.xyz[:, :2], f.boxes.lwh[:, 0], f.boxes.category)
        var = est.variance()[PED]
        want = gate_sq if np.isnan(var) else min(gate_sq, 0.25 + GATE_NOISE_SIGMAS**2 * var)
        assert tracker.gate_sq[PED] == pytest.approx(want, rel=1e-12)
        seen += not np.isnan(var)
    assert seen > 10  # the estimate existed for most of the scene
    assert math.sqrt(tracker.gate_sq[PED]) == pytest.approx(math.sqrt(0.25 + 16 * 0.01), rel=0.1)
    # off (the default): the config's gate throughout
    off = MCTracker(_config(math.inf), compiled=compiled)
    for f in frames:
        off.step(f)
    assert off.gate_sq[PED] == gate_sq


def _neighbour_scene(sigma: float, seed: int = 0) -> list[Frame]:
    """A pedestrian standing at (10, 0), detected with noise ``sigma`` for 60 frames; in frame
    60 its detection is missing and a neighbour's is 0.9 m to its side."""
    rng = np.random.default_rng(seed)
    frames = [_frame(i, np.array([10.0, 0.0]) + rng.normal(0, sigma, 2)) for i in range(60)]
    return [*frames, _frame(60, np.array([10.0, 0.9]))]


def _holders(tracker: MCTracker, frames: list[Frame]) -> tuple[int, int]:
    """The ids of the tracks that hold the last two frames' boxes."""
    for f in frames[:-2]:
        tracker.step(f)
    ids = []
    for f in frames[-2:]:
        out = tracker.step(f)
        holder = out.boxes.track_id[out.det_row == 0]
        assert len(holder) == 1
        ids.append(int(holder[0]))
    return ids[0], ids[1]


@pytest.mark.parametrize("compiled", [False, True])
def test_a_track_missing_its_detection_leaves_a_neighbours_alone(compiled: bool) -> None:
    """The cost gate (made wide here) accepts the neighbour; on clean boxes (σ 0.03 m) the
    motion gate (√(0.5² + (4σ)²) m) does not, so the neighbour starts its own track; with boxes
    noisy enough (σ 0.3 m: a radius of about 1.2 m) a 0.9 m jump can be the object's own, and
    its track takes it."""
    frames = _neighbour_scene(0.03)
    own, taker = _holders(MCTracker(_config(math.inf, cost_max=3.0), compiled=compiled), frames)
    assert taker == own  # without the motion gate the track jumps to its neighbour
    own, taker = _holders(MCTracker(_config(0.5, cost_max=3.0), compiled=compiled), frames)
    assert taker != own
    frames = _neighbour_scene(0.3)
    own, taker = _holders(MCTracker(_config(0.5, cost_max=3.0), compiled=compiled), frames)
    assert taker == own


def test_compiled_and_numpy_paths_agree_with_the_motion_gate() -> None:
    """Pedestrians walking 1.2 m apart, with noise and drops: the same ids and boxes."""
    rng = np.random.default_rng(4)
    t, scene = _scene(rng, n_objects=6, frames=50, sigma=0.15, category=PED, spacing=1.2)
    frames = []
    for i, (xy, _, _) in enumerate(scene):
        keep = rng.uniform(size=len(xy)) > 0.15
        frames.append(_frame(i, xy[keep] / 8.0))  # walking pace: 0.6-1.9 m/s
    assert _feed(t, scene).variance()[PED] > 0
    outs = []
    for compiled in (False, True):
        tracker = MCTracker(_config(0.5), compiled=compiled)
        outs.append([tracker.step(f).boxes for f in frames])
        assert tracker.gate_sq[PED] < 100.0  # the gate narrowed
    for a, b in zip(*outs, strict=True):
        np.testing.assert_array_equal(a.track_id, b.track_id)
        np.testing.assert_allclose(a.xyz, b.xyz, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_a_non_positive_motion_gate_is_refused(value: float) -> None:
    with pytest.raises(InputError, match="gate_motion_m"):
        _config(value)
