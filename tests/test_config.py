"""Config loading: built-ins resolve, overrides merge, unknown keys name their dotted path."""

from __future__ import annotations

import dataclasses
import json
import re
import tomllib
from pathlib import Path

import pytest

from tracker.categories import category_index
from tracker.config import (
    BUILTIN,
    CostKind,
    CostState,
    config_from_dict,
    config_to_dict,
    load_config,
)
from tracker.errors import InputError

CONFIGS = Path(__file__).resolve().parents[1] / "tracker" / "configs"
SAMPLE = CONFIGS.parents[1] / "sample_data" / "kitti-0001"


@pytest.mark.parametrize("name", ["kitti"])
def test_builtin_configs_load(name: str) -> None:
    cfg = load_config(name)
    assert cfg.dataset == name
    assert set(cfg.per_category) == set(cfg.categories)
    assert config_to_dict(cfg)["category"]["car"]["bev"]["cost"] == "ro_gdiou"


@pytest.mark.parametrize("name", sorted(BUILTIN))
def test_config_to_dict_reloads_to_the_same_config(name: str) -> None:
    """A run's summary (config_to_dict, through strict JSON, as the writers use: an infinite
    setting such as an off track score gate is written as "-inf") loads back into the config
    it ran."""
    cfg = load_config(name)
    raw = json.loads(json.dumps(config_to_dict(cfg), allow_nan=False))
    assert config_from_dict(raw, source=cfg.source) == cfg
    changed = load_config(name, overrides={"category": {"car": {"score_min": 0.123}}})
    assert config_from_dict(json.loads(json.dumps(config_to_dict(changed)))) != cfg


@pytest.mark.parametrize(("name", "category"), [("kitti_reference", "car"), ("kitti", "cyclist")])
def test_kitti_reference_values(name: str, category: str) -> None:
    """The reference's cost settings: in kitti_reference, and in kitti's [defaults] (which the
    untuned cyclist keeps)."""
    cfg = load_config(name).per_category[category]
    assert cfg.bev.cost is CostKind.RO_GDIOU and cfg.bev.cost_state is CostState.PREDICT
    assert (cfg.bev.w1, cfg.bev.w2, cfg.bev.cost_max, cfg.rv.cost_max) == (1.0, 1.0, 1.4, -0.3)


def test_override_merges_one_key() -> None:
    cfg = load_config("kitti", overrides={"category": {"car": {"bev": {"cost_max": 0.9}}}})
    assert cfg.per_category["car"].bev.cost_max == 0.9
    assert cfg.per_category["car"].bev.w1 == 1.0  # sibling kept
    assert cfg.per_category["cyclist"].bev.cost_max == 1.4  # other categories untouched


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"category": {"car": {"bev": {"cost_mx": 1}}}}, "unknown key 'category.car.bev.cost_mx'"),
        ({"defaults": {"bev": {"cost": "foo"}}}, "bev.cost: 'foo' is not one of"),
        ({"frame_rate": 3}, "unknown key 'frame_rate'"),
        ({"defaults": {"score_min": "high"}}, "score_min: expected a number"),
        ({"categories": ["car", "unicorn"]}, "unknown category 'unicorn'"),
        ({"category": {"unicorn": {"score_min": 0.1}}}, "category.unicorn: unknown category"),
        ({"category": {"bus": {"score_mn": 0.1}}}, "unknown key 'category.bus.score_mn'"),
        ({"defaults": {"size": {"q": "x"}}}, "size.q: expected a list"),
    ],
)
def test_strict_errors(overrides: dict, message: str) -> None:
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_config("kitti", overrides=overrides)


