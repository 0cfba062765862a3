"""`mctrack convert nuscenes`, `mctrack nuscenes` and `mctrack eval --dataset nuscenes` on the
synthetic dataset (tests/test_nuscenes_fixture.py)."""

from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from app.cli import main
from tests.test_nuscenes import NOISY, _devkit_missing, _edited_dataset, _set_annotation
from tests.test_nuscenes_fixture import (
    SyntheticNuScenes,
    make_detections,
    token,
    write_synthetic_nuscenes,
)
from tracker.categories import category_index
from tracker.io.baseversion import read_baseversion
from tracker.io.writers import read_tracks_file

pytestmark = pytest.mark.skipif(_devkit_missing() is not None, reason=str(_devkit_missing()))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> SyntheticNuScenes:
    return write_synthetic_nuscenes(tmp_path_factory.mktemp("nuscenes_cli"))


@pytest.fixture(scope="module")
def noisy(dataset: SyntheticNuScenes) -> Path:
    path = dataset.dataroot / "noisy.json"
    path.write_text(json.dumps(make_detections(dataset, seed=11, **NOISY)))
    return path


def _common(data: SyntheticNuScenes) -> list[str]:
    return ["--dataroot", str(data.dataroot), "--version", data.version, "--split", "mini_val"]


def test_convert_nuscenes_cli(dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path) -> None:
    out, gt = tmp_path / "dets.json", tmp_path / "gt.json.gz"
    argv = ["convert", "nuscenes", *_common(dataset), "--detections", str(noisy)]
    assert main([*argv, "--out", str(out), "--gt-out", str(gt)]) == 0
    dets, truth = read_baseversion(out), read_baseversion(gt)
    assert sorted(dets) == sorted(truth) == ["scene-0103", "scene-0916"]
    frame = truth["scene-0103"][0]
    assert len(frame.boxes) == 10 and frame.sample_token == dataset.samples["scene-0103"][0]
    assert len(frame.cameras) == 6 and (frame.boxes.camera >= 0).any()


