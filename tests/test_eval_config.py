"""`mctrack eval` writes the KITTI 2D boxes with the config the tracks were made with: by
default the run's, read from the summary.json beside its tracks.json (it scored the tracks of a
`kitti_reference` run with the `kitti` config, another pedestrian HOTA, without a word)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from app.cli import main

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "kitti-0001"
LABELS = SAMPLE / "raw" / "training" / "label_02"


def _eval(tracks: Path, gt: Path, labels: Path, out: Path, *extra: str) -> int:
    argv = ["eval", str(tracks), "--gt", str(gt), "--labels", str(labels), "--out", str(out)]
    return main([*argv, *extra])


def _pedestrian_hota(out: Path) -> float:
    return json.loads((out / "eval.json").read_text())["static"]["pedestrian"]["HOTA"]


def test_eval_uses_the_config_of_the_track_run_beside_the_tracks(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A `mctrack track --config kitti_reference` run: eval scores its tracks with
    kitti_reference and says so; --config kitti scores them otherwise, with a warning."""
    run = tmp_path / "run"
    argv = ["track", str(SAMPLE / "detections.json.gz"), "--config", "kitti_reference"]
    assert main([*argv, "--out", str(run)]) == 0
    tracks, gt = run / "tracks.json", SAMPLE / "gt.json.gz"
    capsys.readouterr()
    hota = {}
    for name, extra in (("default", ()), ("reference", ("--config", "kitti_reference"))):
        assert _eval(tracks, gt, LABELS, tmp_path / name, *extra) == 0
        hota[name] = _pedestrian_hota(tmp_path / name)
        out, err = capsys.readouterr()
        assert "not the config the tracks were made with" not in err
    assert hota["default"] == hota["reference"]
    assert out.splitlines()[0] == "config kitti_reference"
    assert json.loads((tmp_path / "default" / "eval.json").read_text())["config"] == (
        "kitti_reference"
    )
    assert _eval(tracks, gt, LABELS, tmp_path / "default", "--config", "kitti") == 0
    out, err = capsys.readouterr()
    assert abs(_pedestrian_hota(tmp_path / "default") - hota["default"]) > 1.0
    assert (
        "mctrack eval: --config kitti is not the config the tracks were made with "
        f"(kitti_reference, {run / 'summary.json'})"
    ) in err
    # the default names the run's config: the line before the table
    assert _eval(tracks, gt, LABELS, tmp_path / "again") == 0
    out = capsys.readouterr().out
    assert f"config kitti_reference (the run's: {run / 'summary.json'})" in out.splitlines()
    # a tracks file that is no run's (a copy elsewhere): the kitti default, said
    alone = tmp_path / "alone" / "tracks.json"
    alone.parent.mkdir()
    alone.write_bytes(tracks.read_bytes())
    assert _eval(alone, gt, LABELS, tmp_path / "alone") == 0
    assert capsys.readouterr().out.startswith("config kitti (the default:")
    assert abs(_pedestrian_hota(tmp_path / "alone") - hota["default"]) > 1.0


def test_eval_reproduces_a_track_run_whose_config_file_is_elsewhere_or_gone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """`track --config mine.toml`, then eval from another folder: the summary named the file
    as typed, and eval looked it up from its own folder: refused ("gone") though it was there,
    or another folder's mine.toml silently used. The run's settings are recorded now."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "mine.toml").write_text('base = "kitti_reference"\n')
    (tmp_path / "b" / "mine.toml").write_text('base = "kitti"\n')  # (another file, same name)
    monkeypatch.chdir(tmp_path / "a")
    argv = ["track", str(SAMPLE / "detections.json.gz"), "--config", "mine.toml"]
    assert main([*argv, "--out", "run"]) == 0
    run = tmp_path / "a" / "run"
    tracks, gt = run / "tracks.json", SAMPLE / "gt.json.gz"
    assert _eval(tracks, gt, LABELS, tmp_path / "as_run", "--config", "kitti_reference") == 0
    monkeypatch.chdir(tmp_path / "b")
    (tmp_path / "a" / "mine.toml").unlink()
    capsys.readouterr()
    assert _eval(tracks, gt, LABELS, tmp_path / "e") == 0
    out, err = capsys.readouterr()
    assert _pedestrian_hota(tmp_path / "e") == _pedestrian_hota(tmp_path / "as_run")
    assert out.splitlines()[0] == f"config mine.toml (the run's: {run / 'summary.json'})"
    assert "not the config the tracks were made with" not in err


def test_eval_of_a_kitti_run_scores_what_the_run_scored(
    real_runs, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The tracks of a real `mctrack kitti --config kitti_reference` run (0016): eval's default
    gives the run's pedestrian HOTA, from the config its summary recorded; `kitti` another
    (on the 11 validation sequences: 42.247 as the run, 46.263 with kitti)."""
    root, ref, _ = real_runs
    run = root / "reference"
    assert ref["config_name"] == "kitti_reference"
    conv = tmp_path / "conv"
    argv = ["convert", "kitti", "--kitti-root", ref["kitti_root"], "--seqs", "0016"]
    assert main([*argv, "--out", str(conv)]) == 0
    labels = Path(ref["labels"])
    assert _eval(run / "tracks.json", conv / "gt.json", labels, tmp_path / "e") == 0
    assert _pedestrian_hota(tmp_path / "e") == pytest.approx(
        ref["metrics"]["pedestrian"]["HOTA"], abs=1e-3
    )
    assert f"config kitti_reference (the run's: {run / 'summary.json'})" in capsys.readouterr().out
    args = ("--config", "kitti")
    assert _eval(run / "tracks.json", conv / "gt.json", labels, tmp_path / "k", *args) == 0
    kitti = _pedestrian_hota(tmp_path / "k")
    assert abs(kitti - ref["metrics"]["pedestrian"]["HOTA"]) > 1.0


def test_eval_warns_of_another_config_only_where_it_writes_other_boxes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The warning compared every setting: a run whose config differs from --config in a gate
    alone (the same 2D boxes) was warned of too; kitti_reference writes other boxes."""
    mine = tmp_path / "mine.toml"
    mine.write_text('base = "kitti"\n[category.car]\nscore_min = 0.4\n')
    run = tmp_path / "run"
    argv = ["track", str(SAMPLE / "detections.json.gz"), "--frames", "0:40"]
    assert main([*argv, "--config", str(mine), "--out", str(run)]) == 0
    capsys.readouterr()
    tracks, gt = run / "tracks.json", SAMPLE / "gt.json.gz"
    warning = "is not the config the tracks were made with"
    for given, warned in (("kitti", False), ("kitti_reference", True)):
        assert _eval(tracks, gt, LABELS, tmp_path / given, "--config", given) == 0
        assert (warning in capsys.readouterr().err) is warned, given
