"""The KITTI result writer's 2D boxes: projected 3D boxes, optionally narrowed per class."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from tracker.boxes import Boxes
from tracker.calibration import calibrate_frames, find_profile
from tracker.categories import CATEGORIES, category_index
from tracker.config import load_config
from tracker.io.baseversion import read_baseversion
from tracker.io.writers import kitti_lines
from tracker.pipeline import run_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"


def _boxes(lines: list[str]) -> dict[tuple[int, str], np.ndarray]:
    return {(int(f[1]), f[2]): np.array(f[6:10], float) for f in (ln.split() for ln in lines)}


def test_width_scale_narrows_only_its_class_about_the_centre() -> None:
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    frames = calibrate_frames(frames, find_profile("pointrcnn"))
    outputs = run_scene(frames, load_config("kitti")).outputs
    scale = np.ones(len(CATEGORIES))
    scale[category_index("pedestrian")] = 0.5
    pairs = 0
    for out, frame in zip(outputs, frames, strict=True):
        cam = frame.cameras[frame.camera_index("CAM_FRONT")]
        plain = _boxes(kitti_lines(out, cam))
        narrow = _boxes(kitti_lines(out, cam, width_scale=scale))
        assert set(narrow) <= set(plain)
        for key, b in narrow.items():
            a = plain[key]
            if key[1] != "Pedestrian":
                np.testing.assert_allclose(b, a)
                continue
            assert b[[1, 3]] == pytest.approx(a[[1, 3]])  # height unchanged
            if 0 < a[0] and a[2] < cam.width_px - 1:  # not clipped by the image edge
                assert b[2] - b[0] == pytest.approx((a[2] - a[0]) / 2, abs=1e-3)
                assert b[0] + b[2] == pytest.approx(a[0] + a[2], abs=1e-3)
                pairs += 1
    assert pairs > 20


def test_eval_writes_boxes_with_the_given_configs_width(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack eval --config` shapes the static metrics' 2D boxes like the tracking run did:
    the shipped pedestrian width gives another pedestrian HOTA than no narrowing."""
    import json

    from app.cli import main
    from tracker.io.writers import write_tracks_file

    cfg = load_config("kitti")
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    frames = calibrate_frames(frames, find_profile("pointrcnn"))
    outputs = run_scene(frames, cfg).outputs
    write_tracks_file(tmp_path / "tracks.json", {"0001": (frames, outputs)})
    hota = {}
    for name in ("kitti", "kitti_reference"):  # pedestrian width 0.8155 / 1
        out = tmp_path / name
        args = ["eval", str(tmp_path / "tracks.json"), "--gt", str(SAMPLE / "gt.json.gz")]
        args += ["--labels", str(SAMPLE / "raw" / "training" / "label_02"), "--out", str(out)]
        assert main([*args, "--config", name]) == 0
        record = json.loads((out / "eval.json").read_text())
        assert record["classes"] == ["car", "pedestrian", "cyclist"]  # as `mctrack kitti`
        hota[name] = record["static"]["pedestrian"]["HOTA"]
    assert hota["kitti"] > hota["kitti_reference"] + 1.0
    # the detections' own 2D boxes are not in a tracks file: without --detections kitti's
    # image_boxes (auto) falls back to the projections, which the note says
    assert "image_boxes = 'auto' needs the detections' 2D boxes" in capsys.readouterr().err