def test_convert_nuscenes_cli_names_the_bad_token(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = json.loads(noisy.read_text())
    outside = dataset.samples["scene-0061"][0]
    data["results"][outside] = []
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    argv = ["convert", "nuscenes", *_common(dataset), "--detections", str(bad)]
    assert main([*argv, "--out", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err
    assert outside in err and "scene-0061" in err and "mini_val" in err


def test_nuscenes_end_to_end_and_eval(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    argv = ["nuscenes", *_common(dataset), "--detections", str(noisy), "--motion"]
    assert main([*argv, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    amota = summary["metrics"]["overall"]["amota"]
    assert 0.5 < amota < 0.99
    assert summary["frames"] == 32 and summary["boxes_written"] > 0
    assert isinstance(summary["motion"], dict)
    assert (out / "motion.md").is_file() and (out / "gt.json").is_file()
    frames, _ = read_tracks_file(out / "tracks.json")
    assert frames["scene-0103"][0].sample_token == dataset.samples["scene-0103"][0]

    # the same numbers from the tracks file and from the submission itself
    common = [*_common(dataset), "--dataset", "nuscenes"]
    assert main(["eval", str(out / "tracks.json"), *common, "--out", str(tmp_path / "e1")]) == 0
    again = json.loads((tmp_path / "e1" / "eval.json").read_text())
    assert again["static"]["overall"]["amota"] == pytest.approx(amota)
    assert main(["eval", str(out / "results.json"), *common, "--out", str(tmp_path / "e2")]) == 0
    direct = json.loads((tmp_path / "e2" / "eval.json").read_text())
    assert direct["static"]["overall"]["amota"] == pytest.approx(amota)
    assert "AMOTA" in (tmp_path / "e2" / "eval.md").read_text()

    # with --motion the motion metrics are printed too, as for KITTI (they were only in eval.md)
    capsys.readouterr()
    motion = ["--motion", "--gt", str(out / "gt.json"), "--out", str(tmp_path / "e3")]
    assert main(["eval", str(out / "tracks.json"), *common, *motion]) == 0
    printed = capsys.readouterr().out
    kalman = json.loads((tmp_path / "e3" / "eval.json").read_text())["motion"]["metrics"]["kalman"]
    assert "AMOTA" in printed and "motion (all)" in printed
    assert f"{kalman['all']['vae_deg']:>11.3f}" in printed.split("kalman", 1)[1].splitlines()[0]


def test_a_run_that_tracks_nothing_is_not_evaluated_and_says_why(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """No detection kept (every sample's list empty): mctrack nuscenes, then mctrack eval of its
    tracks file and of its submission, say the evaluation is skipped, exit 0 (the devkit's
    TrackingEval stopped on the empty submission: 'unexpected error: Invalid box type: None')."""
    from tracker.eval.nuscenes import NO_BOXES_NOTE

    data = json.loads(noisy.read_text())
    data["results"] = {sample: [] for sample in data["results"]}
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps(data))
    out = tmp_path / "run"
    argv = ["nuscenes", *_common(dataset), "--detections", str(empty), "--motion"]
    assert main([*argv, "--out", str(out)]) == 0
    said = capsys.readouterr()
    assert NO_BOXES_NOTE in said.out and "unexpected" not in said.err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["boxes_written"] == 0 and summary["evaluation"] == NO_BOXES_NOTE
    assert "metrics" not in summary and isinstance(summary["motion"], dict)
    common = [*_common(dataset), "--dataset", "nuscenes"]
    for i, path in enumerate((out / "tracks.json", out / "results.json")):
        assert main(["eval", str(path), *common, "--out", str(tmp_path / f"e{i}")]) == 0
        said = capsys.readouterr()
        assert NO_BOXES_NOTE in said.out and "unexpected" not in said.err
        assert json.loads((tmp_path / f"e{i}" / "eval.json").read_text())["static"] == NO_BOXES_NOTE
        assert NO_BOXES_NOTE in (tmp_path / f"e{i}" / "eval.md").read_text()


def test_nuscenes_record(dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path) -> None:
    pytest.importorskip("rerun")
    out = tmp_path / "rec"
    argv = ["nuscenes", *_common(dataset), "--detections", str(noisy), "--record"]
    assert main([*argv, "--scenes", "scene-0916", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["evaluation"].startswith("skipped: --scenes")
    rrd = out / "recordings" / "scene-0916.rrd"
    assert rrd.is_file() and rrd.stat().st_size > 10_000


def test_nuscenes_with_workers_gives_the_sequential_files(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path
) -> None:
    argv = ["nuscenes", *_common(dataset), "--detections", str(noisy), "--no-eval", "--motion"]
    runs = {}
    for workers in ("1", "2"):
        out = tmp_path / workers
        assert main([*argv, "--workers", workers, "--out", str(out)]) == 0
        summary = json.loads((out / "summary.json").read_text())
        files = {n: (out / n).read_bytes() for n in ("results.json", "tracks.json", "gt.json")}
        motion = {k: v for k, v in summary["motion"].items() if k != "plot"}  # path differs
        runs[workers] = (files, motion, summary["boxes_written"])
    assert runs["2"] == runs["1"]
    assert list(json.loads(runs["2"][0]["tracks.json"])) == ["scene-0103", "scene-0916"]


def test_nuscenes_run_into_an_earlier_run_replaces_it(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path
) -> None:
    """A second run into the same --out leaves only its own outputs: an earlier run's metrics
    and motion metrics went with it (they stayed beside a --no-eval run's submission); a run
    refused on its inputs keeps the earlier one, and files of other names stay."""
    out = tmp_path / "run"
    argv = ["nuscenes", *_common(dataset), "--detections", str(noisy), "--out", str(out)]
    assert main([*argv, "--motion"]) == 0
    (out / "notes.txt").write_text("mine")
    earlier = ("eval/metrics_summary.json", "gt.json", "motion.md", "motion_velocity.png")
    assert all((out / name).is_file() for name in earlier)
    assert main([*argv, "--no-eval", "--scenes", "scene-9999"]) == 2  # refused
    assert all((out / name).is_file() for name in earlier)
    assert main([*argv, "--no-eval"]) == 0
    assert not any((out / name).exists() for name in earlier)
    assert (out / "results.json").is_file() and (out / "notes.txt").read_text() == "mine"


def test_nuscenes_into_a_run_cut_short_refuses_recordings_it_does_not_write(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run killed mid-way leaves its scene parts and recordings, no summary.json saying whose
    they are: a new run kept them all (beside its own, or in place of none). Now a recording
    the run does not write is refused, named: before any work (without --record, or with
    --scenes), else once the split's scenes are known; the run's own are replaced."""
    pytest.importorskip("rerun")
    out = tmp_path / "run"
    (out / ".scenes").mkdir(parents=True)
    (out / "recordings").mkdir()
    for name in ("scene-0103", "mine"):
        (out / "recordings" / f"{name}.rrd").write_text("earlier\n")
    argv = ["nuscenes", *_common(dataset), "--detections", str(noisy), "--no-eval"]
    refused = f": {out} holds an earlier run, and it was cut short"
    for extra, named in (
        ([], "mine.rrd (and 1 more)"),  # (without --record none is its own)
        (["--record", "--scenes", "scene-0916"], "mine.rrd (and 1 more)"),
        (["--record"], "mine.rrd"),  # (scene-0103's is its own)
    ):
        capsys.readouterr()
        assert main([*argv, *extra, "--out", str(out)]) == 2, extra
        assert f"{out / 'recordings' / named}{refused}" in capsys.readouterr().err, extra
        assert sorted(p.name for p in (out / "recordings").iterdir()) == [
            "mine.rrd", "scene-0103.rrd"
        ]  # fmt: skip
    (out / "recordings" / "mine.rrd").unlink()
    assert main([*argv, "--record", "--scenes", "scene-0103", "--out", str(out)]) == 0
    assert (out / "recordings" / "scene-0103.rrd").stat().st_size > 10_000


@pytest.mark.parametrize(
    ("refusal", "said"),
    [("format check", "rejected by the nuScenes devkit"), ("evaluation", "nuScenes TrackingEval")],
)
def test_nuscenes_refused_after_the_tracking_leaves_no_partial_outputs(
    dataset: SyntheticNuScenes,
    noisy: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    refusal: str,
    said: str,
) -> None:
    """The devkit refusing the submission after the tracking (its format check, or its
    evaluation: an AssertionError, exit 2) into an earlier run's --out: the run's own outputs
    go too (results.json, tracks.json and the recordings were left without the summary.json
    that marks a complete run, the earlier run's outputs already removed); files of other names
    stay. Into a new --out: nothing is left."""
    pytest.importorskip("rerun")
    import nuscenes.eval.common.loaders as loaders
    import nuscenes.eval.tracking.evaluate as evaluate

    out = tmp_path / "run"
    argv = ["nuscenes", *_common(dataset), "--detections", str(noisy)]
    assert main([*argv, "--no-eval", "--motion", "--out", str(out)]) == 0
    (out / "notes.txt").write_text("mine")

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("Error: Only <= 500 boxes per sample allowed!")

    if refusal == "format check":  # (load_results_with_devkit's; TrackingEval has its own)
        monkeypatch.setattr(loaders, "load_prediction", refuse)
    else:
        monkeypatch.setattr(evaluate.TrackingEval, "evaluate", refuse)
    capsys.readouterr()
    assert main([*argv, "--record", "--out", str(out)]) == 2
    assert said in capsys.readouterr().err
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == ["notes.txt"]
    new = tmp_path / "new"
    assert main([*argv, "--record", "--out", str(new / "out")]) == 2
    assert not new.exists()


def test_eval_names_a_file_that_is_not_a_tracking_submission(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """mctrack eval --dataset nuscenes of a detection results file (no tracking_id) or of a
    truncated submission: one line naming the file (was 'unexpected error: KeyError', or
    'malformed JSON' without the file)."""
    truncated = tmp_path / "results.json"
    truncated.write_text(noisy.read_text()[:3000])
    common = [*_common(dataset), "--dataset", "nuscenes", "--out", str(tmp_path / "e")]
    for path, said in ((noisy, "a box has no field 'tracking_id'"), (truncated, "malformed JSON")):
        assert main(["eval", str(path), *common]) == 2
        err = capsys.readouterr().err
        assert f"error: {path}: {said}" in err and "unexpected" not in err


def test_eval_refused_leaves_no_output_of_its_own(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """mctrack eval --dataset nuscenes refused by the devkit (here: a tracks file of one scene
    of the split) removes what it created (the folder, eval_results.json, nuscenes_eval/: they were
    left half-written); files that were there before stay."""
    run = tmp_path / "run"
    argv = ["nuscenes", *_common(dataset), "--detections", str(noisy), "--no-eval"]
    assert main([*argv, "--scenes", "scene-0916", "--out", str(run)]) == 0
    common = [*_common(dataset), "--dataset", "nuscenes"]
    new = tmp_path / "new"
    assert main(["eval", str(run / "tracks.json"), *common, "--out", str(new)]) == 2
    assert "nuScenes TrackingEval" in capsys.readouterr().err
    assert not new.exists()
    before = sorted(p.relative_to(run).as_posix() for p in run.rglob("*"))
    assert main(["eval", str(run / "tracks.json"), *common]) == 2  # --out: the tracks' folder
    assert sorted(p.relative_to(run).as_posix() for p in run.rglob("*")) == before
    assert "results.json" in before and "nuscenes_eval" not in before


def test_eval_of_a_tracks_file_leaves_the_runs_submission_as_it_is(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """mctrack eval TRACKS --dataset nuscenes writes TRACKS' submission as OUT/eval_results.json,
    OUT by default the run's own folder: the run's results.json (with its detections' meta)
    stays byte for byte (it was overwritten with the default meta, also when refused)."""
    run = tmp_path / "run"
    argv = ["nuscenes", *_common(dataset), "--detections", str(noisy), "--no-eval"]
    assert main([*argv, "--out", str(run)]) == 0
    submission = json.loads((run / "results.json").read_text())
    submission["meta"]["use_camera"] = True  # as a camera detector's run writes it
    (run / "results.json").write_text(json.dumps(submission))
    before = (run / "results.json").read_bytes()
    common = [*_common(dataset), "--dataset", "nuscenes"]
    assert main(["eval", str(run / "tracks.json"), *common]) == 0
    assert (run / "results.json").read_bytes() == before
    evaluated = json.loads((run / "eval.json").read_text())["results"]
    assert evaluated == str(run / "eval_results.json") and Path(evaluated).is_file()


def test_nuscenes_refuses_detections_it_would_overwrite(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--detections OUT/results.json --out OUT: the run would delete (an earlier run's outputs go
    first) or overwrite the file it reads; refused before any work, the file kept (it was
    deleted)."""
    out = tmp_path / "run"
    out.mkdir()
    detections = out / "results.json"
    shutil.copy(noisy, detections)
    before = detections.read_bytes()
    argv = ["nuscenes", *_common(dataset), "--detections", str(detections), "--no-eval"]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{detections}: --detections is a file this run writes in {out}" in err
    assert detections.read_bytes() == before and sorted(out.iterdir()) == [detections]


FAR = "beyond ±1e+08 m (farther or larger than anything on Earth)"


@pytest.mark.parametrize(
    ("fields", "said"),
    [
        ({"translation": [1.0, float("nan"), 0.8]}, "'translation' must be 3 finite numbers"),
        ({"rotation": [0.0, 0.0, 0.0, 0.0]}, "'rotation' is the zero quaternion (no heading)"),
        ({"translation": [1.0, 2.0]}, "'translation' must be 3 finite numbers"),
        ({"size": [1.9, 1e300, 1.6]}, f"'size' = [1.9, 1e+300, 1.6]: {FAR}"),
    ],
    ids=["nan_translation", "zero_rotation", "short_translation", "far_size"],
)
def test_a_bad_ground_truth_annotation_is_one_error_line(
    dataset: SyntheticNuScenes,
    noisy: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    fields: dict[str, Any],
    said: str,
) -> None:
    """A tracked sample_annotation with a NaN translation or a zero quaternion: `mctrack convert
    nuscenes --gt-out` and `mctrack nuscenes` (its evaluation reads the annotations) stop with
    one line naming the table, the annotation and the field, writing nothing (convert wrote the
    detections, then failed with 'unexpected error'; the evaluation blamed its results.json for
    the NaN, and took the zero quaternion). A run that reads no annotation is not refused.
    `mctrack eval --dataset nuscenes` checks them the same way before the devkit reads them, of a
    tracks file or a submission, writing nothing (it handed them to the devkit: a traceback for a
    short translation, the results file blamed for a NaN, a size of 1e300 scored)."""
    ann_token = token("ann", "scene-0916", 4, 0)  # object 0, a car, in sample 4

    def edit(tables: dict[str, list[Any]]) -> None:
        next(a for a in tables["sample_annotation"] if a["token"] == ann_token).update(fields)

    root = _edited_dataset(dataset, tmp_path / "data", edit)
    table = root / dataset.version / "sample_annotation.json"
    sample = token("sample", "scene-0916", 4)
    line = f"error: {table}: sample_annotation '{ann_token}' of sample '{sample}': field {said}"
    common = ["--dataroot", str(root), "--version", dataset.version, "--split", "mini_val"]
    out, gt = tmp_path / "dets.json", tmp_path / "gt.json"
    argv = ["convert", "nuscenes", *common, "--detections", str(noisy), "--out", str(out)]
    assert main([*argv, "--gt-out", str(gt)]) == 2
    assert capsys.readouterr().err.splitlines() == [f"mctrack convert: {line}"]
    assert not out.exists() and not gt.exists()
    run = ["nuscenes", *common, "--detections", str(noisy), "--out", str(tmp_path / "run")]
    assert main(run) == 2
    assert capsys.readouterr().err.splitlines() == [f"mctrack nuscenes: {line}"]
    assert not any((tmp_path / "run").glob("*"))  # the folder is made before any work
    assert main([*argv]) == 0  # the detections alone
    assert main([*run, "--no-eval"]) == 0
    capsys.readouterr()
    for tracks in ("tracks.json", "results.json"):
        evaluated = tmp_path / "eval"
        argv = ["eval", str(tmp_path / "run" / tracks), "--dataset", "nuscenes", *common]
        assert main([*argv, "--out", str(evaluated)]) == 2
        assert capsys.readouterr().err.splitlines() == [f"mctrack eval: {line}"], tracks
        assert not evaluated.exists()


def test_an_unknown_ground_truth_velocity_stays_unknown_and_is_counted(
    dataset: SyntheticNuScenes, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """An annotation whose devkit velocity is NaN (annotated once: no prev, no next) is kept
    unknown: null in --gt-out and gt.json, logged, and its motion sample left out of the
    velocity metrics with its count in summary.json and motion.md (it was written as [0, 0]
    and scored as a measured standstill of a car driving 8 m/s)."""
    ann_token = token("ann", "scene-0916", 4, 0)  # object 0, a car, in sample 4
    root = _edited_dataset(
        dataset,
        tmp_path / "data",
        lambda tables: _set_annotation(tables, ann_token, prev="", next=""),
    )
    clean = tmp_path / "clean.json"
    clean.write_text(json.dumps(make_detections(dataset, seed=1)))
    common = ["--dataroot", str(root), "--version", dataset.version, "--split", "mini_val"]
    gt_out = tmp_path / "gt.json"
    argv = ["convert", "nuscenes", *common, "--detections", str(clean)]
    with caplog.at_level("INFO"):
        assert main([*argv, "--out", str(tmp_path / "dets.json"), "--gt-out", str(gt_out)]) == 0
    assert "1 ground-truth boxes have no velocity (the devkit's NaN" in caplog.text

    def unknown(path: Path) -> list[tuple[str, int]]:
        scenes = json.loads(path.read_text())
        return [
            (scene, f["frame_id"])
            for scene, frames in scenes.items()
            for f in frames
            for b in f["bboxes"]
            if b["global_velocity"] is None
        ]

    assert unknown(gt_out) == [("scene-0916", 4)]
    out = tmp_path / "run"
    run = ["nuscenes", *common, "--detections", str(clean), "--motion", "--no-eval"]
    assert main([*run, "--out", str(out)]) == 0
    assert unknown(out / "gt.json") == [("scene-0916", 4)]
    motion = json.loads((out / "summary.json").read_text())["motion"]
    assert motion["counts"]["car"]["gt_velocity_unknown"] == 1
    for estimator, rows in motion["metrics"].items():
        assert rows["car"]["n_gt_velocity_unknown"] == 1, estimator
        assert rows["all"]["n_gt_velocity_unknown"] == 1, estimator
    car = motion["metrics"]["kalman"]["car"]
    assert car["n_samples"] + car["n_dropped_samples"] == motion["counts"]["car"]["samples"] - 1
    report = (out / "motion.md").read_text()
    assert "Samples whose GT velocity is unknown, left out of the velocity metrics: 1." in report


def test_eval_frees_its_check_of_the_annotations_before_the_devkit_loads_them(
    dataset: SyntheticNuScenes, monkeypatch: pytest.MonkeyPatch
) -> None:
    """eval --dataset nuscenes checks the annotations on its own copy of the tables (several GB
    on trainval), then the devkit loads another: the first must be gone by then. The devkit's
    NuScenes and its explorer refer to each other, so dropping the name did not free it (only
    a full collection does, which may not come before the second load)."""
    import argparse
    import gc
    import weakref

    import tracker.io.convert.nuscenes as convert
    from app.eval import _check_nuscenes_ground_truth

    loaded: list[weakref.ref] = []
    real_load = convert.load_nuscenes

    def load(*args: Any, **kwargs: Any) -> Any:
        nusc = real_load(*args, **kwargs)
        loaded.append(weakref.ref(nusc))
        return nusc

    monkeypatch.setattr(convert, "load_nuscenes", load)
    args = argparse.Namespace(
        dataroot=str(dataset.dataroot), version=dataset.version, split="mini_val"
    )
    gc.disable()
    try:
        _check_nuscenes_ground_truth(args)
        assert len(loaded) == 1 and loaded[0]() is None
    finally:
        gc.enable()


def test_a_detection_name_of_no_nuscenes_class_is_counted_apart_and_warned(
    dataset: SyntheticNuScenes,
    noisy: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """'Car', 'vehicle.car' or 'spaceship' is no nuScenes class: dropped, but counted apart from
    the non-tracking classes and warned about with the file (was silently counted as one, e.g.
    'Car': 90 then 0 boxes); the non-tracking count is said once (was also printed)."""
    data = json.loads(noisy.read_text())
    renamed = Counter()
    for boxes in data["results"].values():
        for box in boxes:
            if box["detection_name"] == "car":
                box["detection_name"] = "Car"
                renamed["Car"] += 1
        boxes.append({**boxes[0], "detection_name": "spaceship"})
        renamed["spaceship"] += 1
    path = tmp_path / "misspelt.json"
    path.write_text(json.dumps(data))
    argv = ["convert", "nuscenes", *_common(dataset), "--detections", str(path)]
    with caplog.at_level("INFO"):
        assert main([*argv, "--out", str(tmp_path / "x.json")]) == 0
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    said = f"{sum(renamed.values())} detections with a detection_name that is no nuScenes class"
    assert [w for w in warnings if said in w] == [
        f"{path}: {said} dropped: {dict(renamed.most_common())} (a misspelt class? the classes "
        "are barrier, bicycle, bus, car, construction_vehicle, motorcycle, pedestrian, "
        "traffic_cone, trailer, truck)"
    ]
    skips = [r.getMessage() for r in caplog.records if "non-tracking" in r.getMessage()]
    assert len(skips) == 1 and "'barrier'" in skips[0] and "Car" not in skips[0]
    assert "non-tracking" not in capsys.readouterr().out
    frames = read_baseversion(tmp_path / "x.json")["scene-0103"]
    assert category_index("car") not in {int(c) for f in frames for c in f.boxes.category}


@pytest.mark.parametrize("value", ["2", "nan", "-1", "x"])
@pytest.mark.parametrize("command", [["convert", "nuscenes"], ["nuscenes"]])
def test_score_min_outside_0_1_is_a_usage_error(
    dataset: SyntheticNuScenes,
    noisy: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: list[str],
    value: str,
) -> None:
    """--score-min 2 gave 0 boxes without a word, nan and -1 filtered nothing: refused."""
    out = tmp_path / "out.json"
    argv = [*command, *_common(dataset), "--detections", str(noisy), "--out", str(out)]
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--score-min", value])
    assert exit_.value.code == 2 and not out.exists()
    assert f"argument --score-min: expected a number in [0, 1], got '{value}'" in (
        capsys.readouterr().err
    )


def test_score_min_counts_what_it_drops_and_help_shows_its_default(
    dataset: SyntheticNuScenes,
    noisy: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    data = json.loads(noisy.read_text())
    tracked = {"bicycle", "bus", "car", "motorcycle", "pedestrian", "trailer", "truck"}
    scores = [b["detection_score"] for v in data["results"].values() for b in v
              if b["detection_name"] in tracked]  # fmt: skip
    below = sum(s < 0.6 for s in scores)
    assert 0 < below < len(scores)
    out = tmp_path / "x.json"
    argv = ["convert", "nuscenes", *_common(dataset), "--detections", str(noisy), "--out", str(out)]
    with caplog.at_level("INFO"):
        assert main([*argv, "--score-min", "0.6"]) == 0
    said = f"{noisy}: {below} detections scoring below 0.6 (score_min) dropped, "
    assert [r.levelname for r in caplog.records if said in r.getMessage()] == ["INFO"]
    assert (
        sum(len(f.boxes) for s in read_baseversion(out).values() for f in s) == len(scores) - below
    )
    caplog.clear()
    with caplog.at_level("INFO"):  # all dropped: a warning
        assert main([*argv, "--score-min", "1"]) == 0
    assert any(
        r.levelname == "WARNING" and f"{len(scores)} detections scoring below 1" in r.getMessage()
        for r in caplog.records
    )
    capsys.readouterr()
    for command in (["convert", "nuscenes"], ["nuscenes"]):
        with pytest.raises(SystemExit):
            main([*command, "--help"])
        assert "(default: 0: keep all)" in " ".join(capsys.readouterr().out.split())


def test_a_runs_summary_counts_the_detections_its_conversion_dropped(
    dataset: SyntheticNuScenes, noisy: Path, tmp_path: Path
) -> None:
    """summary.json held the non-tracking classes' count only: the names of no nuScenes class
    and the boxes below --score-min, dropped too, were said on the log alone."""
    data = json.loads(noisy.read_text())
    for boxes in data["results"].values():
        boxes.append({**boxes[0], "detection_name": "spaceship"})
    path = tmp_path / "misspelt.json"
    path.write_text(json.dumps(data))
    scores = [b["detection_score"] for bs in data["results"].values() for b in bs]
    argv = ["nuscenes", *_common(dataset), "--detections", str(path), "--no-eval"]
    assert main([*argv, "--score-min", "0.3", "--out", str(tmp_path / "run")]) == 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    spaceships = len(data["results"])
    assert summary["unknown_detections"] == {"spaceship": spaceships}
    tracked = {"bicycle", "bus", "car", "motorcycle", "pedestrian", "trailer", "truck"}
    below = [b["detection_score"] < 0.3 for bs in data["results"].values() for b in bs]
    names = [b["detection_name"] for bs in data["results"].values() for b in bs]
    expected = sum(low and name in tracked for low, name in zip(below, names, strict=True))
    assert 0 < summary["below_score_min"] == expected < len(scores)