def test_config_file_path(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('dataset = "x"\nframe_rate_hz = 2\ncategories = ["car"]\n')
    cfg = load_config(path)
    assert cfg.frame_rate_hz == 2.0 and cfg.categories == ("car",)
    with pytest.raises(InputError, match="config not found"):
        load_config(tmp_path / "missing.toml")
    path.write_text("dataset = [")
    with pytest.raises(InputError, match="malformed TOML"):
        load_config(path)


def test_base_inheritance_and_loops(tmp_path: Path) -> None:
    offline = load_config("kitti_offline")
    online = load_config("kitti")
    assert offline.mode.value == "offline" and online.mode.value == "online"
    # offline is the online settings plus its own post-processing (its TOML's [offline]) and
    # the offline-only values it sets per category (tentative misses, the whole-track gate)
    offline_only = ("max_misses_tentative", "offline_track_score_min")
    assert offline.per_category != online.per_category
    for name, cat in offline.per_category.items():
        plain = {k: getattr(online.per_category[name].lifecycle, k) for k in offline_only}
        same = dataclasses.replace(cat, lifecycle=dataclasses.replace(cat.lifecycle, **plain))
        assert same == online.per_category[name], name
    own = tomllib.loads((CONFIGS / "kitti_offline.toml").read_text())["offline"]
    assert offline.offline.track_score_min == own["track_score_min"]
    assert offline.offline != online.offline
    child = tmp_path / "child.toml"
    child.write_text('base = "kitti"\n[category.car]\nscore_min = 0.6\n')
    cfg = load_config(child)
    assert cfg.per_category["car"].score_min == 0.6
    assert cfg.per_category["car"].birth_score_min == online.per_category["car"].birth_score_min
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text('base = "b.toml"\n')
    b.write_text('base = "a.toml"\n')
    with pytest.raises(InputError, match="loops"):
        load_config(a)


def test_image_width_scale_is_a_fraction_per_class() -> None:
    with pytest.raises(InputError, match=r"category.pedestrian.image_width_scale must be in"):
        load_config("kitti", overrides={"category": {"pedestrian": {"image_width_scale": 0.0}}})
    cfg = load_config("kitti", overrides={"category": {"car": {"image_width_scale": 0.5}}})
    scales = cfg.image_width_scales()
    assert scales[category_index("car")] == 0.5 and scales[category_index("cyclist")] == 1.0


# ---------------------------------------------------------------------------------------------
# category names: as --classes reads them (case, aliases), each once


@pytest.mark.parametrize("written", ["Car", "CAR", "vehicle"])
def test_a_category_section_is_read_under_its_canonical_name(tmp_path: Path, written: str) -> None:
    """[category.Car] is car's section, merged over the base's [category.car] (it was accepted
    and then ignored)."""
    path = tmp_path / "c.toml"
    path.write_text(f'base = "kitti"\ncategories = ["{written}"]\n[category.{written}]\n'
                    "score_min = 0.9\n")  # fmt: skip
    cfg = load_config(path)
    kitti_car = load_config("kitti").per_category["car"]
    assert cfg.categories == ("car",) and list(cfg.per_category) == ["car"]
    assert cfg.per_category["car"] == dataclasses.replace(kitti_car, score_min=0.9)
    over = load_config("kitti", overrides={"category": {written: {"score_min": 0.8}}})
    assert over.per_category["car"].score_min == 0.8


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ("[category.car]\nscore_min = 0.1\n[category.Car]\nscore_min = 0.9\n",
         "category.Car: the same category as category.car"),
        ("[category.vehicle]\nscore_min = 0.1\n[category.car]\nscore_min = 0.9\n",
         "category.car: the same category as category.vehicle"),
        ('categories = ["car", "Car"]\n', "categories: 'Car' names 'car' a second time"),
        ("[category]\ncar = 3\n", "category.car: expected a table, got 3"),
    ],
    ids=lambda v: v.split("\n")[0],
)  # fmt: skip
def test_a_category_named_twice_is_refused(tmp_path: Path, toml: str, message: str) -> None:
    path = tmp_path / "twice.toml"
    path.write_text('base = "kitti"\n' + toml)
    with pytest.raises(InputError, match=f"^{re.escape(f'{path}: {message}')}"):
        load_config(path)


# ---------------------------------------------------------------------------------------------
# value ranges


def test_a_pose_r_of_two_or_four_loads_either_way(tmp_path: Path) -> None:
    """R is [x, y], or [x, y, vx, vy] for a detector's velocity; the filter takes either (a
    velocity measured with 2 gets a placeholder), so neither is refused: nuScenes' 4 with the
    velocity not measured ran before the lengths were checked, and still does."""
    path = tmp_path / "c.toml"
    path.write_text('base = "nuscenes"\n[category.car.pose]\nmeasure_velocity = false\n')
    assert len(load_config(path).per_category["car"].pose.cv.r) == 4


@pytest.mark.parametrize("name", sorted(BUILTIN))
@pytest.mark.parametrize("mode", ["online", "offline"])
def test_every_shipped_config_loads(name: str, mode: str) -> None:
    """The ranges refuse no shipped value, in either mode (by name and by path)."""
    assert load_config(name, overrides={"mode": mode}).mode.value == mode
    assert load_config(CONFIGS / f"{name}.toml", overrides={"mode": mode}).mode.value == mode