def test_eval_with_the_detections_writes_their_own_boxes_as_the_run_did(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An image head's boxes: `mctrack eval --detections` writes them as the tracking run's
    writer does (auto, offline smoothing), so it scores what that run's files score, not the
    projections; detections the tracks were not made from are refused in one line."""
    import json

    from app.cli import main
    from tracker.eval.kitti import evaluate_kitti
    from tracker.io.baseversion import write_baseversion
    from tracker.io.writers import write_kitti_sequence, write_tracks_file

    cfg = load_config("kitti_offline")
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    frames = _with_image_boxes(calibrate_frames(frames, find_profile("pointrcnn")), _image_head)
    outputs = run_scene(frames, cfg).outputs
    write_tracks_file(tmp_path / "tracks.json", {"0001": (frames, outputs)})
    write_baseversion(tmp_path / "dets.json", {"0001": frames})
    labels = SAMPLE / "raw" / "training" / "label_02"
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    write_kitti_sequence(run_dir / "0001.txt", outputs, frames, **cfg.kitti_writer_options())
    length = {"0001": 1 + max(f.frame_id for f in frames)}
    want = evaluate_kitti(label_dir=labels, result_dir=run_dir, seq_lengths=length,
                          classes=["car"])["car"]["HOTA"]  # fmt: skip
    args = ["eval", str(tmp_path / "tracks.json"), "--gt", str(SAMPLE / "gt.json.gz"),
            "--labels", str(labels), "--classes", "car", "--config", "kitti_offline"]  # fmt: skip
    hota = {}
    for name, extra in (("own", ["--detections", str(tmp_path / "dets.json")]), ("proj", [])):
        assert main([*args, *extra, "--out", str(tmp_path / name)]) == 0
        hota[name] = json.loads((tmp_path / name / "eval.json").read_text())["static"]
    assert hota["own"]["car"]["HOTA"] == pytest.approx(want, abs=1e-9)
    assert abs(hota["own"]["car"]["HOTA"] - hota["proj"]["car"]["HOTA"]) > 1.0
    capsys.readouterr()
    fewer = [dataclasses.replace(f, boxes=f.boxes[np.arange(min(1, len(f.boxes)))]) for f in frames]
    write_baseversion(tmp_path / "other.json", {"0001": fewer})
    assert main([*args, "--detections", str(tmp_path / "other.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "other.json" in err[0] and "not the detections" in err[0]


# -- which 2D box a matched track reports (image_boxes) ------------------------------------------


def _sample_run() -> tuple[list, list]:
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    frames = calibrate_frames(frames, find_profile("pointrcnn"))
    return frames, run_scene(frames, load_config("kitti")).outputs


def _with_image_boxes(frames: list, move, after: int = -1) -> list:
    """The frames with each detection 2D box replaced by ``move(xyxy)`` from frame ``after`` on."""
    import dataclasses

    return [
        dataclasses.replace(f, boxes=f.boxes.replace(xyxy_image=move(f.boxes.xyxy_image.copy())))
        if i > after
        else f
        for i, f in enumerate(frames)
    ]


def _image_head(xyxy: np.ndarray) -> np.ndarray:
    """A box of its own: 0.67 of the width, shifted by 0.3 of it (IoU with the input < 0.95)."""
    w = xyxy[:, 2] - xyxy[:, 0]
    centre = (xyxy[:, 0] + xyxy[:, 2]) / 2 + 0.3 * w
    return np.column_stack([centre - 0.335 * w, xyxy[:, 1], centre + 0.335 * w, xyxy[:, 3]])


def _matched_pedestrians(outputs: list, frames: list, path: Path):
    """(written 2D box, matched detection's 2D box) of each pedestrian row of ``path`` whose
    track is matched in its frame."""
    lines = _lines_by_frame(path)
    ped = category_index("pedestrian")
    for out, frame in zip(outputs, frames, strict=True):
        written = {int(ln.split()[1]): ln.split() for ln in lines.get(out.frame_id, [])}
        for tid, row, cat in zip(out.boxes.track_id, out.det_row, out.boxes.category, strict=True):
            if row >= 0 and cat == ped and int(tid) in written:
                yield np.array(written[int(tid)][6:10], float), frame.boxes.xyxy_image[row]


def _lines_by_frame(path: Path) -> dict[int, list[str]]:
    out: dict[int, list[str]] = {}
    for line in path.read_text().splitlines():
        out.setdefault(int(line.split()[0]), []).append(line)
    return out


def test_auto_image_boxes_keep_the_projection_of_projected_detections(tmp_path: Path) -> None:
    """A LiDAR detector's 2D boxes are its 3D boxes' projections (PointRCNN's: IoU ~1): they
    add nothing, so `auto` writes exactly what `projection` writes."""
    from tracker.io.writers import ImageBoxStats, write_kitti_sequence

    frames, outputs = _sample_run()
    scale = load_config("kitti").image_width_scales()
    for mode in ("projection", "auto"):
        write_kitti_sequence(
            tmp_path / f"{mode}.txt", outputs, frames, image_boxes=mode, width_scale=scale
        )
    assert (tmp_path / "auto.txt").read_bytes() == (tmp_path / "projection.txt").read_bytes()
    stats = ImageBoxStats(scale)
    own = [
        stats.update(f.boxes, f.cameras[f.camera_index("CAM_FRONT")], f.camera_index("CAM_FRONT"))
        for f in frames
    ]
    assert sum(len(o) for o in own) > 1000 and not np.concatenate(own).any()
    np.testing.assert_array_equal(stats.width_scale(), scale)  # (no own box seen)


def test_auto_image_boxes_write_a_detections_own_box(tmp_path: Path) -> None:
    """Detections with 2D boxes of their own (an image head's) in even rows: a track matched
    to one writes its detection's box as it is (already narrower than the projection: never
    widened); a track matched to a projected box writes its projection; a coasting track
    carries the own box of its last match along with its projection, or writes the projection
    when that match had none."""
    from tracker.io.writers import write_kitti_sequence

    frames, outputs = _sample_run()

    def even_rows(xyxy: np.ndarray) -> np.ndarray:
        xyxy[::2] = _image_head(xyxy[::2])
        return xyxy

    own = _with_image_boxes(frames, even_rows)
    scale = load_config("kitti").image_width_scales()
    for name, fr, mode in (("proj", frames, "projection"), ("auto", own, "auto")):
        write_kitti_sequence(tmp_path / f"{name}.txt", outputs, fr, image_boxes=mode,
                             width_scale=scale)  # fmt: skip
    proj, auto = _lines_by_frame(tmp_path / "proj.txt"), _lines_by_frame(tmp_path / "auto.txt")
    matched = projected_rows = carried_rows = 0
    last_own: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # own box written, projection then
    for out, frame in zip(outputs, own, strict=True):
        written = {int(ln.split()[1]): ln.split() for ln in auto.get(out.frame_id, [])}
        projected = {int(ln.split()[1]): ln.split() for ln in proj.get(out.frame_id, [])}
        for tid, row in zip(out.boxes.track_id.tolist(), out.det_row.tolist(), strict=True):
            if tid not in projected:  # out of the image: nothing to compare
                if row >= 0 and row % 2:
                    last_own.pop(tid, None)
                continue
            proj_box = np.array(projected[tid][6:10], float)
            box = np.array(written[tid][6:10], float)
            assert written[tid][:6] + written[tid][10:] == projected[tid][:6] + projected[tid][10:]
            if row >= 0 and row % 2 == 0:
                np.testing.assert_allclose(box, frame.boxes.xyxy_image[row], atol=1e-3)
                last_own[tid] = (box, proj_box)
                matched += 1
            elif row < 0 and tid in last_own:
                was, then = last_own[tid]
                scale = (proj_box[2:] - proj_box[:2]) / (then[2:] - then[:2])
                centre_then, centre_now = (
                    (then[:2] + then[2:]) / 2,
                    (proj_box[:2] + proj_box[2:]) / 2,
                )
                moved = np.r_[centre_now + (was[:2] - centre_then) * scale,
                              centre_now + (was[2:] - centre_then) * scale]  # fmt: skip
                camera = frame.cameras[frame.camera_index("CAM_FRONT")]
                moved = np.clip(moved, 0, [camera.width_px - 1, camera.height_px - 1] * 2)
                if np.all(moved[2:] > moved[:2]):
                    np.testing.assert_allclose(box, moved, atol=0.05)
                    carried_rows += 1
                else:  # carried out of the image: the projection
                    assert written[tid] == projected[tid]
            else:
                assert written[tid] == projected[tid]
                if row >= 0:
                    last_own.pop(tid, None)
                projected_rows += 1
    assert matched > 100 and projected_rows > 100 and carried_rows > 10


def test_a_carried_box_keeps_its_offset_from_the_projection() -> None:
    """The projection moves 10 px right and doubles in size about its centre: the own box
    moves and scales with it; a track matched to a box not its own forgets its box."""
    from tracker.io.writers import CarriedBoxes

    carried = CarriedBoxes()
    ids = np.array([7, 8])
    own = np.array([[100.0, 50.0, 120.0, 90.0], [0.0, 0.0, 10.0, 10.0]])
    then = np.array([[98.0, 48.0, 118.0, 88.0], [0.0, 0.0, 10.0, 10.0]])  # centre (108, 68)
    carried.remember(ids, own, then, other=np.zeros(0, dtype=np.int64))
    now = np.array([[np.nan] * 4, [88.0, 28.0, 128.0, 108.0]])  # 8: no projection now
    at, boxes = carried.carry(np.array([8, 7]), now)
    assert at.tolist() == [1]  # track 7, at index 1 of the ids asked
    # centre now (108, 68) + 10 px; (100 - 108) * 2 = -16, (50 - 68) * 2 = -36, ...
    now_7 = np.array([98.0, 48.0, 138.0, 128.0])  # centre (118, 88), twice the size
    at, boxes = carried.carry(np.array([7]), now_7[None])
    np.testing.assert_allclose(boxes, [[102.0, 52.0, 142.0, 132.0]])
    carried.remember(np.zeros(0, dtype=np.int64), np.zeros((0, 4)), np.zeros((0, 4)),
                     other=np.array([7]))  # fmt: skip
    assert len(carried.carry(np.array([7]), now_7[None])[0]) == 0


def test_projected_boxes_of_their_own_are_narrowed_like_projections(tmp_path: Path) -> None:
    """A 2D box as wide as its projection but elsewhere (a box left where it was while its 3D
    box moved): written narrowed about its centre by the class's image_width_scale."""
    from tracker.io.writers import write_kitti_sequence

    frames, outputs = _sample_run()

    def shifted(xyxy: np.ndarray) -> np.ndarray:
        w = xyxy[:, 2] - xyxy[:, 0]
        return xyxy + np.column_stack([0.2 * w, 0 * w, 0.2 * w, 0 * w])

    own = _with_image_boxes(frames, shifted)
    scale = load_config("kitti").image_width_scales()
    write_kitti_sequence(tmp_path / "auto.txt", outputs, own, image_boxes="auto",
                         width_scale=scale)  # fmt: skip
    ped, checked = category_index("pedestrian"), 0
    for box, det in _matched_pedestrians(outputs, own, tmp_path / "auto.txt"):
        assert box[2] - box[0] == pytest.approx((det[2] - det[0]) * scale[ped], rel=0.02)
        assert box[0] + box[2] == pytest.approx(det[0] + det[2], abs=1e-3)
        checked += 1
    assert checked > 20


def test_auto_image_boxes_decide_from_the_frames_so_far(tmp_path: Path) -> None:
    """Online output stays online: a frame's boxes depend on the detections up to it. Boxes that
    become the detector's own a third of the way through change nothing before, and are written
    as the detections' from then on."""
    from tracker.io.writers import write_kitti_sequence

    frames, outputs = _sample_run()
    third = len(frames) // 3
    late = _with_image_boxes(frames, _image_head, after=third)
    scale = load_config("kitti").image_width_scales()
    for name, fr, mode in (("proj", frames, "projection"), ("late", late, "auto")):
        write_kitti_sequence(tmp_path / f"{name}.txt", outputs, fr, image_boxes=mode,
                             width_scale=scale)  # fmt: skip
    proj, auto = _lines_by_frame(tmp_path / "proj.txt"), _lines_by_frame(tmp_path / "late.txt")
    ids = [o.frame_id for o in outputs]
    assert all(auto.get(i) == proj.get(i) for i in ids[: third + 1])
    changed = [auto.get(i) != proj.get(i) for i in ids[third + 1 :]]
    assert sum(changed) > 0.5 * len(changed)


def test_image_boxes_setting_is_checked() -> None:
    from tracker.errors import InputError

    assert load_config("kitti").image_boxes.value == "auto"
    assert load_config("kitti", overrides={"image_boxes": "auto"}).image_boxes.value == "auto"
    with pytest.raises(InputError, match="image_boxes"):
        load_config("kitti", overrides={"image_boxes": "detector"})


def test_auto_ignores_the_boxes_detectors_write_for_boxes_behind_the_camera(
    kitti_root: Path, tmp_path: Path
) -> None:
    """VirConv writes whole-image or misplaced 2D boxes for cars reaching behind the camera
    (sequence 0001 has some): those are no evidence, so `auto` still writes what `projection`
    writes for this LiDAR detector."""
    from tracker.cost import iou_xyxy
    from tracker.io.convert.kitti import convert_kitti
    from tracker.io.writers import kitti_label_fields, write_kitti_sequence

    dets, _ = convert_kitti(kitti_root, seqs=["0001"], detector="virconv", classes=["car"],
                            with_gt=False)  # fmt: skip
    frames = calibrate_frames(dets["0001"], find_profile("virconv"))
    odd = 0
    for f in frames:
        _, proj, visible = kitti_label_fields(f.boxes, f.cameras[f.camera_index("CAM_FRONT")])
        ok = visible & np.isfinite(f.boxes.xyxy_image).all(axis=1)
        odd += int((iou_xyxy(f.boxes.xyxy_image[ok], proj[ok]) < 0.95).sum())
    assert odd > 0  # the artefacts are there
    config = load_config("kitti", overrides={"categories": ["car"]})
    outputs = run_scene(frames, config).outputs
    for mode in ("projection", "auto"):
        write_kitti_sequence(tmp_path / f"{mode}.txt", outputs, frames, image_boxes=mode,
                             width_scale=config.image_width_scales())  # fmt: skip
    assert (tmp_path / "auto.txt").read_bytes() == (tmp_path / "projection.txt").read_bytes()


def test_the_width_factor_learnt_so_far_is_the_one_used(tmp_path: Path) -> None:
    """The frames up to k are written the same whether the sequence stops at k or goes on with
    boxes of another width: own boxes as wide as the projection up to k (pedestrians narrowed
    like projections), then as narrow as an image head's (a look-ahead mean ratio of about 0.77
    would leave the early pedestrian boxes unnarrowed)."""
    from tracker.io.writers import write_kitti_sequence

    frames, outputs = _sample_run()
    k = len(frames) // 3

    def wide(xyxy: np.ndarray) -> np.ndarray:  # own boxes, projection-wide
        w = xyxy[:, 2] - xyxy[:, 0]
        return xyxy + np.column_stack([0.2 * w, 0 * w, 0.2 * w, 0 * w])

    mixed = (
        _with_image_boxes(frames, wide)[: k + 1] + _with_image_boxes(frames, _image_head)[k + 1 :]
    )
    scale = load_config("kitti").image_width_scales()
    write_kitti_sequence(tmp_path / "all.txt", outputs, mixed, image_boxes="auto",
                         width_scale=scale)  # fmt: skip
    write_kitti_sequence(tmp_path / "head.txt", outputs[: k + 1], mixed[: k + 1],
                         image_boxes="auto", width_scale=scale)  # fmt: skip
    whole, head = _lines_by_frame(tmp_path / "all.txt"), _lines_by_frame(tmp_path / "head.txt")
    assert head and all(whole.get(i) == lines for i, lines in head.items())
    later = [o.frame_id for o in outputs[k + 1 :]]
    assert any(whole.get(i) for i in later)


def test_detection_boxes_of_another_camera_are_not_written(tmp_path: Path) -> None:
    """A 2D box lives in its own camera's pixels: one of another camera is never written as
    the front camera's, by `auto` or by `detection`; projections keep the class's width."""
    import dataclasses

    from tracker.io.writers import write_kitti_sequence

    frames, outputs = _sample_run()
    other = [
        dataclasses.replace(f, boxes=f.boxes.replace(
            xyxy_image=_image_head(f.boxes.xyxy_image.copy()), camera=f.boxes.camera + 1))
        for f in frames
    ]  # fmt: skip
    scale = load_config("kitti").image_width_scales()
    for name, fr, mode in (("proj", frames, "projection"), ("auto", other, "auto"),
                           ("det", other, "detection")):  # fmt: skip
        write_kitti_sequence(tmp_path / f"{name}.txt", outputs, fr, image_boxes=mode,
                             width_scale=scale)  # fmt: skip
    projected = (tmp_path / "proj.txt").read_bytes()
    assert (tmp_path / "auto.txt").read_bytes() == projected
    assert (tmp_path / "det.txt").read_bytes() == projected
    # detection mode on projected boxes: the box of the detection, narrowed like a projection
    write_kitti_sequence(tmp_path / "det_proj.txt", outputs, frames, image_boxes="detection",
                         width_scale=scale)  # fmt: skip
    ped, checked = category_index("pedestrian"), 0
    for got, box in _matched_pedestrians(outputs, frames, tmp_path / "det_proj.txt"):
        if box[0] < 1 or box[2] > 1240:  # (clipped by the image edge)
            continue
        assert got[2] - got[0] == pytest.approx((box[2] - box[0]) * scale[ped], rel=1e-3)
        checked += 1
    assert checked > 20


def test_window_means_equal_a_loop_over_each_groups_frames() -> None:
    from tracker.io.writers import window_means

    rng = np.random.default_rng(3)
    group = rng.integers(0, 4, 60)
    frame = np.array([rng.choice(200, 1)[0] for _ in group])
    keep = np.unique(np.column_stack([group, frame]), axis=0, return_index=True)[1]
    group, frame = group[keep], frame[keep]  # one row per group and frame
    values = rng.normal(size=(len(group), 3))
    got = window_means(frame, group, values, 5)
    for i in range(len(group)):
        near = (group == group[i]) & (np.abs(frame - frame[i]) <= 5)
        np.testing.assert_allclose(got[i], values[near].mean(axis=0))
    # at other points (a group of no row, frames with no row near: NaN)
    q_frame, q_group = rng.integers(-10, 210, 40), rng.integers(0, 5, 40)
    got = window_means(frame, group, values, 5, at=(q_frame, q_group))
    for i in range(len(q_frame)):
        near = (group == q_group[i]) & (np.abs(frame - q_frame[i]) <= 5)
        want = values[near].mean(axis=0) if near.any() else np.full(3, np.nan)
        np.testing.assert_allclose(got[i], want)
    assert np.isnan(got).any() and np.isfinite(got).any()


def _offline_run() -> tuple[list, list]:
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"]
    frames = calibrate_frames(frames, find_profile("pointrcnn"))
    return frames, run_scene(frames, load_config("kitti_offline")).outputs


def _written(path: Path) -> dict[tuple[int, int], np.ndarray]:
    return {
        (int(f[0]), int(f[1])): np.array(f[6:10], float)
        for f in (ln.split() for ln in path.read_text().splitlines())
    }


def test_offline_smoothing_averages_an_image_heads_noise(tmp_path: Path) -> None:
    """An image head whose boxes sit at a fixed offset from the 3D boxes' projections, each with
    its own noise (σ 4 px a corner): offline, the written boxes of matched tracks come nearer the
    noise-free ones, and so do the boxes coasting and interpolated rows carry (the average
    offset around their frame, not their track's last own box's)."""
    from tracker.io.writers import write_kitti_sequence

    frames, outputs = _offline_run()
    rng = np.random.default_rng(0)
    clean = _with_image_boxes(frames, _image_head)
    noisy = _with_image_boxes(frames, lambda b: _image_head(b) + rng.normal(0, 4.0, b.shape))
    scale = load_config("kitti_offline").image_width_scales()
    runs = (("clean", clean, 0), ("clean_smooth", clean, 15), ("raw", noisy, 0),
            ("smooth", noisy, 15))  # fmt: skip
    for name, fr, window in runs:
        write_kitti_sequence(tmp_path / f"{name}.txt", outputs, fr, image_boxes="auto",
                             width_scale=scale, own_box_window=window)  # fmt: skip
    truth, truth_smooth, raw, smooth = (_written(tmp_path / f"{n}.txt") for n, _, _ in runs)
    assert raw.keys() == smooth.keys() == truth.keys() == truth_smooth.keys()
    matched = {
        (o.frame_id, int(t))
        for o in outputs
        for t, r in zip(o.boxes.track_id, o.det_row, strict=True)
        if r >= 0
    }
    own = sorted(matched & raw.keys())
    err_raw = np.mean([np.abs(raw[k] - truth[k]).mean() for k in own])
    err_smooth = np.mean([np.abs(smooth[k] - truth[k]).mean() for k in own])
    # the noise that is left: the same smoothing of the noise-free boxes is nearly the same box
    noise_left = np.mean([np.abs(smooth[k] - truth_smooth[k]).mean() for k in own])
    assert len(own) > 300 and err_smooth < 0.8 * err_raw and noise_left < 0.4 * err_raw
    others = sorted(raw.keys() - matched)  # coasting and interpolated rows
    carried_raw = np.mean([np.abs(raw[k] - truth[k]).mean() for k in others])  # 4.1 px
    carried_left = np.mean([np.abs(smooth[k] - truth_smooth[k]).mean() for k in others])
    # (their last own box's noise, carried as before, would leave all of it: 4.1 px here)
    assert len(others) > 100 and carried_left < 0.7 * carried_raw


def test_offline_smoothing_leaves_projected_boxes_alone(tmp_path: Path) -> None:
    """PointRCNN's 2D boxes are its 3D boxes' projections: there is no own box to smooth, and
    the file is the same byte for byte; the window comes from the offline config only."""
    from tracker.io.writers import write_kitti_sequence

    frames, outputs = _offline_run()
    for window in (0, 15):
        write_kitti_sequence(tmp_path / f"{window}.txt", outputs, frames, image_boxes="auto",
                             own_box_window=window)  # fmt: skip
    assert (tmp_path / "0.txt").read_bytes() == (tmp_path / "15.txt").read_bytes()
    assert load_config("kitti_offline").kitti_writer_options()["own_box_window"] == 15  # 1.5 s
    assert load_config("kitti").kitti_writer_options()["own_box_window"] == 0
    plain = load_config("kitti_offline", overrides={"offline": {"smooth_image_boxes": False}})
    assert plain.kitti_writer_options()["own_box_window"] == 0


def test_a_sliver_of_projection_at_the_image_edge_stays_out_of_the_average() -> None:
    """Track 1 writes own boxes 10 px right of its projection in 3 frames; in the middle frame
    its projection is cut by the image edge to a 2 px sliver (a tenth of its width): that row
    keeps its box and leaves the others' offset alone. In the full frames the offset is the
    same, so the average changes nothing."""
    from tracker.events import TrackOutput
    from tracker.frame import Camera
    from tracker.io.writers import smooth_own_boxes

    camera = Camera("CAM_FRONT", np.eye(3, 4), np.eye(4), 1242, 375)
    boxes = Boxes.create(xyz=np.zeros((1, 3)), lwh=np.ones((1, 3)), yaw=np.zeros(1),
                         category=np.zeros(1, dtype=np.int64), track_id=np.array([1]))  # fmt: skip
    out = [TrackOutput("s", k, k / 10, boxes, np.zeros((1, 2)), np.zeros(1, np.int8),
                       np.zeros(1, np.int64), np.ones(1, np.int8)) for k in range(3)]  # fmt: skip
    proj = [np.array([[100.0, 100.0, 120.0, 150.0]]), np.array([[0.0, 100.0, 2.0, 150.0]]),
            np.array([[104.0, 100.0, 124.0, 150.0]])]  # fmt: skip
    own = [p + np.array([10.0, 0.0, 10.0, 0.0]) for p in proj]
    own[1] = np.array([[0.0, 100.0, 30.0, 150.0]])  # the head's box: the visible part
    in_view = [np.ones(1), np.array([0.1]), np.ones(1)]
    collected = [
        (out[k], (None, own[k].copy(), np.ones(1, bool), proj[k], np.array([0]), in_view[k]),
         camera)
        for k in range(3)
    ]  # fmt: skip
    smooth_own_boxes(collected, 15)
    for k in range(3):
        np.testing.assert_allclose(collected[k][1][1], own[k])


@pytest.mark.parametrize("fill", [0.0, -1.0])
def test_detections_without_a_2d_box_write_the_projections(tmp_path: Path, fill: float) -> None:
    """3D-only pipelines write 0 0 0 0 or -1 -1 -1 -1 as the 2D box: no box of their own, so
    `auto` (offline, with the own boxes' smoothing) writes what `projection` writes."""
    from tracker.io.writers import write_kitti_sequence

    frames, outputs = _offline_run()
    write_kitti_sequence(tmp_path / "projection.txt", outputs, frames, image_boxes="projection")
    blank = _with_image_boxes(frames, lambda b: np.full_like(b, fill))
    write_kitti_sequence(tmp_path / "auto.txt", outputs, blank, image_boxes="auto",
                         own_box_window=15)  # fmt: skip
    text = (tmp_path / "auto.txt").read_text()
    assert text.count("\n") > 300 and text == (tmp_path / "projection.txt").read_text()


def test_eval_says_nothing_of_image_boxes_without_labels(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The image_boxes note is about the 2D boxes of the static metrics: without --labels
    (motion metrics alone) it does not apply and is not printed."""
    from app.cli import main

    tracks = tmp_path / "t" / "tracks.json"
    assert main(["track", str(SAMPLE / "detections.json.gz"), "--out", str(tracks.parent)]) == 0
    capsys.readouterr()
    args = ["eval", str(tracks), "--gt", str(SAMPLE / "gt.json.gz"), "--motion"]
    assert main([*args, "--out", str(tmp_path / "e")]) == 0
    assert "image_boxes" not in capsys.readouterr().err
