"""The BEV distance gate that follows the detections' noise (``bev.gate_motion_m``): its radius
is √(gate_motion_m² + (4σ)²) once the scene's centre noise σ is estimated, so a track whose own
detection is missing leaves a neighbour's alone on clean boxes and still follows its object on
noisy ones; the compiled and numpy paths agree."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tests.test_noise import PED, _scene
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


def _camera_frame(i: int, xy: np.ndarray) -> Frame:
    """``_frame`` seen by a camera at the origin looking along +x, each box's 2D box its
    projection (as a LiDAR detector's)."""
    from tests.test_mctracker import _front_camera
    from tracker.camera import project_boxes

    f = _frame(i, xy)
    cam = _front_camera()
    xyxy, _ = project_boxes(f.boxes, cam)
    boxes = f.boxes.replace(xyxy_image=xyxy, camera=np.zeros(len(xyxy), dtype=np.int64))
    return Frame(scene="s", frame_id=i, timestamp_secs=f.timestamp_secs, boxes=boxes,
                 cameras=(cam,))  # fmt: skip


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("behind_m", [0.7, 1.5])
def test_stage_2_cannot_take_what_the_motion_gate_refused(compiled: bool, behind_m: float) -> None:
    """The neighbour stands behind the pedestrian on the camera's line of sight, so their 2D
    boxes overlap and stage 2 (image plane) would pair them within its own 5 m gate: capped at
    the motion gate (0.5 m + 4σ), it leaves the neighbour alone too; without the motion gate the
    track takes it."""
    rng = np.random.default_rng(0)
    frames = [_camera_frame(i, np.array([10.0, 0.0]) + rng.normal(0, 0.03, 2)) for i in range(60)]
    frames.append(_camera_frame(60, np.array([10.0 + behind_m, 0.0])))
    own, taker = _holders(MCTracker(_config(math.inf), compiled=compiled), frames)
    assert taker == own
    tracker = MCTracker(_config(0.5), compiled=compiled)
    own, taker = _holders(tracker, frames)
    assert taker != own
    assert tracker.rv_gate[PED] < math.sqrt(tracker.gate_sq[PED])  # (the shortcut stays exact)


def test_compiled_and_numpy_paths_agree_with_the_motion_gate() -> None:
    """Four pairs of pedestrians walking 0.6 m apart, one of each pair detected in six frames of
    seven (p 0.99), the other in one of three (p 0.6: its tracks never confirm), with the
    shipped pedestrian settings: the same ids and boxes from both paths, and not those of the
    same scene without the motion gate, where a track whose box is missing takes the
    neighbour's."""
    rng = np.random.default_rng(4)
    frames = []
    for i in range(80):
        xy, score = [], []
        for k in range(4):
            if (i + k) % 7 != 3:
                xy.append(np.array([10 + 0.12 * i, 3.0 * k]) + rng.normal(0, 0.03, 2))
                score.append(0.99)
            if (i + k) % 3 == 0:
                xy.append(np.array([10.6 + 0.12 * i, 3.0 * k]) + rng.normal(0, 0.03, 2))
                score.append(0.6)
        f = _frame(i, np.array(xy))
        frames.append(dataclasses.replace(f, boxes=f.boxes.replace(score=np.array(score))))

    def run(gate: float, compiled: bool) -> list[list[tuple[int, int]]]:
        bev = {"pedestrian": {"bev": {"gate_motion_m": gate}}}
        config = load_config("kitti", overrides={"categories": ["pedestrian"], "category": bev})
        tracker = MCTracker(config, compiled=compiled)
        outs = [tracker.step(f) for f in frames]
        assert (tracker.gate_sq[PED] < 100.0) == (gate < math.inf)  # the gate narrowed
        return [list(zip(o.boxes.track_id.tolist(), o.det_row.tolist(), strict=True)) for o in outs]

    plain, compiled = run(0.5, False), run(0.5, True)
    assert plain == compiled
    assert sum(a != b for a, b in zip(compiled, run(math.inf, True), strict=True)) > 5


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_a_non_positive_motion_gate_is_refused(value: float) -> None:
    with pytest.raises(InputError, match="gate_motion_m"):
        _config(value)