@pytest.mark.parametrize(
    ("table", "dotted"),
    [
        ("[category.car]\nscore_min = 2", "category.car.score_min"),
        ("[category.car]\nscore_min = nan", "category.car.score_min"),
        ("[category.car]\nscore_min = -0.1", "category.car.score_min"),
        ("[category.car]\nbirth_score_min = 1.5", "category.car.birth_score_min"),
        ("[category.car]\nnms_iou_max = 2", "category.car.nms_iou_max"),
        ("[category.car.lifecycle]\nmax_misses = -1", "category.car.lifecycle.max_misses"),
        ("[category.car.lifecycle]\nmin_hits = -2", "category.car.lifecycle.min_hits"),
        ("[category.car.lifecycle]\nconfirm_prob = 1.5", "category.car.lifecycle.confirm_prob"),
        ("[category.car.lifecycle]\nconfirm_score = -1", "category.car.lifecycle.confirm_score"),
        ("[category.car.lifecycle]\ntrack_score_min = inf",
         "category.car.lifecycle.track_score_min"),
        ("[category.car.bev]\nalpha = 1.5", "category.car.bev.alpha"),
        ("[category.car.bev]\ngate_distance_m = 0", "category.car.bev.gate_distance_m"),
        ("[category.car.pose.ca]\nr = [0.0, 0.1]", "category.car.pose.ca.r"),
        ("[category.car.size]\nq = [0.01, -1, 0.001, 0.001]", "category.car.size.q"),
        # a variance per axis: the constant-acceleration state has 6, the size 4, heading 2
        ("[category.car.pose.ca]\np = [1, 1]", "category.car.pose.ca.p"),
        ("[category.car.size]\np = [1, 1, 10]", "category.car.size.p"),
        ("[category.car.heading.noise]\nr = [0.2]", "category.car.heading.noise.r"),
        ("[category.car.pose.ca]\nr = [0.1, 0.1, 0.1]", "category.car.pose.ca.r"),
        ("[category.car.heading]\nmin_speed_mps = -1", "category.car.heading.min_speed_mps"),
        ("[defaults]\nscore_min = 2", "defaults.score_min"),
        ("[defaults.lifecycle]\nmax_misses_output = -1", "defaults.lifecycle.max_misses_output"),
        ("[offline]\ninterpolate_max_gap = -1", "offline.interpolate_max_gap"),
        ("[offline]\nsmooth_seconds = inf", "offline.smooth_seconds"),
        ("[offline]\ntrack_score_min = nan", "offline.track_score_min"),
        ("frame_rate_hz = nan", "frame_rate_hz"),
    ],
    ids=lambda v: v.split("\n")[0],
)  # fmt: skip
def test_an_impossible_value_is_refused_naming_file_and_key(
    tmp_path: Path, table: str, dotted: str
) -> None:
    """Scores are probabilities in every score mode (a detection's score is in [0, 1]), counts
    are >= 0, variances finite and >= 0 (r > 0), NaN never: each was accepted and ran (a
    score_min of 2 to HOTA 0, exit 0)."""
    path = tmp_path / "bad.toml"
    path.write_text(f'base = "kitti"\n{table}\n')
    with pytest.raises(InputError, match=f"^{re.escape(f'{path}: {dotted}')}[ :]") as err:
        load_config(path)
    assert "\n" not in str(err.value)


def test_the_cli_refuses_an_impossible_value_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from app.cli import main

    path = tmp_path / "bad.toml"
    path.write_text('base = "kitti"\n[category.car]\nscore_min = 2\n')
    code = main(["track", str(SAMPLE / "detections.json.gz"), "--config", str(path),
                 "--out", str(tmp_path / "out")])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert f"{path}: category.car.score_min must be in [0, 1]" in err[0]
    assert not (tmp_path / "out" / "tracks.json").exists()


# ---------------------------------------------------------------------------------------------
# offline mode: one rule, every command


def _best_toml(tmp_path: Path, extra: str = "") -> Path:
    """A `mctrack tune` output of an online search: kitti with a car value of its own."""
    path = tmp_path / "best.toml"
    path.write_text(f'base = "kitti"\nmode = "online"\n[category.car]\nscore_min = 0.3\n{extra}')
    return path


