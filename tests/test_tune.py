"""`mctrack tune`'s pieces: the noise levels of the objective, the objective, and the mapping
from searched values to config overrides (the search itself runs on real data: docs/tune/)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from app.cli import main
from app.tune import (
    CAR_SPACE,
    ONLINE_SPACE,
    _current,
    base_level,
    draw_levels,
    level_frames,
    noise_levels,
    objective_value,
    parse_search,
    record_seeds,
    search_space,
    settings_to_overrides,
    with_searched,
)
from tests.cli_output import without_kernel_lines
from tracker.config import load_config
from tracker.errors import InputError


def test_noise_levels_parse_and_reject_unknown_names() -> None:
    assert noise_levels("noise") == ["noise"]
    assert noise_levels("noise, double,noise") == ["noise", "double"]
    assert noise_levels("none") == [] and noise_levels("clean") == [] and noise_levels("") == []
    with pytest.raises(InputError, match="loud"):
        noise_levels("noise,loud")


def test_objective_averages_hota_over_every_detector_and_level() -> None:
    metrics = {
        ("a", "clean"): {"HOTA": 80.0},
        ("a", "noise"): {"HOTA": 70.0},
        ("b", "clean"): {"HOTA": 60.0},
        ("b", "noise"): {"HOTA": 30.0},
    }
    assert objective_value(metrics) == pytest.approx(60.0)


def test_the_objective_averages_a_levels_draws_before_the_levels() -> None:
    """Three draws of the noise estimate the same objective as one, with less spread: the noisy
    level keeps its weight beside the clean one."""
    assert draw_levels(["clean", "noise"], [0]) == ["clean", "noise"]
    runs = draw_levels(["clean", "noise", "double"], [0, 7])
    assert runs == ["clean", "noise@0", "noise@7", "double@0", "double@7"]
    assert [base_level(r) for r in runs] == ["clean", "noise", "noise", "double", "double"]
    metrics = {
        ("a", "clean"): {"HOTA": 80.0},
        ("a", "noise@0"): {"HOTA": 70.0},
        ("a", "noise@7"): {"HOTA": 60.0},
        ("b", "clean"): {"HOTA": 60.0},
        ("b", "noise@0"): {"HOTA": 30.0},
        ("b", "noise@7"): {"HOTA": 40.0},
    }
    # (80 + 65 + 60 + 35) / 4, not the mean of the six runs (56.67)
    assert objective_value(metrics) == pytest.approx(60.0)
    assert record_seeds({"noise_seed": 0}) == (0,) and record_seeds({}) == (0,)
    assert record_seeds({"noise_seed": [0, 100]}) == (0, 100)


def test_each_seed_draws_its_own_noise_of_the_same_clean_frames(kitti_root: Path) -> None:
    from tracker.calibration import find_profile
    from tracker.eval.perturb import NOISE_LEVELS
    from tracker.io.convert.kitti import convert_kitti

    raw = {"0013": convert_kitti(kitti_root, seqs=["0013"], classes=["car"])[0]["0013"][:20]}
    specs = {"clean": None, "noise": NOISE_LEVELS["noise"]}
    profile = find_profile("pointrcnn")
    one = level_frames(raw, profile, specs, [0])
    two = level_frames(raw, profile, specs, [0, 1])
    assert list(one) == ["clean", "noise"] and list(two) == ["clean", "noise@0", "noise@1"]

    def centres(frames: list) -> list:
        return [f.boxes.xyz.round(6).tolist() for f in frames]

    assert centres(two["clean"]["0013"]) == centres(one["clean"]["0013"])
    assert centres(two["noise@0"]["0013"]) == centres(one["noise"]["0013"])  # seed 0 is seed 0
    assert centres(two["noise@1"]["0013"]) != centres(two["noise@0"]["0013"])
    assert centres(two["noise@0"]["0013"]) != centres(two["clean"]["0013"])


@pytest.mark.parametrize("seeds", ["x", "0,-1", "1.5"])
def test_a_bad_noise_seed_is_a_one_line_error(
    seeds: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:  # argparse's own error: usage, then one line
        main(["tune", "--noise-seed", seeds, "--out", str(tmp_path / "t")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "Traceback" not in err
    assert "--noise-seed" in err.strip().splitlines()[-1]
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize(
    ("flag", "value", "message"),
    [
        ("--folds", "1", "expected an integer >= 2"),  # (was an IndexError after a trial)
        ("--folds", "0", "expected an integer >= 2"),
        ("--class", "van", "'van' is not scored by the KITTI protocol"),
        ("--class", "bus", "'bus' is not scored"),
        ("--class", "car,pedestrian", "one class at a time"),
        ("--class", "lorry", "unknown class 'lorry'"),
        ("--trials", "0", "expected an integer >= 1"),
        ("--seed", "-1", "expected an integer 0.."),  # (was Optuna's ValueError)
        ("--detectors", ",", "expected comma-separated detectors"),
        ("--detectors", "virconv,virconv", "virconv given more than once"),
    ],
)
def test_a_bad_tune_argument_is_a_usage_error_before_any_work(
    flag: str, value: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["tune", flag, value, "--out", str(tmp_path / "t")])
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert exit_.value.code == 2 and "Traceback" not in err
    assert last.startswith(f"mctrack tune: error: argument {flag}: ") and message in last, last
    assert not (tmp_path / "t").exists()


def test_class_is_read_as_classes_is_elsewhere() -> None:
    from app.cli import build_parser

    args = build_parser().parse_args(["tune", "--class", "Pedestrian", "--out", "x"])
    assert args.cls == "pedestrian"


def test_more_folds_than_sequences_or_an_out_file_is_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    no_kit = ["--kitti-root", str(tmp_path / "no_kit")]  # (its error would come after)
    code = main(["tune", *no_kit, "--seqs", "0006,0010", "--folds", "3", "--out", str(tmp_path)])
    assert code == 2
    assert without_kernel_lines(capsys.readouterr().err).strip() == (
        "mctrack tune: error: --folds 3 needs at least as many --seqs (got 2)"
    )
    a_file = tmp_path / "afile"
    a_file.write_text("")
    assert main(["tune", *no_kit, "--seqs", "0006,0010", "--folds", "2", "--out", str(a_file)]) == 2
    assert without_kernel_lines(capsys.readouterr().err).strip() == (
        f"mctrack tune: error: {a_file}: exists and is not a folder; pass another --out"
    )
    # searching on from a best.toml into its own folder would delete it (a new search there
    # replaces the results): refused, the file kept
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "best.toml").write_text('base = "kitti"\n')
    argv = ["tune", *no_kit, "--seqs", "0006,0010", "--folds", "2"]
    assert main([*argv, "--config", str(earlier / "best.toml"), "--out", str(earlier)]) == 2
    assert without_kernel_lines(capsys.readouterr().err).strip() == (
        f"mctrack tune: error: --config {earlier / 'best.toml'} is this --out's own result: "
        "pass another --out to search on from it"
    )
    assert (earlier / "best.toml").is_file()


def test_a_detector_without_the_class_is_refused_before_the_search(
    kitti_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """VirConv's files hold cars only: its pedestrian HOTA would be 0 in every trial (the
    search then wrote a best.toml, 'HOTA held out virconv 0.00')."""
    code = main(["tune", "--kitti-root", str(kitti_root), "--class", "pedestrian",
                 "--detectors", "pointrcnn,virconv", "--seqs", "0012,0014", "--folds", "2",
                 "--trials", "1", "--noise", "none", "--workers", "1",
                 "--out", str(tmp_path / "t")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert err.strip().splitlines()[-1] == (
        f"mctrack tune: error: {kitti_root / 'detections' / 'virconv'}: no pedestrian "
        "detections in --seqs (0012, 0014); --detectors must name detectors that detect pedestrian"
    )
    assert "trial" not in err  # refused before the search's progress bar
    assert not (tmp_path / "t").exists()


def test_the_chosen_settings_are_written_as_a_config_file(tmp_path: Path) -> None:
    """best.toml: the tuned config as its base, the search's mode and the chosen values over it;
    loaded, it is the base with the record's overrides, to the last bit, every other class as
    in the base."""
    from app.tune import best_config_toml

    user = tmp_path / "mine.toml"
    user.write_text('base = "kitti"\n[category.car]\nscore_min = 0.3\n')
    params = {"score_min": 0.12345678901, "lifecycle.min_hits": 3, "pose.r_scale": 3e-7,
              "lifecycle.confirm_nines": 2.0, "offline.rts_r_multiple": 4.0}  # fmt: skip
    overrides = settings_to_overrides("pedestrian", params)
    for config in ("kitti", str(user)):  # both online bases; the search ran offline
        record = {
            "class": "pedestrian", "mode": "offline", "config": config,
            "cross_validated": {"pointrcnn": {"HOTA": 53.0}},
            "final": {"overrides": overrides, "in_sample": {"pointrcnn": {"HOTA": 54.0}}},
        }  # fmt: skip
        where = tmp_path / "out" / "best.toml"  # a user base: named relative to best.toml
        where.parent.mkdir(exist_ok=True)
        where.write_text(best_config_toml(record, where))
        assert f'base = "{"kitti" if config == "kitti" else "../mine.toml"}"' in where.read_text()
        got = load_config(str(where))
        want = load_config(config, overrides={**overrides, "mode": "offline"})
        assert got.per_category == want.per_category and got.offline == want.offline
        assert got.per_category["pedestrian"].score_min == 0.12345678901
        assert got.per_category["pedestrian"].pose.r_scale == 3e-7
        assert got.mode.value == "offline" and got.offline.rts_r_multiple == 4.0
        kitti_car = load_config("kitti").per_category["car"].score_min
        assert got.per_category["car"].score_min == (0.3 if config == str(user) else kitti_car)


def test_searched_values_become_overrides_the_config_accepts() -> None:
    params = {
        "score_min": 0.1,
        "lifecycle.confirm_nines": 2.0,
        "lifecycle.max_misses_output": 2,
        "pose.ca.r": 0.35,
    }
    overrides = settings_to_overrides("pedestrian", params)
    cat = load_config("kitti", overrides=overrides).per_category["pedestrian"]
    assert cat.score_min == 0.1
    assert cat.lifecycle.confirm_prob == pytest.approx(0.99)
    assert cat.lifecycle.max_misses_output == 2
    assert cat.pose.ca.r == (0.35, 0.35)
    assert cat.pose.r_scale == 0.0  # a record of a fixed r replays as one, not as a prior
    # the rest of the filter is the base config's, not a default
    assert cat.pose.ca.q == load_config("kitti").per_category["pedestrian"].pose.ca.q


@pytest.mark.parametrize("cls", ["car", "pedestrian"])
def test_the_first_trial_is_the_base_config_itself(cls: str) -> None:
    """Trial 0 of every search is the shipped setting: mapping its values back to overrides
    leaves the config unchanged."""
    base = {"categories": [cls]}
    space = search_space(cls, "online")
    values = _current("kitti", base, cls, space)
    assert set(values) == set(space)
    for key, (_, low, high) in space.items():
        assert low <= values[key] <= high, key
    before = load_config("kitti", overrides=base).per_category[cls]
    after = load_config(
        "kitti", overrides={**base, **settings_to_overrides(cls, values)}
    ).per_category[cls]
    assert after.pose == before.pose and after.bev == before.bev
    assert after.image_width_scale == pytest.approx(before.image_width_scale, abs=1e-6)
    assert after.lifecycle.min_hits == before.lifecycle.min_hits
    assert after.lifecycle.confirm_prob == pytest.approx(before.lifecycle.confirm_prob, abs=1e-6)


def test_only_pedestrians_search_their_2d_box_width() -> None:
    assert "image_width_scale" in search_space("pedestrian", "online")
    assert "image_width_scale" in search_space("pedestrian", "offline")
    assert "image_width_scale" not in search_space("car", "online")
    assert set(search_space("car", "online")) == set(ONLINE_SPACE) | set(CAR_SPACE)


def test_only_cars_search_the_online_output_gate() -> None:
    gate = "lifecycle.track_score_min"
    assert gate in search_space("car", "online")
    for cls, mode in [("car", "offline"), ("pedestrian", "online"), ("cyclist", "online")]:
        assert gate not in search_space(cls, mode)
    overrides = settings_to_overrides("car", {gate: -0.7})
    assert (
        load_config("kitti", overrides=overrides).per_category["car"].lifecycle.track_score_min
        == -0.7
    )
    overrides = settings_to_overrides("pedestrian", {"image_width_scale": 0.7})
    assert load_config("kitti", overrides=overrides).image_width_scales()[
        load_config("kitti").category_ids[1]
    ] == pytest.approx(0.7)


def test_unknown_noise_level_is_a_one_line_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["tune", "--noise", "loud", "--out", str(tmp_path / "t")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("mctrack tune: error: --noise: unknown")
    assert not (tmp_path / "t").exists()


def test_fold_searches_do_not_start_from_the_shipped_settings(
    kitti_root: Path, tmp_path: Path
) -> None:
    """The shipped values were searched on every labelled sequence: only the in-sample search
    starts from them; a fold's search proposes its own (else its held-out figure would have
    seen the held-out labels)."""
    import json

    code = main(["tune", "--kitti-root", str(kitti_root), "--class", "Car", "--detectors",
                 "pointrcnn", "--seqs", "0012,0014", "--folds", "2", "--trials", "4",
                 "--noise", "none", "--workers", "2", "--out", str(tmp_path)])  # fmt: skip
    assert code == 0
    record = json.loads((tmp_path / "tune.json").read_text())
    best = load_config(str(tmp_path / "best.toml"))  # the chosen settings, as a config file
    assert best.per_category["car"].score_min == pytest.approx(
        record["final"]["best"]["score_min"], abs=1e-6
    )
    shipped = _current("kitti", {"categories": ["car"]}, "car", search_space("car", "online"))
    assert record["final"]["trials"][0]["params"] == pytest.approx(shipped)
    assert len(record["cv"]) == 2
    for fold in record["cv"]:
        assert len(fold["trials"]) == 4
        assert all(t["params"] != pytest.approx(shipped) for t in fold["trials"])


def test_a_detector_without_a_profile_is_tuned_on_a_profile_fitted_on_the_sequences(
    kitti_root: Path, tmp_path: Path
) -> None:
    """The in-sample search calibrates a new detector as `mctrack calibrate` would on the same
    sequences (the folds fit their own), not on the uncalibrated fallback: its figure is the
    one `mctrack kitti --profile` gives with that profile."""
    import json

    from app.kitti import run_kitti

    kit = tmp_path / "kit"
    (kit / "detections").mkdir(parents=True)
    (kit / "training").symlink_to(kitti_root / "training")
    (kit / "detections" / "mydet").symlink_to(kitti_root / "detections" / "virconv")
    seqs = ["--seqs", "0006,0010"]
    code = main(["tune", "--kitti-root", str(kit), "--class", "car", "--detectors", "mydet",
                 *seqs, "--folds", "2", "--trials", "1", "--noise", "none", "--workers", "1",
                 "--out", str(tmp_path / "t")])  # fmt: skip
    assert code == 0
    record = json.loads((tmp_path / "t" / "tune.json").read_text())
    assert record["profiles"]["in_sample"] == {"mydet": "fitted on --seqs (0006, 0010)"}
    profile = tmp_path / "mydet.toml"
    calibrate = ["calibrate", "--kitti-root", str(kit), "--detector", "mydet", "--classes", "car"]
    assert main([*calibrate, *seqs, "--out", str(profile)]) == 0
    plain = run_kitti(kitti_root=kit, seqs=["0006", "0010"], classes=["car"], detector="mydet",
                      profile=profile, out=tmp_path / "k", quiet=True)  # fmt: skip
    assert record["final"]["in_sample"]["mydet"]["HOTA"] == plain["metrics"]["car"]["HOTA"]


def test_the_search_reads_each_label_file_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The labels are checked before the search; every trial's evaluation (in the pool's
    workers) and each held-out fold's re-read and re-checked them, though checked as strictly
    already."""
    import shutil

    import tracker.eval.kitti

    kit = tmp_path / "kit"  # the sample's sequence 0001, and a copy as 0002 (two folds)
    shutil.copytree(Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001" / "raw", kit)
    for path in list(kit.rglob("0001.txt")):
        shutil.copy(path, path.with_name("0002.txt"))
    checked = tmp_path / "checked.txt"  # (a file: the trials run in forked workers)
    check_label_file = tracker.eval.kitti.check_label_file

    def counting(path: Path, *args: Any, **kwargs: Any) -> int:
        with open(checked, "a") as fh:
            fh.write(f"{Path(path).name}\n")
        return check_label_file(path, *args, **kwargs)

    monkeypatch.setattr(tracker.eval.kitti, "check_label_file", counting)
    code = main(["tune", "--kitti-root", str(kit), "--class", "car", "--detectors", "pointrcnn",
                 "--seqs", "0001,0002", "--folds", "2", "--trials", "1", "--noise", "none",
                 "--workers", "1", "--out", str(tmp_path / "t")])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    assert (tmp_path / "t" / "tune.json").is_file()  # 3 trials and 2 held-out folds scored
    assert sorted(checked.read_text().split()) == ["0001.txt", "0002.txt"]


def test_a_class_whose_boxes_all_score_the_same_is_said_before_the_search_and_recorded(
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A detector writing one pedestrian score was tuned silently: every fold's map gave all its
    boxes one probability, so each trial kept all of them or none. Now tune warns once per
    detector and class (not once per profile: the folds' and the in-sample one), before the
    search, as `mctrack calibrate` words it, and tune.json keeps it."""
    import json
    import logging
    import shutil

    import app.tune
    from tests.test_detectors import _constant_score_kit

    kit = _constant_score_kit(tmp_path)  # sequence 0001; a copy as 0002 makes two folds
    for path in list(kit.rglob("0001.txt")):
        shutil.copy(path, path.with_name("0002.txt"))
    seqs = ["--seqs", "0001,0002"]
    said_at_start: list[list[str]] = []
    make_sampler = app.tune.make_sampler

    def first_search(seed: int, n_startup: int) -> object:  # (what was said as a search starts)
        said_at_start.append([r.getMessage() for r in caplog.records])
        return make_sampler(seed, n_startup)

    monkeypatch.setattr(app.tune, "make_sampler", first_search)
    with caplog.at_level(logging.WARNING):
        code = main(["tune", "--kitti-root", str(kit), "--class", "pedestrian", "--detectors",
                     "constdet", *seqs, "--folds", "2", "--trials", "1", "--noise",
                     "none", "--workers", "1", "--out", str(tmp_path / "t")])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    said = [r.getMessage() for r in caplog.records if "one value cannot rank" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("constdet pedestrian: all 1666 boxes ")
    assert said[0] in said_at_start[0]
    record = json.loads((tmp_path / "t" / "tune.json").read_text())
    assert record["profiles"]["one_score"] == {"constdet": said[0]}
    # the in-sample profile is the one `mctrack calibrate` fits on the same sequences: one wording
    caplog.clear()
    calibrate = ["calibrate", "--kitti-root", str(kit), "--detector", "constdet", "--classes",
                 "pedestrian", *seqs, "--out", str(tmp_path / "c.toml")]  # fmt: skip
    with caplog.at_level(logging.WARNING):
        assert main(calibrate) == 0
    assert said[0] in [r.getMessage() for r in caplog.records]
    capsys.readouterr()


@pytest.mark.parametrize(("config", "mode"), [("kitti_offline", "offline"), ("kitti", "online")])
def test_without_mode_the_config_is_tuned_in_its_own_mode(
    kitti_root: Path,
    tmp_path: Path,
    config: str,
    mode: str,
    caplog: pytest.LogCaptureFixture,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """`tune --config kitti_offline` without --mode tuned online (argparse's default), so kitti,
    with a warning, where `mctrack kitti`/`track` run the config's own mode. Now tune does too,
    and the record, its command and best.toml name the mode, so the run repeats as it ran."""
    import json
    import logging
    import shlex

    from tracker import config as config_module

    monkeypatch.setattr(config_module, "_NOTED", set())  # (its notes are said once per process)
    out = tmp_path / "t"
    argv = ["tune", "--kitti-root", str(kitti_root), "--class", "car", "--detectors", "pointrcnn",
            "--config", config, "--seqs", "0006,0010", "--folds", "2", "--trials", "1",
            "--noise", "none", "--workers", "1", "--out", str(out)]  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="tracker.config"):
        assert main(argv) == 0, capsys.readouterr().err
    assert "online mode" not in caplog.text  # (kitti_offline's "runs its base kitti")
    record = json.loads((out / "tune.json").read_text())
    assert (record["mode"], record["config"]) == (mode, config)
    assert ("offline.track_score_min" in record["space"]) == (mode == "offline")
    words = shlex.split(record["command"])
    assert words[words.index("--mode") + 1] == mode
    best = (out / "best.toml").read_text()
    assert f'base = "{config}"\nmode = "{mode}"\n' in best
    assert load_config(out / "best.toml").mode.value == mode
    capsys.readouterr()


def test_a_base_with_a_fixed_r_searches_r_itself() -> None:
    """Without ``pose.r_scale`` in the base config the search covers the fixed r (the first
    trial is then the base itself); with it, the multiple."""
    assert "pose.r_scale" in search_space("car", "online")
    space = search_space("car", "online", r_scale=False)
    assert "pose.ca.r" in space and "pose.r_scale" not in space
    base = {"categories": ["car"]}
    values = _current("kitti_reference", base, "car", space)
    assert values["pose.ca.r"] == load_config("kitti_reference").per_category["car"].pose.ca.r[0]


def _held_out_better(rec: dict, mode: str) -> bool:
    """Whether choosing per fold held out better than the grid's first point (a record of
    bench/offline_from_online.py)."""
    judged = rec["choice"].get("held_out_objective")
    if judged is not None:
        return judged[mode] > judged[f"{mode}_first"]
    held = rec["held_out"].values()
    return sum(m[mode]["HOTA"] for m in held) > sum(m[f"{mode}_first"]["HOTA"] for m in held)


def test_shipped_offline_choices_are_the_records() -> None:
    """`kitti_offline` ships an offline-only value chosen on labels only where the record of
    bench/offline_from_online.py says choosing held out better than the config's values; the
    value shipped is the record's choice on all sequences. A setting that no such record chose
    keeps the plain value (the grid's first point) of every record that tried it. A record made
    for online settings no longer shipped names the record that replaced it. "Held out better"
    is on the objective the choice was made by (clean and noisy held-out detections) where the
    record holds it, else (records before December 2026) on the clean held-out HOTA."""
    import json

    from tracker.config import load_config

    config = load_config("kitti_offline")
    docs = Path(__file__).resolve().parents[1] / "docs" / "tune"
    paths = sorted(docs.glob("*_offline*_choice*.json"))
    assert [p.name for p in paths] == [
        "car_offline_choice.json",
        "car_offline_score_choice.json",
        "car_offline_three_draws_choice.json",  # the same choice, from the car search's rerun
        "pedestrian_offline_buffer_choice.json",  # held out worse: the plain 0.3 stays
        "pedestrian_offline_choice.json",  # superseded (before the online distance gate)
        "pedestrian_offline_choice_motion_gate.json",  # superseded (before the exchange)
        "pedestrian_offline_choice_motion_gate_short_links.json",  # superseded
        "pedestrian_offline_choice_noise_only.json",  # superseded
        "pedestrian_offline_exchange_choice.json",
        "pedestrian_offline_score_choice.json",
        "pedestrian_offline_stitch_choice.json",
    ]
    shipped: dict[tuple[str, str], set] = {}  # (class or "", key) -> the values records chose
    plain: dict[tuple[str, str], set] = {}  # ... -> the plain values of records not shipped
    for path in paths:
        rec = json.loads(path.read_text())
        if "superseded_by" in rec:
            assert (docs / rec["superseded_by"]).is_file()
            continue
        better = _held_out_better(rec, "offline")
        for key, grid in rec["choice"]["grid"].items():
            owner = "" if key.startswith("offline.") else rec["class"]
            if better:
                shipped.setdefault((owner, key), set()).add(rec["choice"]["final"]["chosen"][key])
            else:
                plain.setdefault((owner, key), set()).add(grid[0])
    for owner, key in shipped.keys() | plain.keys():
        node = config.per_category[owner] if owner else config
        for part in key.split("."):
            node = getattr(node, part)
        want = shipped.get((owner, key)) or plain[owner, key]
        assert {node} == want, (owner, key)


def test_shipped_online_choices_are_the_records() -> None:
    """A value added to a searched record and chosen per fold (bench/offline_from_online.py
    --choose-online) ships in `kitti` as the record's choice on all sequences only where choosing
    held out better online than the record's settings alone; else the grid's first point. A
    record the code has moved past names the record that replaced it."""
    import json

    from tracker.config import load_config

    config = load_config("kitti")
    docs = Path(__file__).resolve().parents[1] / "docs" / "tune"
    paths = sorted(docs.glob("*_online_*_choice*.json"))
    assert [p.name for p in paths] == [
        "ped_online_motion_gate_choice.json",
        "ped_online_motion_gate_choice_short_links.json",  # superseded
    ]
    for path in paths:
        rec = json.loads(path.read_text())
        if "superseded_by" in rec:
            assert (docs / rec["superseded_by"]).is_file()
            continue
        assert "held_out_objective" in rec["choice"]
        better = _held_out_better(rec, "online")
        cat = config.per_category[rec["class"]]
        for key, grid in rec["choice"]["grid"].items():
            node = cat
            for part in key.split("."):
                node = getattr(node, part)
            want = rec["choice"]["final"]["chosen"][key] if better else grid[0]
            if key == "bev.gate_motion_m":  # (a gate at or beyond gate_distance_m is off)
                node, want = (min(v, cat.bev.gate_distance_m) for v in (node, want))
            assert node == want, key


def test_offline_choice_grid_parses_and_refuses_a_bare_key() -> None:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    from offline_from_online import _parse_choose

    assert _parse_choose(["offline.rts_r_multiple=1,10", "lifecycle.min_hits=2"]) == {
        "offline.rts_r_multiple": [1, 10],
        "lifecycle.min_hits": [2],
    }
    with pytest.raises(SystemExit, match="expected KEY=V1,V2"):
        _parse_choose(["offline.rts_r_multiple"])


def test_after_holds_each_folds_own_choice() -> None:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    from offline_from_online import hold_choices

    record = {
        "cv": [{"test": ["a"], "best": {"x": 1}}, {"test": ["b"], "best": {"x": 2}}],
        "final": {"best": {"x": 3}, "in_sample": {}},
    }
    choice = {
        "folds": [{"test": ["a"], "chosen": {"g": 0.8}}, {"test": ["b"], "chosen": {"g": 1.0}}],
        "final": {"chosen": {"g": 1.2}},
    }
    after = {"online_record": "r.json", "held_out": {"d": {"online_first": {}}}, "choice": choice}
    held = hold_choices(record, after, "docs/tune/r.json")
    assert [f["best"] for f in held["cv"]] == [{"x": 1, "g": 0.8}, {"x": 2, "g": 1.0}]
    assert held["final"] == {"best": {"x": 3, "g": 1.2}, "in_sample": {}}
    assert record["cv"][0]["best"] == {"x": 1}  # the record itself is left as it was
    with pytest.raises(SystemExit, match=r"made for 'r\.json', not for 'other\.json'"):
        hold_choices(record, after, "other.json")
    offline_only = {**after, "held_out": {"d": {"offline_first": {}}}}
    with pytest.raises(SystemExit, match="not a --choose-online record"):
        hold_choices(record, offline_only, "r.json")
    choice["folds"].reverse()
    with pytest.raises(SystemExit, match="folds are not this record's"):
        hold_choices(record, after, "r.json")


def test_search_adds_a_setting_the_config_accepts() -> None:
    assert parse_search("lifecycle.max_misses_tentative=int:0:2") == (
        "lifecycle.max_misses_tentative", ("int", 0.0, 2.0),
    )  # fmt: skip
    config = load_config("kitti", overrides={"categories": ["pedestrian"]})
    built_in = search_space("pedestrian", "online")
    space = with_searched(
        built_in,
        [
            "lifecycle.max_misses_tentative=int:0:2",
            "bev.buffer=float:0.1:0.6",
            "nms_iou_max=float:0:1",
        ],
        config,
        "pedestrian",
        "online",
    )
    assert space == {
        **built_in,
        "lifecycle.max_misses_tentative": ("int", 0.0, 2.0),
        "bev.buffer": ("float", 0.1, 0.6),
        "nms_iou_max": ("float", 0.0, 1.0),  # (a range's own ends are inside it)
    }
    extra = {k: v for k, v in space.items() if k not in built_in}
    first = _current("kitti", {"categories": ["pedestrian"]}, "pedestrian", extra)
    assert first == {"lifecycle.max_misses_tentative": 0, "bev.buffer": 0.3, "nms_iou_max": 1.0}
    overrides = settings_to_overrides("pedestrian", {"lifecycle.max_misses_tentative": 2})
    tuned = load_config("kitti", overrides=overrides).per_category["pedestrian"]
    assert tuned.lifecycle.max_misses_tentative == 2
    offline = load_config("kitti_offline", overrides={"categories": ["car"]})
    space = with_searched({}, ["offline.stitch_max_gap=int:0:40"], offline, "car", "offline")
    assert space == {"offline.stitch_max_gap": ("int", 0.0, 40.0)}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("lifecycle.max_misses_tentative=int:0", "expected KEY=KIND:LOW:HIGH"),
        ("bev.cost_max=normal:1:2", "KIND must be int, float or log"),
        ("bev.cost_max=float:2:1", "needs LOW < HIGH"),
        ("bev.buffer=float:0:inf", "must be finite"),
        ("pose.r_scale=log:0:10", "LOW > 0 for log"),
        ("lifecycle.min_hits=int:1.5:3", "whole numbers"),
        ("lifecycle.no_such=int:0:2", "pedestrian settings have no setting 'lifecycle.no_such'"),
        ("bev=float:1:2", "bev is not a number setting"),
        ("pose.ca.r=log:0.1:1", "pose.ca.r is not a number setting"),
        ("lifecycle.max_misses_tentative=float:0:2", "is an int setting: KIND int"),
        ("bev.buffer=int:0:2", "is a float setting: KIND float or log"),
        ("bev.cost_max=float:1:3", "bev.cost_max is searched already (float 1..2)"),
        ("lifecycle.confirm_prob=float:0.9:0.99", "searched already, as lifecycle.confirm_nines"),
        ("offline.stitch_max_gap=int:0:40", "searched with --mode offline only"),
        # beyond the config's range (tracker.config._RANGES): every trial drawing there failed
        # mid-search with "<builtin kitti>: category.pedestrian.bev.buffer must be in [0, 2]"
        ("bev.buffer=float:0.5:3", "bev.buffer must be in [0, 2]; HIGH 3 is outside"),
        ("nms_iou_max=float:0.5:1.2", "nms_iou_max must be in [0, 1] (an IoU); HIGH 1.2 is"),
        ("vertical_gain=float:0:1", "vertical_gain must be in (0, 1]; LOW 0 is outside"),
        ("lifecycle.max_misses_tentative=int:-1:2", "max_misses_tentative must be >= 0; LOW -1"),
    ],
)
def test_a_bad_search_is_a_one_line_error_before_any_work(
    text: str, message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        [
            "tune", "--class", "pedestrian", "--kitti-root", str(tmp_path / "no_kit"),
            "--search", text, "--out", str(tmp_path / "t"),
        ]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"mctrack tune: error: --search {text!r}") and message in last, last
    assert not (tmp_path / "t").exists()


def test_a_search_given_twice_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(
        [
            "tune", "--class", "pedestrian", "--kitti-root", str(tmp_path / "no_kit"), "--search",
            "bev.buffer=float:0.1:0.6", "--search", "bev.buffer=float:0.2:0.6",
            "--out", str(tmp_path / "t"),
        ]
    )  # fmt: skip
    assert code == 2
    assert "bev.buffer is searched already (float 0.1..0.6)" in capsys.readouterr().err


def test_a_detector_not_in_the_kit_names_the_detectors_flag(
    kitti_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    kit = tmp_path / "kit"
    (kit / "detections").mkdir(parents=True)
    (kit / "training").symlink_to(kitti_root / "training")
    (kit / "detections" / "mydet").symlink_to(kitti_root / "detections" / "virconv")
    code = main(["tune", "--kitti-root", str(kit), "--detectors", "mydet,nope", "--seqs",
                 "0006,0010", "--folds", "2", "--out", str(tmp_path / "t")])  # fmt: skip
    assert code == 2
    assert without_kernel_lines(capsys.readouterr().err).strip() == (
        f"mctrack tune: error: {kit / 'detections' / 'nope' / 'training'}: detections not "
        "found; pass --detectors A,B (found: mydet)"
    )


def test_the_record_repeats_the_search_best_toml_moves_with_its_base_and_a_new_search_clears(
    kitti_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    """tune.json (and best.toml's header) hold the command that repeats the search, quoted;
    best.toml names a user base relative to itself, so a moved tree still loads; a new search
    into the folder removes the earlier one's tune.json and best.toml when it starts, so an
    interrupted search never leaves them looking like its own."""
    import json
    import shlex

    import app.tune

    tree = tmp_path / "my tree"
    (tree / "x").mkdir(parents=True)
    base = tree / "x" / "base.toml"
    base.write_text('base = "kitti"\n[category.car]\nscore_min = 0.3\n')
    out = tree / "y"
    argv = ["tune", "--kitti-root", str(kitti_root), "--class", "car", "--detectors", "pointrcnn",
            "--config", str(base), "--mode", "online", "--trials", "1", "--folds", "2",
            "--seed", "0", "--noise", "none", "--noise-seed", "0", "--seqs", "0006,0010",
            "--workers", "1", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    record = json.loads((out / "tune.json").read_text())
    assert shlex.split(record["command"]) == ["mctrack", *argv]
    best = (out / "best.toml").read_text()
    assert f"# `{record['command']}`" in best and 'base = "../x/base.toml"' in best
    moved = tmp_path / "moved"
    tree.rename(moved)
    assert load_config(moved / "y" / "best.toml").per_category["car"].score_min == pytest.approx(
        record["final"]["best"]["score_min"], abs=1e-6
    )

    (moved / "y" / "notes.txt").write_text("mine")

    def interrupt(trials: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(app.tune, "best_trial", interrupt)  # stopped after the first search
    again = [*argv[:-1], str(moved / "y")]
    again[again.index("--config") + 1] = str(moved / "x" / "base.toml")
    assert main(again) == 130
    capsys.readouterr()
    assert sorted(p.name for p in (moved / "y").iterdir()) == ["notes.txt"]


def test_best_toml_names_a_base_outside_its_tree_by_its_absolute_path() -> None:
    from app.tune import written_base

    assert written_base(Path("/tmp/a/base.toml"), Path("/home/u/best.toml")).startswith("/tmp")
    assert written_base(Path("/tmp/a/base.toml"), None) == str(Path("/tmp/a/base.toml").resolve())
    assert written_base(Path("/w/a/b.toml"), Path("/w/c/best.toml")) == "../a/b.toml"


def test_the_next_tune_removes_the_work_folder_of_a_killed_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A tune killed outright (SIGKILL: no clean-up of its own) left its /tmp/mctrack-tune-*
    folder of trial results forever. Its name carries the tune's pid: the next tune removes it
    once that pid no longer runs, never a running tune's."""
    import os
    import shutil
    import signal
    import subprocess
    import sys
    import tempfile
    import time

    root = Path(__file__).resolve().parents[1]
    kit = tmp_path / "kit"  # the sample's sequence 0001, and a copy as 0002 (two folds)
    shutil.copytree(root / "sample_data" / "kitti-0001" / "raw", kit)
    for path in list(kit.rglob("0001.txt")):
        shutil.copy(path, path.with_name("0002.txt"))
    temp = tmp_path / "temp"  # the runs' $TMPDIR
    temp.mkdir()
    argv = ["tune", "--kitti-root", str(kit), "--class", "car", "--detectors", "pointrcnn",
            "--seqs", "0001,0002", "--folds", "2", "--trials", "1", "--noise", "none",
            "--workers", "1"]  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", *argv, "--out", str(tmp_path / "killed")],
        cwd=root,
        env={**os.environ, "TMPDIR": str(temp)},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # (its pool's workers are killed with it)
    )
    try:
        deadline = time.monotonic() + 300
        while not list(temp.glob("mctrack-tune-*")):
            assert proc.poll() is None and time.monotonic() < deadline, "the tune ended first"
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    left = sorted(p.name for p in temp.iterdir())
    assert any(name.startswith(f"mctrack-tune-{proc.pid}-") for name in left), left
    running = temp / f"mctrack-tune-{os.getpid()}-running"  # a tune of a live process
    running.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))  # (this process's $TMPDIR)
    assert main([*argv, "--out", str(tmp_path / "next")]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in temp.iterdir()) == [running.name]
    assert (tmp_path / "next" / "tune.json").is_file()
