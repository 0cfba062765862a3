"""The robustness benchmark: seeded detection noise (tracker.eval.perturb), `mctrack robustness`."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.cli import main
from tracker.boxes import Boxes
from tracker.camera import project_boxes
from tracker.eval.perturb import NOISE_LEVELS, PerturbSpec, perturb_frames, sigmoid_rescore
from tracker.frame import Frame
from tracker.geometry import wrap_angle
from tracker.io.synthetic import synthetic_scene

SAMPLE_KIT = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001" / "raw"


def _scene(name: str = "synthetic", *, seed: int = 3, num_frames: int = 150) -> list[Frame]:
    """A synthetic scene whose detections sit in the camera, like converted KITTI detections:
    camera 0, the 2D box = the projection, and a raw score (the score's logit)."""
    dets, _ = synthetic_scene(
        num_objects=60, num_frames=num_frames, seed=seed, dropout=0.0, scene=name
    )
    frames = []
    for frame in dets:
        xyxy, visible = project_boxes(frame.boxes, frame.cameras[0])
        b = frame.boxes[visible]
        b = b.replace(
            xyxy_image=xyxy[visible],
            camera=np.zeros(len(b), dtype=np.int64),
            score_raw=np.log(b.score / (1 - b.score)),
        )
        frames.append(dataclasses.replace(frame, boxes=b))
    return frames


def _all(frames: list[Frame]) -> Boxes:
    return Boxes.concat([f.boxes for f in frames])


def _added(perturbed: Frame, source: Frame) -> Boxes:
    """The false positives: the rows after the (undropped) real boxes."""
    return perturbed.boxes[np.arange(len(source.boxes), len(perturbed.boxes))]


def _count(frames: list[Frame]) -> int:
    return sum(len(f.boxes) for f in frames)


@pytest.fixture(scope="module")
def scene() -> list[Frame]:
    frames = _scene()
    assert _count(frames) > 5000
    return frames


def test_same_seed_same_boxes_other_seed_different(scene: list[Frame]) -> None:
    spec = dataclasses.replace(NOISE_LEVELS["double"], score_sigma=0.5)
    a = perturb_frames(scene, spec, seed=4)
    b = perturb_frames(scene, spec, seed=4)
    c = perturb_frames(scene, spec, seed=5)
    assert all(fa.boxes.equals(fb.boxes) for fa, fb in zip(a, b, strict=True))
    assert not _all(a).equals(_all(c))
    assert [f.frame_id for f in a] == [f.frame_id for f in scene]


def test_a_scene_noise_does_not_depend_on_the_other_scenes() -> None:
    """Seeded per scene from its name: perturbing A alone or after B gives the same A."""
    a, b = _scene("A", num_frames=20), _scene("B", seed=9, num_frames=20)
    spec = NOISE_LEVELS["noise"]
    alone = perturb_frames(a, spec, seed=1)
    together = perturb_frames(b + a, spec, seed=1)[len(b) :]
    assert all(x.boxes.equals(y.boxes) for x, y in zip(alone, together, strict=True))
    # and two scenes with the same content but other names get different noise
    renamed = perturb_frames([dataclasses.replace(f, scene="C") for f in a], spec, seed=1)
    assert not _all(alone).equals(_all(renamed))


def test_a_class_noise_does_not_depend_on_the_other_classes(scene: list[Frame]) -> None:
    """One stream per class: a class perturbed alone (`--classes pedestrian`) gets the boxes it
    gets beside the others, drops, jitter, false positives and score noise alike."""
    spec = dataclasses.replace(NOISE_LEVELS["double"], score_sigma=0.5)
    together = perturb_frames(scene, spec, seed=2)
    categories = np.unique(_all(scene).category)
    assert len(categories) == 2
    for c in categories:
        only = [dataclasses.replace(f, boxes=f.boxes[f.boxes.category == c]) for f in scene]
        alone = perturb_frames(only, spec, seed=2)
        for x, y in zip(together, alone, strict=True):
            assert x.boxes[x.boxes.category == c].equals(y.boxes)
        # the false positives were compared too: the same real boxes are kept without them
        no_fp = perturb_frames(only, dataclasses.replace(spec, fp_rate=0.0), seed=2)
        assert _count(alone) > _count(no_fp)
    # the classes' streams differ: the same boxes relabelled draw other noise
    relabelled = [
        dataclasses.replace(f, boxes=f.boxes.replace(category=np.full(len(f.boxes), categories[0])))
        for f in scene
    ]
    swapped = [
        dataclasses.replace(f, boxes=f.boxes.replace(category=np.full(len(f.boxes), categories[1])))
        for f in scene
    ]
    a = perturb_frames(relabelled, spec, seed=2)
    b = perturb_frames(swapped, spec, seed=2)
    assert not np.array_equal(_all(a).xyz[:100], _all(b).xyz[:100])


def test_clean_spec_is_the_identity(scene: list[Frame]) -> None:
    out = perturb_frames(scene, NOISE_LEVELS["clean"], seed=0)
    assert all(o is f for o, f in zip(out, scene, strict=True))
    # a spec whose every rate is zero draws but changes nothing either
    assert PerturbSpec().is_clean and not NOISE_LEVELS["noise"].is_clean


def test_drop_fraction_and_kept_boxes_unchanged(scene: list[Frame]) -> None:
    out = perturb_frames(scene, PerturbSpec(drop_rate=0.3), seed=2)
    n, kept = _count(scene), _count(out)
    sd = np.sqrt(0.3 * 0.7 / n)
    assert abs((n - kept) / n - 0.3) < 4 * sd
    for before, after in zip(scene, out, strict=True):
        rows = [
            int(np.flatnonzero((before.boxes.xyz == p).all(axis=1))[0]) for p in after.boxes.xyz
        ]
        assert rows == sorted(rows)  # a subsequence: the kept rows in their order, untouched
        assert after.boxes.equals(before.boxes[np.array(rows, dtype=np.int64)])


def test_jitter_statistics_and_the_2d_box_moves_with_the_3d_box(scene: list[Frame]) -> None:
    spec = PerturbSpec(centre_sigma_m=0.2, yaw_sigma_deg=3.0)
    out = perturb_frames(scene, spec, seed=6)
    before, after = _all(scene), _all(out)
    assert len(after) == len(before)
    d = after.xyz - before.xyz
    n = len(d)
    for axis in (0, 1):
        assert abs(d[:, axis].std() - 0.2) < 0.2 * 4 / np.sqrt(2 * n)
        assert abs(d[:, axis].mean()) < 0.2 * 4 / np.sqrt(n)
    np.testing.assert_array_equal(d[:, 2], 0.0)  # BEV jitter: height untouched
    dyaw = np.rad2deg(wrap_angle(after.yaw - before.yaw))
    assert abs(dyaw.std() - 3.0) < 3.0 * 4 / np.sqrt(2 * n)
    np.testing.assert_array_equal(after.lwh, before.lwh)
    np.testing.assert_array_equal(after.score, before.score)
    # The 2D box shifts by the change of the projection; here the 2D box *is* the projection, so
    # it must equal the jittered box's projection wherever neither is clipped by the image.
    for frame in out:
        proj, visible = project_boxes(frame.boxes, frame.cameras[0], clip_to_image=False)
        cam = frame.cameras[0]
        inside = visible & (proj[:, :2] > 1).all(axis=1)
        inside &= (proj[:, 2] < cam.width_px - 2) & (proj[:, 3] < cam.height_px - 2)
        np.testing.assert_allclose(frame.boxes.xyxy_image[inside], proj[inside], atol=1e-6)


def test_image_boxes_keep_leaves_the_2d_boxes_and_jitters_the_same_3d_boxes(
    scene: list[Frame],
) -> None:
    """``image_boxes="keep"``: the same 3D jitter (same seed) as "follow", every kept 2D box as
    the detector gave it; an unknown rule is refused."""
    spec = PerturbSpec(drop_rate=0.2, centre_sigma_m=0.3, yaw_sigma_deg=5.0)
    follow = _all(perturb_frames(scene, spec, seed=2))
    keep = _all(perturb_frames(scene, spec, seed=2, image_boxes="keep"))
    np.testing.assert_array_equal(keep.xyz, follow.xyz)
    np.testing.assert_array_equal(keep.yaw, follow.yaw)
    assert np.nanmax(np.abs(follow.xyxy_image - keep.xyxy_image)) > 1.0  # follow moved them
    # the kept boxes are a subsequence of the input: match them by their (unjittered) height
    before = _all(scene)
    rows = [int(np.flatnonzero(before.xyz[:, 2] == z)[0]) for z in keep.xyz[:, 2]]
    np.testing.assert_array_equal(keep.xyxy_image, before.xyxy_image[rows])
    with pytest.raises(ValueError, match="image_boxes"):
        perturb_frames(scene, spec, seed=2, image_boxes="drift")  # type: ignore[arg-type]


def test_false_positives_count_plausibility_and_projection(scene: list[Frame]) -> None:
    rate = 0.2
    out = perturb_frames(scene, PerturbSpec(fp_rate=rate), seed=8)
    real = _all(scene)
    fps = Boxes.concat([_added(o, f) for o, f in zip(out, scene, strict=True)])
    for frame, source in zip(out, scene, strict=True):  # real boxes first, unchanged
        assert frame.boxes[np.arange(len(source.boxes))].equals(source.boxes)
    for category in np.unique(real.category):
        expected = rate * (real.category == category).sum()
        got = (fps.category == category).sum()
        assert abs(got - expected) < 4 * np.sqrt(expected) + 1, (category, got, expected)
    assert (fps.track_id == -1).all() and (fps.camera == 0).all()
    # plausible: a real size and (score, raw score) pair of the class
    for i in range(len(fps)):
        same = real.category == fps.category[i]
        assert (real.lwh[same] == fps.lwh[i]).all(axis=1).any()
        assert (
            (real.score[same] == fps.score[i]) & (real.score_raw[same] == fps.score_raw[i])
        ).any()
    # 2D box = projection of the 3D box, inside the image; the centre is in the camera's view
    for frame, source in zip(out, scene, strict=True):
        fp = _added(frame, source)
        if not len(fp):
            continue
        cam = frame.cameras[0]
        proj, visible = project_boxes(fp, cam)
        assert visible.all()
        np.testing.assert_allclose(fp.xyxy_image, proj, atol=1e-9)
        assert (fp.xyxy_image >= 0).all()
        assert (fp.xyxy_image[:, [0, 2]] <= cam.width_px - 1).all()
        assert (fp.xyxy_image[:, [1, 3]] <= cam.height_px - 1).all()
    # inside the region the real boxes cover (depth = world x for this camera at the origin)
    assert real.xyz[:, 0].min() - 1e-9 <= fps.xyz[:, 0].min()
    assert fps.xyz[:, 0].max() <= real.xyz[:, 0].max() + 1e-9
    assert len(np.unique(fps.yaw)) == len(fps)  # a random heading each


def test_score_noise_recomputes_the_score_with_rescore(scene: list[Frame]) -> None:
    out = perturb_frames(scene, PerturbSpec(score_sigma=0.5), seed=1)
    before, after = _all(scene), _all(out)
    d = after.score_raw - before.score_raw
    assert abs(d.std() - 0.5) < 0.5 * 4 / np.sqrt(2 * len(d))
    np.testing.assert_allclose(after.score, sigmoid_rescore(after.category, after.score_raw))
    np.testing.assert_array_equal(after.xyz, before.xyz)

    seen: list[np.ndarray] = []

    def rescore(category: np.ndarray, raw: np.ndarray, range_m: np.ndarray) -> np.ndarray:
        seen.append(category.copy())
        assert range_m.shape == raw.shape
        return np.clip(raw / 10.0, 0.0, 1.0)

    custom = _all(perturb_frames(scene, PerturbSpec(score_sigma=0.5), seed=1, rescore=rescore))
    np.testing.assert_array_equal(custom.score_raw, after.score_raw)  # same draws
    np.testing.assert_allclose(custom.score, np.clip(custom.score_raw / 10.0, 0.0, 1.0))
    np.testing.assert_array_equal(seen[0], custom.category)


def test_score_noise_needs_a_raw_score_and_specs_are_checked(scene: list[Frame]) -> None:
    no_raw = [
        dataclasses.replace(f, boxes=f.boxes.replace(score_raw=np.full(len(f.boxes), np.nan)))
        for f in scene[:5]
    ]
    with pytest.raises(ValueError, match="score_raw"):
        perturb_frames(no_raw, PerturbSpec(score_sigma=0.1), seed=0)
    with pytest.raises(ValueError, match="drop_rate"):
        PerturbSpec(drop_rate=1.5)
    with pytest.raises(ValueError, match="centre_sigma_m"):
        PerturbSpec(centre_sigma_m=-0.1)
    with pytest.raises(ValueError, match="seed"):
        perturb_frames(scene[:2], NOISE_LEVELS["noise"], seed=-1)


def test_a_stronger_level_drops_a_superset_at_one_seed(scene: list[Frame]) -> None:
    weak = perturb_frames(scene, PerturbSpec(drop_rate=0.1), seed=3)
    strong = perturb_frames(scene, PerturbSpec(drop_rate=0.2), seed=3)
    for w, s in zip(weak, strong, strict=True):
        kept_weak = {tuple(p) for p in w.boxes.xyz}
        assert {tuple(p) for p in s.boxes.xyz} <= kept_weak


# --------------------------------------------------------------------------------------------
# The command, on the bundled one-sequence kit (sample_data/kitti-0001/raw)


@pytest.fixture(scope="module")
def sample_kit() -> Path:
    if not (SAMPLE_KIT / "training" / "calib" / "0001.txt").is_file():
        pytest.skip(f"bundled sample kit missing at {SAMPLE_KIT}")
    return SAMPLE_KIT


def test_tracking_perturbed_kitti_is_deterministic(sample_kit: Path) -> None:
    from tracker.config import load_config
    from tracker.io.convert.kitti import convert_kitti
    from tracker.pipeline import run_scene

    dets, _ = convert_kitti(sample_kit, seqs=["0001"], classes=["car"], with_gt=False)
    frames = dets["0001"][:200]
    config = load_config("kitti", overrides={"categories": ["car"]})
    runs = [run_scene(perturb_frames(frames, NOISE_LEVELS["noise"], seed=0), config) for _ in "ab"]
    first, second = (Boxes.concat([o.boxes for o in r.outputs]) for r in runs)
    assert len(first) > 500 and first.equals(second)


def test_robustness_command_on_the_sample(
    sample_kit: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from app.kitti import run_kitti

    out = tmp_path / "rob"
    args = ["--kitti-root", str(sample_kit), "--seqs", "0001", "--classes", "car"]
    assert main(["robustness", *args, "--levels", "noise", "--seeds", "0", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "car HOTA" in printed and "noise" in printed and "clean" in printed

    report = json.loads((out / "robustness.json").read_text())
    assert {"detector", "sequences", "classes", "config", "seeds", "levels", "evaluator"} <= set(
        report
    )
    assert list(report["levels"]) == ["clean", "noise"]  # clean always runs, first
    for level in report["levels"].values():
        assert set(level) == {"spec", "runs", "summary"}
        assert set(level["summary"]["car"]) == {"HOTA_mean", "HOTA_spread", "HOTA_drop"}
    clean, noise = report["levels"]["clean"], report["levels"]["noise"]
    assert [r["seed"] for r in clean["runs"]] == [None] and [r["seed"] for r in noise["runs"]] == [
        0
    ]
    assert noise["spec"] == dataclasses.asdict(NOISE_LEVELS["noise"])
    drop = noise["summary"]["car"]["HOTA_drop"]
    assert drop == pytest.approx(
        noise["summary"]["car"]["HOTA_mean"] - clean["summary"]["car"]["HOTA_mean"], abs=1e-3
    )
    assert drop < 0  # noise costs HOTA
    assert "| noise |" in (out / "robustness.md").read_text()
    assert report["image_boxes"] == "follow"

    kept = tmp_path / "keep"
    argv = ["robustness", *args, "--levels", "noise", "--seeds", "0", "--image-boxes", "keep"]
    assert main([*argv, "--out", str(kept)]) == 0
    keep_report = json.loads((kept / "robustness.json").read_text())
    assert keep_report["image_boxes"] == "keep"
    assert keep_report["levels"]["clean"] == clean  # the rule only acts on the jitter
    assert "--image-boxes keep" in (kept / "robustness.md").read_text()

    plain = run_kitti(
        kitti_root=sample_kit, seqs=["0001"], classes=["car"], out=tmp_path / "plain", quiet=True
    )
    assert clean["runs"][0]["metrics"]["car"]["HOTA"] == plain["metrics"]["car"]["HOTA"]
    assert clean["summary"]["car"]["HOTA_mean"] == round(plain["metrics"]["car"]["HOTA"], 3)


def test_robustness_reads_each_label_file_once(
    sample_kit: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The labels are checked up front; every level and seed's evaluation re-read and re-checked
    each label file (once per job), though checked as strictly already."""
    import tracker.eval.kitti
    from app.robustness import run_robustness

    checked: list[Path] = []
    check_label_file = tracker.eval.kitti.check_label_file

    def counting(path: Path, *args: Any, **kwargs: Any) -> int:
        checked.append(path)
        return check_label_file(path, *args, **kwargs)

    monkeypatch.setattr(tracker.eval.kitti, "check_label_file", counting)
    report = run_robustness(
        kitti_root=sample_kit, seqs=["0001"], classes=["car"], levels=["noise"], seeds=[0, 1],
        out=tmp_path / "r", quiet=True,
    )  # fmt: skip
    assert [len(level["runs"]) for level in report["levels"].values()] == [1, 2]  # 3 evaluations
    assert checked == [sample_kit / "training" / "label_02" / "0001.txt"]


def test_robustness_calibrates_a_detector_without_a_profile_as_kitti_does(
    sample_kit: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """No shipped profile: fitted without labels on the run's detections, so the clean level
    scores what `mctrack kitti` scores; --profile none keeps the uncalibrated fallback."""
    from app.kitti import run_kitti
    from app.robustness import run_robustness

    kit = tmp_path / "kit"
    (kit / "detections").mkdir(parents=True)
    (kit / "training").symlink_to(sample_kit / "training")
    (kit / "detections" / "mydet").symlink_to(sample_kit / "detections" / "pointrcnn")
    common = {"kitti_root": kit, "seqs": ["0001"], "classes": ["car"], "detector": "mydet"}
    with caplog.at_level("WARNING"):
        report = run_robustness(**common, levels=["clean"], out=tmp_path / "r", quiet=True)
    assert "self-calibration of 'mydet'" in caplog.text
    assert report["score_calibration"].startswith("none for 'mydet': self-calibrated")
    plain = run_kitti(**common, out=tmp_path / "k", quiet=True)
    clean = report["levels"]["clean"]["runs"][0]["metrics"]["car"]["HOTA"]
    assert clean == plain["metrics"]["car"]["HOTA"]
    uncalibrated = run_robustness(
        **common, levels=["clean"], profile="none", out=tmp_path / "n", quiet=True
    )
    assert uncalibrated["score_calibration"].startswith("none (--profile none)")
    assert uncalibrated["levels"]["clean"]["runs"][0]["metrics"]["car"]["HOTA"] != clean


def test_robustness_warns_for_a_class_its_profile_has_no_map_for(
    sample_kit: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The car scores of a pedestrian-only profile fall back to sigmoid(raw): said loudly."""
    from app.robustness import run_robustness
    from tracker.calibration import find_profile, load_profile, profile_toml

    shipped = find_profile("pointrcnn")
    assert shipped is not None
    profile = tmp_path / "pedestrian_only.toml"
    pedestrian = {"pedestrian": shipped.maps["pedestrian"]}
    profile.write_text(profile_toml(dataclasses.replace(shipped, maps=pedestrian)))
    assert list(load_profile(profile).maps) == ["pedestrian"]
    with caplog.at_level("WARNING"):
        run_robustness(
            kitti_root=sample_kit, seqs=["0001"], classes=["car"], detector="pointrcnn",
            profile=profile, levels=["clean"], out=tmp_path / "r", quiet=True,
        )  # fmt: skip
    assert "NO SCORE CALIBRATION for the car boxes of detector 'pointrcnn'" in caplog.text


def test_robustness_warns_for_a_class_the_detector_has_no_box_of(
    sample_kit: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Its HOTA row is 0 because the detector has none, as `mctrack kitti` says too."""
    import shutil

    from app.robustness import run_robustness

    kit = tmp_path / "kit"  # the sample without its cyclist file: a car and pedestrian detector
    shutil.copytree(sample_kit, kit, ignore=shutil.ignore_patterns("Cyclist"))
    with caplog.at_level("WARNING"):
        run_robustness(
            kitti_root=kit, seqs=["0001"], classes=["car", "cyclist"], detector="pointrcnn",
            levels=["clean"], out=tmp_path / "r", quiet=True,
        )  # fmt: skip
    assert "detector 'pointrcnn' has no cyclist detections in these sequences" in caplog.text


def test_a_level_of_your_own(
    sample_kit: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--level NAME:...: run after --levels, recorded, and in the markdown's command line; the
    same noise as a built-in level gives the same figures."""
    from app.robustness import level_text, parse_level

    assert parse_level("j2:centre=0.3:yaw=5") == (
        "j2",
        PerturbSpec(centre_sigma_m=0.3, yaw_sigma_deg=5.0),
    )
    noise = dataclasses.asdict(NOISE_LEVELS["noise"])
    assert parse_level(level_text("mine", noise)) == ("mine", NOISE_LEVELS["noise"])
    odd = PerturbSpec(centre_sigma_m=0.1234567891, fp_rate=1 / 3)
    assert parse_level(level_text("odd", dataclasses.asdict(odd))) == ("odd", odd)

    out = tmp_path / "rob"
    args = ["--kitti-root", str(sample_kit), "--seqs", "0001", "--classes", "car", "--seeds", "0"]
    level = "mine:drop=0.1:centre=0.15:yaw=2:fp=0.02"  # the built-in noise level
    argv = ["robustness", *args, "--levels", "noise", "--level", level, "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    report = json.loads((out / "robustness.json").read_text())
    assert list(report["levels"]) == ["clean", "noise", "mine"]
    assert report["custom_levels"] == ["mine"]
    mine, builtin = report["levels"]["mine"], report["levels"]["noise"]
    assert mine["spec"] == builtin["spec"] and mine["runs"] == builtin["runs"]
    assert (out / "runs" / "mine" / "seed0" / "0001.txt").is_file()
    assert f"--levels noise --level {level} --seeds 0 " in (out / "robustness.md").read_text()


@pytest.mark.parametrize(
    ("level", "message"),
    [
        ("../up:drop=0.1", "the name must be"),
        ("a:drop=0.1:drop=0.2", "drop is given twice"),
        ("a:sigma=0.3", "'sigma=0.3' is not one of drop, centre, yaw, fp"),
        ("a:centre=far", "centre must be a number"),
        ("a:drop=1.5", "drop_rate: expected <= 1"),
        ("a:fp=-1", "fp_rate: expected a finite value >= 0"),
        ("Noise:drop=0.2", "already names a built-in level"),
        ("a:drop=0.1 --level A:drop=0.2", "a level named 'A' is given already"),
        # (each was accepted: a level the same as clean, under another name)
        ("x", "--level x: no noise (drop, centre, yaw and fp all 0, and --score-sigma 0)"),
        ("x:drop=0:fp=0", "--level x: no noise"),
    ],
)
def test_bad_levels_are_one_line_errors(
    sample_kit: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], level: str, message: str
) -> None:
    levels = [arg for text in level.split(" --level ") for arg in ("--level", text)]
    argv = ["robustness", "--kitti-root", str(sample_kit), "--seqs", "0001", *levels]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and "--level" in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--levels", "loud"], "unknown noise level"),
        (["--seeds", "0,x"], "--seeds"),
        (["--classes", "van"], "--classes"),
        (["--seqs", "0002"], "0002.txt"),
        (["--score-sigma", "-1"], "--score-sigma"),
        (["--detector", "nope"], "--detector"),
        (["--config", "nope"], "config not found"),
        (["--profile", "nope.toml"], "nope.toml"),
    ],
)
def test_robustness_bad_arguments_are_one_line_errors(
    sample_kit: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    message: str,
) -> None:
    """Refused before --out is made (it was left behind, empty, by most of these)."""
    argv = ["robustness", "--kitti-root", str(sample_kit), "--seqs", "0001", *extra]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and err.startswith("mctrack robustness")
    assert not (tmp_path / "out").exists()


def test_the_parts_of_noise_add_up_to_noise() -> None:
    """drop, jitter and fp are the noise level's perturbations one at a time."""
    parts = [NOISE_LEVELS[name] for name in ("drop", "jitter", "fp")]
    for field in dataclasses.fields(PerturbSpec):
        values = [getattr(p, field.name) for p in parts]
        assert sum(v != 0 for v in values) <= 1  # each kind in one part only
        assert max(values) == getattr(NOISE_LEVELS["noise"], field.name)


def test_the_recorded_command_repeats_the_run_and_a_rerun_replaces_it(
    sample_kit: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """robustness.md's command line carries every option that changes the result, quoted (a
    path with a space), and gives the same figures; a re-run into the same --out removes the
    earlier run's outputs (levels it leaves out included) and keeps other files."""
    import shlex

    kit = tmp_path / "my kit"
    kit.symlink_to(sample_kit)
    out = tmp_path / "rob out"
    argv = [
        "robustness", "--kitti-root", str(kit), "--seqs", "0001", "--classes", "car",
        "--levels", "drop", "--level", "mine:fp=0.05", "--seeds", "1", "--score-sigma", "0.5",
        "--profile", "none", "--image-boxes", "keep", "--out", str(out),
    ]  # fmt: skip
    assert main(argv) == 0
    first = json.loads((out / "robustness.json").read_text())
    command = shlex.split(first["command"])
    assert command == [
        "mctrack", "robustness", "--kitti-root", str(kit), "--detector", "pointrcnn",
        "--seqs", "0001", "--classes", "car", "--config", "kitti", "--levels", "drop",
        "--level", "mine:fp=0.05", "--seeds", "1", "--score-sigma", "0.5",
        "--image-boxes", "keep", "--profile", "none", "--out", str(out),
    ]  # fmt: skip
    assert f"Command: `{first['command']}`" in (out / "robustness.md").read_text()

    (out / "notes.txt").write_text("mine")
    (out / "runs" / "other").mkdir()
    (out / "runs" / "other" / "keep.txt").write_text("mine")
    assert main(command[1:]) == 0  # the recorded line, as a shell would split it
    again = json.loads((out / "robustness.json").read_text())
    assert again["levels"] == first["levels"] and again["command"] == first["command"]

    clean_only = ["robustness", "--kitti-root", str(kit), "--seqs", "0001", "--classes", "car"]
    assert main([*clean_only, "--levels", "clean", "--seeds", "1", "--out", str(out)]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["clean", "other"]
    assert (out / "runs" / "clean" / "clean" / "0001.txt").is_file()
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "runs" / "other" / "keep.txt").read_text() == "mine"


def test_robustness_out_an_existing_file_is_refused_before_any_work(
    sample_kit: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    argv = ["robustness", "--kitti-root", str(sample_kit), "--seqs", "0001", "--classes", "car"]
    assert main([*argv, "--levels", "clean", "--out", str(afile)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"mctrack robustness: error: --out {afile}: exists and is not a folder", err