def test_offline_mode_of_a_config_is_its_offline_variant(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """kitti in offline mode is kitti_offline (as `mctrack kitti` always had it, now `track`,
    `view`, `tune` too); a file on kitti gets kitti_offline's offline values where it sets none
    of its own; a file without a built-in offline variant under it keeps its own, and says so."""
    offline = load_config("kitti_offline")
    assert load_config("kitti", overrides={"mode": "offline"}) == offline
    assert load_config("kitti_offline", overrides={"mode": "offline"}) == offline
    caplog.set_level("INFO", logger="tracker.config")
    best = load_config(_best_toml(tmp_path), overrides={"mode": "offline"})
    car = offline.per_category["car"]
    assert best.mode.value == "offline" and best.offline == offline.offline
    assert best.per_category["car"] == dataclasses.replace(car, score_min=0.3)
    assert best.per_category["pedestrian"] == offline.per_category["pedestrian"]
    assert "on kitti_offline (the offline variant of its base kitti)" in caplog.text
    # its own offline values win; the file's own mode = "offline" asks the same as --mode
    own = _best_toml(tmp_path, "[offline]\nrts_r_multiple = 2.0\n").read_text()
    (tmp_path / "own.toml").write_text(own.replace('mode = "online"', 'mode = "offline"'))
    mine = load_config(tmp_path / "own.toml")
    assert mine.offline == dataclasses.replace(offline.offline, rts_r_multiple=2.0)
    assert mine.per_category["car"].lifecycle.offline_track_score_min == 0.5
    assert load_config(tmp_path / "own.toml", overrides={"mode": "online"}).offline.rts is False
    # no built-in offline variant under it: its own [offline] table
    alone = tmp_path / "alone.toml"
    alone.write_text((CONFIGS / "kitti.toml").read_text())
    assert load_config(alone, overrides={"mode": "offline"}).offline == load_config("kitti").offline
    assert f"{alone}, offline mode: no built-in offline variant under it" in caplog.text
    assert load_config("nuscenes", overrides={"mode": "offline"}).offline.track_score_min == 1.4


def test_track_offline_writes_what_the_offline_variant_writes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack track --mode offline --config kitti` wrote kitti's settings in offline mode
    (track gate -inf, smoother r 1.0), not kitti_offline's, which `mctrack kitti` used."""
    from app.cli import main

    written = []
    for config in ("kitti", "kitti_offline"):
        out = tmp_path / config
        argv = ["track", str(SAMPLE / "detections.json.gz"), "--frames", "0:80", "--mode",
                "offline", "--config", config, "--out", str(out)]  # fmt: skip
        assert main(argv) == 0, capsys.readouterr().err
        written.append((out / "tracks.json").read_bytes())
        # the summary names the config that ran
        assert json.loads((out / "summary.json").read_text())["config_name"] == "kitti_offline"
    assert written[0] == written[1]


def test_kitti_offline_with_a_tune_output_keeps_the_offline_values(tmp_path: Path) -> None:
    """`mctrack kitti --mode offline --config best.toml` (base kitti) ran best.toml with kitti's
    [offline] table, the offline values dropped silently."""
    from app.cli import main

    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(SAMPLE / "raw"), "--seqs", "0001", "--classes", "car",
            "--mode", "offline", "--config", str(_best_toml(tmp_path)), "--no-eval",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    ran = json.loads((out / "summary.json").read_text())["config"]
    want = load_config("kitti_offline", overrides={"category": {"car": {"score_min": 0.3}}})
    assert ran["offline"] == config_to_dict(want.offline)
    assert ran["category"]["car"] == config_to_dict(want.per_category["car"])


@pytest.mark.parametrize("config", ["kitti", "kitti_reference", "best.toml"])
def test_tune_offline_takes_any_config(
    tmp_path: Path, config: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack tune --mode offline --config X` loaded "X_offline": a file or a built-in without
    a variant was "not found". Now the config loads (the run stops at the next check, --folds)
    and its record names the built-in variant where there is one."""
    from app.cli import main
    from tracker.config import config_for_mode

    name = str(_best_toml(tmp_path)) if config == "best.toml" else config
    argv = ["tune", "--mode", "offline", "--config", name, "--kitti-root", str(SAMPLE / "raw"),
            "--seqs", "0001", "--folds", "2", "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--folds 2 needs at least as many --seqs" in err and "not found" not in err
    want = {"kitti": "kitti_offline", "kitti_reference": "kitti_reference"}.get(config, name)
    assert str(config_for_mode(name, "offline")) == want
    assert str(config_for_mode(name, "online")) == name


def test_online_mode_of_an_offline_variant_is_its_base(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`--config kitti_offline --mode online` ran kitti_offline's settings online, silently (its
    pedestrians' tentative misses 1, kitti's 0). Now it is kitti, said once; a file on
    kitti_offline in online mode is on kitti, said once per file; offline nothing changes."""
    from tracker import config as config_module
    from tracker.config import config_for_mode

    monkeypatch.setattr(config_module, "_NOTED", set())  # (said once per process)
    caplog.set_level("INFO", logger="tracker.config")
    kitti = load_config("kitti")
    assert load_config("kitti_offline").per_category["pedestrian"].lifecycle.max_misses_tentative
    assert load_config("kitti_offline", overrides={"mode": "online"}) == kitti
    assert str(config_for_mode("kitti_offline", "online")) == "kitti"
    assert str(config_for_mode("kitti_offline", None)) == "kitti_offline"
    assert str(config_for_mode("kitti", "online")) == "kitti"
    said = [r for r in caplog.records if "kitti_offline, online mode: runs its base kitti" in
            r.getMessage()]  # fmt: skip
    assert len(said) == 1 and said[0].levelname == "WARNING"
    # a file on kitti_offline (an offline search's best.toml): on kitti online, its own values kept
    best = tmp_path / "best.toml"
    best.write_text('base = "kitti_offline"\nmode = "offline"\n[category.car]\nscore_min = 0.3\n')
    online = load_config(best, overrides={"mode": "online"})
    want = load_config("kitti", overrides={"category": {"car": {"score_min": 0.3}}})
    assert online == dataclasses.replace(want, source=str(best))
    load_config(best, overrides={"mode": "online"})
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith(f"{best}, ")]
    assert len(said) == 1 and "online mode: on kitti instead of kitti_offline" in said[0]
    offline = load_config(best)
    assert offline.mode.value == "offline"
    assert (
        offline.per_category["pedestrian"]
        == load_config("kitti_offline").per_category["pedestrian"]
    )


def test_track_online_with_kitti_offline_writes_what_kitti_writes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack track --mode online --config kitti_offline` wrote other tracks than
    `--config kitti` (kitti_offline's pedestrian setting); its summary named kitti_offline."""
    from app.cli import main

    written = []
    for config in ("kitti", "kitti_offline"):
        out = tmp_path / config
        argv = ["track", str(SAMPLE / "detections.json.gz"), "--mode", "online", "--config",
                config, "--out", str(out)]  # fmt: skip
        assert main(argv) == 0, capsys.readouterr().err
        written.append((out / "tracks.json").read_bytes())
        summary = json.loads((out / "summary.json").read_text())
        assert summary["config_name"] == "kitti" and summary["mode"] == "online"
    assert written[0] == written[1]


def test_a_missing_base_is_named_with_the_file_whose_base_it_is(tmp_path: Path) -> None:
    """The error names the config the user passed and its base as written (a moved folder)."""
    child = tmp_path / "child.toml"
    child.write_text('base = "gone/best.toml"\n')
    with pytest.raises(InputError) as err:
        load_config(child)
    text = str(err.value)
    assert text.startswith(f"{child}: base 'gone/best.toml' (resolved to ")
    assert "config not found" in text and "\n" not in text
    child.write_text(f'base = "{tmp_path / "nope.toml"}"\n')
    with pytest.raises(InputError, match=rf"^{child}: base '.*nope.toml': config not found"):
        load_config(child)


def test_the_bench_configs_differ_from_kitti_only_in_the_written_2d_box() -> None:
    """docs/detectors.md section 5 compares the written 2D box rules with these files: each must
    load, and change nothing but what it says (the rule, and the bearing fusion for the old one)."""
    bench = Path(__file__).resolve().parents[1] / "bench"

    def settings(name: str | Path) -> dict:
        return {k: v for k, v in config_to_dict(load_config(name)).items() if k != "source"}

    kitti = settings("kitti")
    detection = settings(bench / "kitti_detection_boxes.toml")
    projection = settings(bench / "kitti_projection_boxes.toml")
    assert kitti["image_boxes"] == "auto" and kitti["image_bearing"] is True
    assert detection == {**kitti, "image_boxes": "detection"}
    assert projection == {**kitti, "image_boxes": "projection", "image_bearing": False}


def test_a_config_file_that_is_not_utf8_is_named(tmp_path: Path) -> None:
    """A --config file holding bytes that are not UTF-8 gave "not a text file (invalid start
    byte)", naming no file; now the file and the byte offset are named."""
    path = tmp_path / "bad.toml"
    path.write_bytes(b'base = "kitti"\n# \xff\n')
    with pytest.raises(InputError) as excinfo:
        load_config(path)
    assert str(excinfo.value) == f"{path}: not a UTF-8 text file (byte 17: invalid start byte)"
