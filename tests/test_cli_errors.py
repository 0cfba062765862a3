"""The CLI as a newcomer meets it: help that explains every option, and every wrong path,
missing or malformed file or wrong flag ending in one line that names the file, exit status 2,
no traceback (``--debug`` shows it)."""

from __future__ import annotations

import argparse
import gzip
import json
import logging
import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from app import cli
from app.cli import SUBCOMMANDS, build_parser, main
from tracker.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "kitti-0001"
SAMPLE_KIT = SAMPLE / "raw"  # a KITTI tracking layout with one sequence, 0001

#: Options that name an input a user types; the generic case points them at a missing path.
INPUT_OPTIONS = {
    "--kitti-root",
    "--sample",
    "--dataroot",
    "--data-root",
    "--detections",
    "--gt",
    "--labels",
}


def _parsers(
    parser: argparse.ArgumentParser, words: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every parser that runs something (``kitti``, ``convert kitti``, ...) and its words."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield words, parser
    for action in subs:
        for name, child in action.choices.items():
            yield from _parsers(child, (*words, name))


def _commands() -> list[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    return list(_parsers(build_parser()))


def _ids(commands: list[tuple[tuple[str, ...], argparse.ArgumentParser]]) -> list[str]:
    return [" ".join(words) for words, _ in commands]


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse usage errors
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _assert_one_line_error(code: int, err: str, command: str, *fragments: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err
    errors = [line for line in err.splitlines() if ": error:" in line]
    assert len(errors) == 1, err
    assert errors[0].startswith(f"mctrack {command}: error:"), err
    assert err.rstrip().endswith(errors[0]), err  # the error is the last thing printed
    for fragment in fragments:
        assert fragment in errors[0], err


# ---------------------------------------------------------------------------------------------
# help


def test_top_level_help_says_what_the_tool_does_and_where_to_start() -> None:
    text = build_parser().format_help()
    assert "3D multi-object tracking" in text.split("positional arguments")[0]
    assert "mctrack demo" in text and "--debug" in text and "exit status" in text
    for name in SUBCOMMANDS:
        assert name in text


COMMANDS = _commands()


@pytest.mark.parametrize(("words", "parser"), COMMANDS, ids=_ids(COMMANDS))
def test_every_option_has_help_and_shows_its_default(
    words: tuple[str, ...], parser: argparse.ArgumentParser
) -> None:
    formatter = cli.HelpFormatter(parser.prog)
    for action in parser._actions:
        if not action.option_strings or action.help == argparse.SUPPRESS:
            continue  # positionals are listed in the usage; hidden options are for tests
        text = formatter._get_help_string(action)
        assert text and len(text) > 10, f"{' '.join(words)} {action.option_strings}: no help"
        if action.default not in (None, False, argparse.SUPPRESS):
            assert "default" in text, f"{' '.join(words)} {action.option_strings}: no default"
    for action in parser._actions:
        if not action.option_strings and action.help is None:
            pytest.fail(f"{' '.join(words)} {action.dest}: positional without help")
    assert parser.description and len(parser.description) > 20


def test_kitti_help_shows_the_default_root_and_the_environment_variable(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("MCTRACK_KITTI_ROOT", str(tmp_path))
    text = " ".join(
        build_parser()._subparsers._group_actions[0].choices["kitti"].format_help().split()
    )
    assert "$MCTRACK_KITTI_ROOT" in text and str(tmp_path) in text.replace("- ", "-")


# ---------------------------------------------------------------------------------------------
# errors: a missing input on every command


def _missing_input_argv(
    words: tuple[str, ...], parser: argparse.ArgumentParser, tmp_path: Path
) -> list[str] | None:
    """The command with every input path missing, other required options given."""
    missing = tmp_path / "nonexistent"
    argv, any_input = list(words), False
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction) or action.dest == "debug":
            continue
        if not action.option_strings:
            argv.append(str(missing / action.dest))
            any_input = True
        elif set(action.option_strings) & INPUT_OPTIONS:
            argv += [action.option_strings[0], str(missing / action.dest)]
            any_input = True
        elif action.required:
            argv += [action.option_strings[0], str(tmp_path / "out" / action.dest)]
    return argv if any_input else None


@pytest.mark.parametrize(("words", "parser"), COMMANDS, ids=_ids(COMMANDS))
def test_missing_input_is_one_line_naming_the_path(
    words: tuple[str, ...],
    parser: argparse.ArgumentParser,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = _missing_input_argv(words, parser, tmp_path)
    if argv is None:
        pytest.skip(f"{' '.join(words)} reads no input path")
    code, _, err = _run(argv, capsys)
    _assert_one_line_error(code, err, words[0], str(tmp_path / "nonexistent"))


@pytest.mark.parametrize("name", sorted(SUBCOMMANDS))
def test_unknown_flag_is_a_usage_error(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run([name, "--no-such-flag"], capsys)
    assert code == 2 and "Traceback" not in err
    # one line (no usage block), named by the command: the flag, or a missing argument
    (line,) = err.strip().splitlines()
    assert line.startswith(f"mctrack {name}") and ": error: " in line, err
    assert line.endswith(f"(see mctrack {name} --help)"), err


def test_an_unknown_flag_is_named_by_its_command(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = _run(["kitti", "--detectr", "x", "--out", "o"], capsys)
    assert code == 2
    assert err == (
        "mctrack kitti: error: unrecognized arguments: --detectr x (see mctrack kitti --help)\n"
    )


#: Every command that takes a list of KITTI sequences and of classes.
LIST_COMMANDS = [
    c
    for c in COMMANDS
    if {"--seqs", "--classes"} <= {o for a in c[1]._actions for o in a.option_strings}
]


@pytest.mark.parametrize(("words", "parser"), LIST_COMMANDS, ids=_ids(LIST_COMMANDS))
@pytest.mark.parametrize(
    ("flag", "value", "fragment"),
    [
        ("--seqs", ",", "expected comma-separated sequences"),
        ("--seqs", "6,0006", "0006 given more than once"),
        ("--classes", "car,carr", "unknown class 'carr' (known: car, pedestrian, cyclist"),
        ("--classes", "Car,car", "more than once"),
        ("--classes", "dontcare", "unknown class 'dontcare'"),
    ],
)
def test_a_bad_sequence_or_class_list_is_a_usage_error(
    words: tuple[str, ...],
    parser: argparse.ArgumentParser,
    flag: str,
    value: str,
    fragment: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Before any work: never a run that tracks nothing, a sequence twice, or a traceback."""
    required = [
        (a.option_strings[0], "x")
        for a in parser._actions
        if a.required and a.option_strings and a.option_strings[0] not in {flag, "--out"}
    ]
    argv = [*words, *(w for pair in required for w in pair), "--out", str(tmp_path / "o")]
    if "tune" in words:
        argv += ["--class", "car"]
    code, _, err = _run([*argv, flag, value], capsys)
    _assert_one_line_error(code, err, " ".join(words), f"argument {flag}:", fragment)
    assert not (tmp_path / "o").exists()


def test_a_sequence_the_kit_lacks_names_the_ones_it_has(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "01O", "--out", str(tmp_path)]
    code, _, err = _run(argv, capsys)
    _assert_one_line_error(code, err, "kitti", "01O.txt: no calibration", "has 1: 0001)")


def test_sequence_and_class_lists_are_normalised() -> None:
    from app.inputs import class_list, sequence_list

    assert sequence_list(" 1, 0006 ,0019,") == ["0001", "0006", "0019"]
    assert class_list("Car, Pedestrian,person (sitting)") == ["car", "pedestrian", "person_sitting"]


def test_eval_reads_and_defaults_its_classes_as_kitti_does(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack eval` of a `mctrack kitti` run scores the same classes by default (it left out
    cyclist), and reads --classes with the same type."""
    from app.cli import build_parser

    parser = build_parser()
    kitti = parser.parse_args(["kitti", "--out", "o"]).classes
    assert kitti == ["car", "pedestrian", "cyclist"]
    assert parser.parse_args(["eval", "t.json"]).classes is None  # per dataset: KITTI's three
    assert parser.parse_args(["eval", "t.json", "--classes", "Cyclist"]).classes == ["cyclist"]
    code, _, err = _run(["eval", "t.json", "--classes", "car,carr"], capsys)
    _assert_one_line_error(code, err, "eval", "argument --classes:", "unknown class 'carr'")


# ---------------------------------------------------------------------------------------------
# errors: malformed files and wrong values, command by command


def _sample_frames() -> list[dict]:
    """Scene 0001 of the sample's detections, as JSON (frames 0-446)."""
    import gzip

    return json.loads(gzip.decompress((SAMPLE / "detections.json.gz").read_bytes()))["0001"]


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """Bad inputs, and a stock KITTI layout: the sample kit without ORB-SLAM3 poses, as in every
    official KITTI download."""
    truncated = tmp_path / "truncated.json"
    truncated.write_text('{"0001": [')
    not_rrd = tmp_path / "notes.rrd"
    not_rrd.write_text("not a recording\n")
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    stock = tmp_path / "stock_kitti"
    shutil.copytree(SAMPLE_KIT, stock, ignore=shutil.ignore_patterns("pose_orbslam3"))
    bad_calib = tmp_path / "bad_calib"
    shutil.copytree(SAMPLE_KIT, bad_calib)
    (bad_calib / "training" / "calib" / "0001.txt").write_text("P2: 1 2 3\n")
    bad_detections = tmp_path / "bad_detections"  # found only when the detections are read
    shutil.copytree(SAMPLE_KIT, bad_detections)
    (bad_detections / "detections" / "pointrcnn" / "training" / "Car" / "0001.txt").write_text(
        "0 Car x y z\n"
    )
    truncated_poses = tmp_path / "truncated_poses"  # cut mid-line, 13 whole lines of 447
    shutil.copytree(SAMPLE_KIT, truncated_poses)
    pose_file = truncated_poses / "training" / "pose_orbslam3" / "0001.txt"
    pose_file.write_bytes(pose_file.read_bytes()[:2000])
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text('base = "kitti"\n[defaults]\nno_such_key = 1\n')
    empty = tmp_path / "empty.json"
    empty.write_bytes(b"")
    no_scenes = tmp_path / "no_scenes.json"
    no_scenes.write_text("{}")
    no_frames = tmp_path / "no_frames.json"
    no_frames.write_text('{"0001": [], "0002": []}')
    empty_dir = tmp_path / "empty_dir"
    empty_dir.mkdir()
    bad_labels = tmp_path / "bad_labels"
    bad_labels.mkdir()
    (bad_labels / "0001.txt").write_text("frame track Car\n")  # no frame number
    no_camera = tmp_path / "no_camera.json"
    frames = _sample_frames()[:3]
    for frame in frames:
        del frame["transform_matrix"]["cameras_transform_matrix"]
        for box in frame["bboxes"]:
            box.pop("bbox_image", None)
    no_camera.write_text(json.dumps({"0001": frames}))
    no_image_shape = tmp_path / "no_image_shape.json"
    frames = _sample_frames()[:3]
    del frames[2]["transform_matrix"]["cameras_transform_matrix"]["CAM_FRONT"]["image_shape"]
    no_image_shape.write_text(json.dumps({"0001": frames}))
    return {
        "truncated": truncated,
        "not_rrd": not_rrd,
        "a_file": a_file,
        "stock": stock,
        "bad_calib": bad_calib,
        "bad_detections": bad_detections,
        "truncated_poses": truncated_poses,
        "bad_toml": bad_toml,
        "empty": empty,
        "no_scenes": no_scenes,
        "no_frames": no_frames,
        "empty_dir": empty_dir,
        "bad_labels": bad_labels,
        "no_camera": no_camera,
        "no_image_shape": no_image_shape,
        "out": tmp_path / "out",
        "detections": SAMPLE / "detections.json.gz",
        "gt": SAMPLE / "gt.json.gz",
    }


F = dict[str, Path]
# (case id, argv from the files, fragments the error line must hold)
CASES: list[tuple[str, Callable[[F], list[str]], tuple[str, ...]]] = [
    ("validate truncated", lambda f: ["validate", str(f["truncated"])], ("truncated.json",)),
    ("validate folder", lambda f: ["validate", str(f["stock"])], ("stock_kitti",)),
    (  # (was "OK, scenes: 0, frames: 0", exit 0)
        "validate no scene",
        lambda f: ["validate", str(f["no_scenes"])],
        ("no_scenes.json", "no scene to track", "holds none"),
    ),
    (  # (was "OK, scenes: 2, frames: 0", exit 0; with --json too)
        "validate no frames",
        lambda f: ["validate", str(f["no_frames"]), "--json"],
        ("no_frames.json", "no frames to track", "2 scene(s)"),
    ),
    (  # (was a KITTI results file of 0 lines, exit 0: a camera without a size held no box)
        "track camera without image_shape",
        lambda f: ["track", str(f["no_image_shape"]), "--out", str(f["out"]), "--kitti-results"],
        ("no_image_shape.json", "frame index 2", "CAM_FRONT.image_shape' is missing"),
    ),
    (  # (was "0 scenes, 0 frames" and an empty tracks.json, exit 0)
        "track no scene",
        lambda f: ["track", str(f["no_scenes"]), "--out", str(f["out"])],
        ("no_scenes.json", "no scene to track (the file holds none)"),
    ),
    (  # (was "2 scenes, 0 frames" and a tracks.json of empty scenes, exit 0)
        "track no frames",
        lambda f: ["track", str(f["no_frames"]), "--out", str(f["out"])],
        ("no_frames.json", "no frames to track (2 scene(s), all empty)"),
    ),
    (
        "track chosen scene without frames",
        lambda f: ["track", str(f["no_frames"]), "--scenes", "0002", "--out", str(f["out"])],
        ("no_frames.json", "no frames to track (--scenes 0002, all empty)"),
    ),
    (
        "track truncated",
        lambda f: ["track", str(f["truncated"]), "--out", str(f["out"])],
        ("truncated.json", "JSON"),
    ),
    (
        "track bad frames",
        lambda f: ["track", str(f["detections"]), "--frames", "x", "--out", str(f["out"])],
        ("--frames",),
    ),
    (  # (was "--profile maps detection_score_raw, but no box has one")
        "track frames past the input",
        lambda f: [
            *("track", str(f["detections"]), "--profile", "virconv", "--frames=1000:2000"),
            *("--out", str(f["out"])),
        ],
        ("detections.json.gz", "--frames 1000:2000", "no frame of any scene", "'0001' 0:447"),
    ),
    (
        "track negative frames",
        lambda f: ["track", str(f["detections"]), "--frames=-5:10", "--out", str(f["out"])],
        ("--frames -5:10", "start at 0"),
    ),
    (  # (was "0 frames, 0 tracks", exit 0)
        "track empty frame range",
        lambda f: ["track", str(f["detections"]), "--frames", "10:5", "--out", str(f["out"])],
        ("--frames 10:5", "selects no frame"),
    ),
    (
        "track unknown scene",
        lambda f: ["track", str(f["detections"]), "--scenes", "9999", "--out", str(f["out"])],
        ("--scenes", "9999"),
    ),
    (
        "track unknown config",
        lambda f: ["track", str(f["detections"]), "--config", "nope", "--out", str(f["out"])],
        ("nope", "kitti"),
    ),
    (
        "track bad config key",
        lambda f: ["track", str(f["detections"]), "--config", str(f["bad_toml"]), "--out", "o"],
        ("no_such_key",),
    ),
    (
        "kitti stock layout without poses",
        lambda f: ["kitti", "--kitti-root", str(f["stock"]), "--seqs", "0001", "--out", "o"],
        ("pose_orbslam3", "--poses none"),
    ),
    (
        "kitti root is the parent folder",
        lambda f: ["kitti", "--kitti-root", str(f["stock"].parent), "--out", "o"],
        ("calib", "--kitti-root"),
    ),
    (
        "kitti unknown detector",
        lambda f: [
            *("kitti", "--kitti-root", str(f["stock"]), "--seqs", "0001"),
            *("--detector", "x", "--out", "o"),
        ],
        ("--detector", "pointrcnn"),
    ),
    (
        "kitti unknown sequence",
        lambda f: ["kitti", "--kitti-root", str(f["stock"]), "--seqs", "0042", "--out", "o"],
        ("0042",),
    ),
    (
        "kitti malformed calib",
        lambda f: [
            *("kitti", "--kitti-root", str(f["bad_calib"]), "--seqs", "0001"),
            *("--no-eval", "--out", str(f["out"])),
        ],
        ("0001.txt", "P2"),
    ),
    (  # (was "label_02/0001.txt:4271: field 'frame': frame 446 is beyond the sequence's 14
        # frames": the pose lines, counted unparsed, judged the labels)
        "kitti truncated pose file",
        lambda f: [
            *("kitti", "--kitti-root", str(f["truncated_poses"]), "--seqs", "0001"),
            *("--classes", "car", "--out", str(f["out"])),
        ],
        ("pose_orbslam3/0001.txt:14", "expected 12 columns, got 7"),
    ),
    (  # (was a metrics table of its header alone, exit 0)
        "kitti a class the protocol does not score",
        lambda f: [
            *("kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001"),
            *("--classes", "truck", "--out", str(f["out"])),
        ],
        ("--classes truck", "scores only car, pedestrian, cyclist", "--no-eval"),
    ),
    (
        "convert kitti stock layout without poses",
        lambda f: ["convert", "kitti", "--kitti-root", str(f["stock"]), "--out", str(f["out"])],
        ("pose_orbslam3", "--poses none"),
    ),
    (
        "convert kitti missing pose folder",
        lambda f: [
            *("convert", "kitti", "--kitti-root", str(f["stock"])),
            *("--poses", str(f["out"] / "poses"), "--out", str(f["out"])),
        ],
        ("--poses",),
    ),
    (
        "eval truncated tracks",
        lambda f: ["eval", str(f["truncated"]), "--gt", str(f["gt"]), "--motion"],
        ("truncated.json",),
    ),
    ("eval without --gt", lambda f: ["eval", str(f["detections"])], ("--gt",)),
    (
        "eval missing labels",
        lambda f: [
            *("eval", str(f["detections"]), "--gt", str(f["gt"])),
            *("--labels", str(f["out"] / "labels"), "--out", str(f["out"])),
        ],
        ("--labels",),
    ),
    ("view truncated", lambda f: ["view", str(f["truncated"])], ("truncated.json",)),
    (  # (each was 'malformed JSON (Expecting value: line 1 column 1 (char 0))')
        "view empty file",
        lambda f: ["view", str(f["empty"])],
        ("empty.json: the file is empty (0 bytes)",),
    ),
    (
        "track empty file",
        lambda f: ["track", str(f["empty"]), "--out", str(f["out"])],
        ("empty.json: the file is empty (0 bytes)",),
    ),
    (
        "validate empty file",
        lambda f: ["validate", str(f["empty"])],
        ("empty.json: the file is empty (0 bytes)",),
    ),
    (  # (was exit 0, nothing written, nothing said)
        "view no scene",
        lambda f: ["view", str(f["no_scenes"]), "--save", str(f["out"] / "x.rrd")],
        ("no_scenes.json", "no scene to record"),
    ),
    (  # (was "scene 0001: no frames in range, skipped" per scene, exit 0)
        "view no frames",
        lambda f: ["view", str(f["no_frames"]), "--save", str(f["out"] / "x.rrd")],
        ("no_frames.json", "no frames to record", "2 scene(s)"),
    ),
    (
        "view chosen scene without frames",
        lambda f: ["view", str(f["no_frames"]), "--scenes", "0002", "--save", "x.rrd"],
        ("no_frames.json", "--scenes 0002"),
    ),
    (  # (was "scene 0001: no frames in range, skipped", exit 0)
        "view frames past the input",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "1000:2000"),
            *("--save", str(f["out"] / "x.rrd")),
        ],
        ("detections.json.gz", "--frames 1000:2000", "no frame of any scene", "'0001' 0:447"),
    ),
    (  # (was "scene 0001: not in ...; recording without ground truth", exit 0)
        "view ground truth without frames",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "0:2", "--gt", str(f["no_frames"])),
            *("--save", str(f["out"] / "x.rrd")),
        ],
        ("no_frames.json", "--gt", "no frames"),
    ),
    (
        "view missing images",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "0:2"),
            *("--images", str(f["out"] / "img"), "--save", str(f["out"] / "x.rrd")),
        ],
        ("--images",),
    ),
    (  # (was a recording without labels, exit 0, nothing said)
        "view missing labels folder",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "0:2"),
            *("--labels", str(f["out"] / "labels"), "--save", str(f["out"] / "x.rrd")),
        ],
        ("labels", "--labels folder not found"),
    ),
    (  # (was the same)
        "view labels folder without the scene's file",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "0:2"),
            *("--labels", str(f["empty_dir"]), "--save", str(f["out"] / "x.rrd")),
        ],
        ("empty_dir", "--labels", "0001.txt"),
    ),
    (  # (was "unexpected error: ValueError", exit 1, after the tracking)
        "view malformed label file",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "0:2"),
            *("--labels", str(f["bad_labels"]), "--save", str(f["out"] / "x.rrd")),
        ],
        ("bad_labels/0001.txt:1", "columns"),
    ),
    (  # (was a recording whose camera view stays dark, exit 0)
        "view images folder without images",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "0:2"),
            *("--images", str(f["empty_dir"]), "--save", str(f["out"] / "x.rrd")),
        ],
        ("--images", "empty_dir", "no images"),
    ),
    (  # (was a recording without its images, exit 0, nothing said)
        "view images of a camera the input has not",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "10:12"),
            *("--images", f"CAM_BACK={SAMPLE / 'image_02'}", "--save", str(f["out"] / "x.rrd")),
        ],
        ("--images CAM_BACK=", "detections.json.gz", "no camera 'CAM_BACK'", "CAM_FRONT)"),
    ),
    (  # (was the same)
        "view images for an input without cameras",
        lambda f: [
            *("view", str(f["no_camera"]), "--images", str(SAMPLE / "image_02")),
            *("--save", str(f["out"] / "x.rrd")),
        ],
        ("--images", "image_02", "no_camera.json has no camera"),
    ),
    (  # (was the same: the sample's images are of frames 10, 15 and 20)
        "view images of no recorded frame",
        lambda f: [
            *("view", str(f["detections"]), "--frames", "0:3"),
            *("--images", f"CAM_FRONT={SAMPLE / 'image_02'}", "--save", str(f["out"] / "x.rrd")),
        ],
        ("--images", "image_02", "no image of a recorded frame", "0..2", "frames 10..20"),
    ),
    (
        "shots not a recording",
        lambda f: ["shots", str(f["not_rrd"]), "--out", str(f["out"])],
        ("notes.rrd", "recording"),
    ),
    (
        "demo bad frames",
        lambda f: ["demo", "--frames", "1:x", "--out", str(f["out"])],
        ("--frames",),
    ),
    ("demo out is a file", lambda f: ["demo", "--out", str(f["a_file"])], ("a_file", "--out")),
    ("bench zero repeats", lambda f: ["bench", "--repeat", "0"], ("--repeat",)),
    (
        "nuscenes truncated detections",
        lambda f: [
            *("nuscenes", "--dataroot", str(f["stock"]), "--version", "v1.0-mini"),
            *("--detections", str(f["truncated"]), "--out", str(f["out"])),
        ],
        ("v1.0-mini",),
    ),
    (
        "waymo data root without ego_info",
        lambda f: [
            *("waymo", "--data-root", str(f["stock"]), "--detections", str(f["stock"])),
            *("--out", str(f["out"])),
        ],
        ("stock_kitti",),
    ),
]


@pytest.mark.parametrize(
    ("argv_of", "fragments"), [c[1:] for c in CASES], ids=[c[0] for c in CASES]
)
def test_bad_input_is_one_line_naming_the_file(
    argv_of: Callable[[F], list[str]],
    fragments: tuple[str, ...],
    files: F,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
) -> None:
    monkeypatch.chdir(tmp_path)  # relative --out folders land in the test's folder
    argv = argv_of(files)
    code, _, err = _run(argv, capsys)
    _assert_one_line_error(code, err, argv[0], *fragments)


# ---------------------------------------------------------------------------------------------
# errors: a refused run leaves --out as it found it


#: (case id, argv from the files and the output folder, an earlier run's files in that folder).
#: Each is refused (exit 2) after its command used to make --out (or an output file's folder),
#: late where it can be: a file's contents, a flag read after the kit is checked.
REFUSED: list[tuple[str, Callable[[F, Path], list[str]], tuple[str, ...]]] = [
    (
        "kitti unknown detector",
        lambda f, out: [
            *("kitti", "--kitti-root", str(f["stock"]), "--seqs", "0001", "--poses", "none"),
            *("--detector", "x", "--out", str(out)),
        ],
        ("summary.json", "tracks.json", "data/0001.txt"),
    ),
    (
        "kitti bad config",
        lambda f, out: [
            *("kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001"),
            *("--config", str(f["bad_toml"]), "--out", str(out)),
        ],
        ("summary.json", "tracks.json", "data/0001.txt"),
    ),
    (
        "robustness malformed detections",
        lambda f, out: [
            *("robustness", "--kitti-root", str(f["bad_detections"]), "--seqs", "0001"),
            *("--levels", "noise", "--seeds", "0", "--out", str(out)),
        ],
        ("robustness.json", "robustness.md", "runs/noise/seed0/0001.txt"),
    ),
    (
        "track bad frames",
        lambda f, out: ["track", str(f["detections"]), "--frames", "x", "--out", str(out)],
        ("summary.json", "tracks.json"),
    ),
    (
        "nuscenes truncated detections",
        lambda f, out: [
            *("nuscenes", "--dataroot", str(f["stock"]), "--version", "v1.0-mini"),
            *("--detections", str(f["truncated"]), "--out", str(out)),
        ],
        ("summary.json", "results.json", "tracks.json"),
    ),
    (
        "waymo data root without ego_info",
        lambda f, out: [
            *("waymo", "--data-root", str(f["stock"]), "--detections", str(f["stock"])),
            *("--out", str(out)),
        ],
        ("summary.json", "tracks.json", "results/0/x.npz"),
    ),
    (
        "convert kitti without poses",
        lambda f, out: ["convert", "kitti", "--kitti-root", str(f["stock"]), "--out", str(out)],
        ("detections.json", "gt.json"),
    ),
    (
        "convert nuscenes truncated detections",
        lambda f, out: [
            *("convert", "nuscenes", "--dataroot", str(f["stock"]), "--version", "v1.0-mini"),
            *("--detections", str(f["truncated"]), "--out", str(out / "d.json")),
            *("--gt-out", str(out / "gt" / "gt.json")),
        ],
        ("d.json", "gt/gt.json"),
    ),
    (
        "convert waymo data root without ego_info",
        lambda f, out: [
            *("convert", "waymo", "--data-root", str(f["stock"]), "--detections", str(f["stock"])),
            *("--out", str(out / "d.json")),
        ],
        ("d.json",),
    ),
    (
        "eval malformed label file",
        lambda f, out: [
            *("eval", str(f["detections"]), "--gt", str(f["gt"])),
            *("--labels", str(f["bad_labels"]), "--out", str(out)),
        ],
        ("eval.json", "eval.md"),
    ),
    (  # (refused after it made --out itself: its outputs_removed_on_failure removes --out and
        # the folders on the way to it, before the CLI's own clean-up would)
        "eval nuscenes tracks without sample tokens",
        lambda f, out: [
            *("eval", str(f["detections"]), "--dataset", "nuscenes"),
            *("--dataroot", str(f["stock"]), "--out", str(out)),
        ],
        ("eval.json", "eval.md", "eval_results.json", "nuscenes_eval/metrics_summary.json"),
    ),
    (
        "tune too few sequences",
        lambda f, out: [
            *("tune", "--kitti-root", str(f["stock"]), "--seqs", "0001", "--folds", "2"),
            *("--out", str(out)),
        ],
        ("tune.json", "best.toml"),
    ),
    (
        "calibrate unknown detector",
        lambda f, out: [
            *("calibrate", "--kitti-root", str(f["stock"]), "--seqs", "0001"),
            *("--detector", "x", "--out", str(out / "x.toml")),
        ],
        ("x.toml",),
    ),
    (
        "compare folders no run wrote",
        lambda f, out: ["compare", str(f["empty_dir"]), str(f["empty_dir"]), "--out", str(out)],
        ("compare.json", "compare.md"),
    ),
    (
        "report folder no run wrote",
        lambda f, out: ["report", str(f["empty_dir"]), "--out", str(out)],
        ("index.html", "plots/hota.svg"),
    ),
    (
        "demo bad frames",
        lambda f, out: ["demo", "--frames", "1:x", "--out", str(out)],
        ("demo.rrd",),
    ),
    (
        "view no frames",
        lambda f, out: ["view", str(f["no_frames"]), "--save", str(out / "x.rrd")],
        ("x.rrd",),
    ),
    (
        "shots not a recording",
        lambda f, out: ["shots", str(f["not_rrd"]), "--out", str(out)],
        ("event0_f10_3d.png",),
    ),
    (
        "bench missing kit",
        lambda f, out: [
            *("bench", "--kitti-root", str(f["out"] / "no_kit"), "--repeat", "1"),
            *("--json", str(out / "bench.json")),
        ],
        ("bench.json",),
    ),
]


def _tree(folder: Path) -> dict[str, bytes | None]:
    """Every file (its bytes) and folder (None) under ``folder``, by relative path."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes() if p.is_file() else None
        for p in folder.rglob("*")
    }


def test_every_command_that_writes_has_a_refused_case() -> None:
    """A command that gains an output option (cli.OUTPUT_OPTIONS) gets a case above."""
    writing = [
        " ".join(words)
        for words, parser in COMMANDS
        if any(
            set(a.option_strings) & set(cli.OUTPUT_OPTIONS) and a.nargs != 0  # (not a flag)
            for a in parser._actions
        )
    ]
    assert len(writing) >= 15
    for command in writing:
        assert any(case[0].startswith(f"{command} ") for case in REFUSED), command


@pytest.mark.parametrize(
    ("argv_of", "earlier"), [c[1:] for c in REFUSED], ids=[c[0] for c in REFUSED]
)
def test_a_refused_run_leaves_no_folder_it_made(
    argv_of: Callable[[F, Path], list[str]],
    earlier: tuple[str, ...],
    files: F,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """(each left its --out behind, empty, or the folder of its output file: the folders on
    the way to it too)"""
    monkeypatch.chdir(tmp_path)
    new = tmp_path / "new"
    code, _, err = _run(argv_of(files, new / "deeper" / "out"), capsys)
    assert code == 2, err
    assert not new.exists(), sorted(_tree(new))


@pytest.mark.parametrize(
    ("argv_of", "earlier"), [c[1:] for c in REFUSED], ids=[c[0] for c in REFUSED]
)
def test_a_refused_run_keeps_an_earlier_runs_outputs(
    argv_of: Callable[[F, Path], list[str]],
    earlier: tuple[str, ...],
    files: F,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """An earlier run's outputs go only once the new run's inputs are accepted."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "earlier"
    for name in earlier:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        run = name == "summary.json"  # (a run's says so: its folder's files are replaced)
        (out / name).write_text('{"command": "track"}\n' if run else "an earlier run's\n")
    (out / "notes.txt").write_text("mine\n")
    before = _tree(out)
    code, _, err = _run(argv_of(files, out), capsys)
    assert code == 2, err
    assert _tree(out) == before


def test_only_the_empty_folders_a_run_made_are_removed(tmp_path: Path) -> None:
    """Not a folder that was there before, nor one that holds a file (and so not its parents);
    an output file's folders are made for it too."""
    from app.common import folders_to_make, remove_made_folders

    (tmp_path / "there").mkdir()
    outputs = [tmp_path / "there", tmp_path / "a" / "b" / "out", tmp_path / "c" / "d" / "x.json"]
    made = folders_to_make([*outputs, tmp_path / "a" / "kept"])
    assert made[-2:] == [tmp_path / "a", tmp_path / "c"] and tmp_path / "there" not in made
    for folder in outputs[:2]:
        folder.mkdir(parents=True, exist_ok=True)
    (tmp_path / "c" / "d").mkdir(parents=True)
    (tmp_path / "a" / "kept").mkdir()
    (tmp_path / "a" / "kept" / "partial.txt").write_text("x")
    remove_made_folders(made)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "there"]
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["kept"]


def test_a_failed_block_removes_the_outputs_it_wrote_only(tmp_path: Path) -> None:
    """outputs_removed_on_failure: the files of its globs that the block wrote (new, or
    rewritten) go with the folders it made for them (and a library's, named); files it did not
    touch stay, matching or not, and so does a folder that was there; on success, all stay."""
    from app.common import outputs_removed_on_failure

    out = tmp_path / "out"
    (out / "recordings").mkdir(parents=True)
    for name in ("kept.json", "rewritten.json", "recordings/mine.rrd", "notes.txt"):
        (out / name).write_text("there before\n")
    patterns = ("*.json", "recordings/*.rrd", "eval/*.json")
    with pytest.raises(InputError), outputs_removed_on_failure(out, patterns, ["eval/plots"]):
        (out / "rewritten.json").write_text("the run's\n")
        (out / "results.json").write_text("the run's\n")
        (out / "recordings" / "a.rrd").write_text("the run's\n")
        (out / "eval" / "plots").mkdir(parents=True)
        (out / "eval" / "metrics.json").write_text("the run's\n")
        raise InputError("refused after writing")
    assert _tree(out) == {
        "kept.json": b"there before\n",
        "notes.txt": b"there before\n",
        "recordings": None,
        "recordings/mine.rrd": b"there before\n",
    }
    with outputs_removed_on_failure(out, patterns):
        (out / "results.json").write_text("the run's\n")
    assert (out / "results.json").is_file()


def test_a_failed_block_keeps_an_empty_folder_that_was_there(tmp_path: Path) -> None:
    """results/ there before (empty) and results/vehicle/ made by the run for
    results/*/*.npz: only the folder the run made goes; results/ was removed too."""
    from app.common import outputs_removed_on_failure

    out = tmp_path / "out"
    (out / "results").mkdir(parents=True)
    (out / "runs" / "a" / "clean").mkdir(parents=True)
    patterns = ("results/*/*.npz", "runs/*/clean/*.txt")
    with pytest.raises(InputError), outputs_removed_on_failure(out, patterns):
        (out / "results" / "vehicle").mkdir()
        (out / "results" / "vehicle" / "seg.npz").write_text("the run's\n")
        (out / "runs" / "a" / "clean" / "0001.txt").write_text("the run's\n")
        raise InputError("refused after writing")
    assert _tree(out) == {"results": None, "runs": None, "runs/a": None, "runs/a/clean": None}


def test_a_run_that_fails_without_an_exception_leaves_no_folder_it_made(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """(a status of its own, as `mctrack shots` returns when the viewer fails)"""
    import app.shots

    def viewer_failed(args: argparse.Namespace) -> int:
        Path(args.out).mkdir(parents=True)
        return app.shots.EXIT_VIEWER_FAILED

    monkeypatch.setattr(app.shots, "run", viewer_failed)
    code, _, _ = _run(["shots", "x.rrd", "--out", str(tmp_path / "new" / "shots")], capsys)
    assert code == app.shots.EXIT_VIEWER_FAILED and not (tmp_path / "new").exists()


def test_bench_refuses_a_bad_json_path_before_the_benchmark(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """(was: after the whole benchmark, naming its temporary file: "/x/.out.123.tmp: is a
    folder, expected a file")"""
    monkeypatch.setenv("MCTRACK_KITTI_ROOT", str(tmp_path / "no_kit"))  # synthetic cases only
    folder = tmp_path / "results"
    folder.mkdir()
    code, out, err = _run(
        ["bench", "--repeat", "1", "--frames", "2", "--json", str(folder)], capsys
    )
    _assert_one_line_error(code, err, "bench", f"--json {folder}: is a folder")
    assert "synthetic" not in out  # refused before any case ran


def test_eval_refuses_a_bad_out_before_evaluating(
    files: F, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """(was: after the evaluation, when eval.json or the velocity plot was written)"""
    import app.eval

    def evaluated(*args: object, **kwargs: object) -> None:
        raise AssertionError("evaluated before --out was checked")

    monkeypatch.setattr(app.eval, "evaluate_tracks", evaluated)
    argv = ["eval", str(files["gt"]), "--gt", str(files["gt"]), "--motion"]  # (ids: tracks)
    code, _, err = _run([*argv, "--out", str(files["a_file"])], capsys)
    _assert_one_line_error(code, err, "eval", f"--out {files['a_file']}: exists and is not a")


# ---------------------------------------------------------------------------------------------
# the console script: exit status, no traceback, --debug


def _mctrack(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "app.cli", *argv],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
        check=False,
    )


def test_console_exit_status_and_debug_traceback(tmp_path: Path) -> None:
    missing = str(tmp_path / "missing.json")
    plain = _mctrack("validate", missing)
    assert plain.returncode == 2
    assert plain.stderr.strip().splitlines() == [
        f"mctrack validate: error: {missing}: file not found"
    ]
    debug = _mctrack("validate", missing, "--debug")
    # the traceback, then the same line and exit status (was 1: the error was raised again)
    assert debug.returncode == 2, debug.stderr
    assert "Traceback" in debug.stderr and "InputError" in debug.stderr
    assert debug.stderr.strip().splitlines()[-1] == plain.stderr.strip()
    before = _mctrack("--debug", "track", missing, "--out", str(tmp_path / "x"))
    assert before.returncode == 2 and "Traceback" in before.stderr, before.stderr
    assert not (tmp_path / "x").exists()  # (the folder the run made is removed, as without it)


def test_unexpected_errors_are_one_line_with_exit_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from app import validate

    def broken(args: argparse.Namespace) -> int:
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(validate, "run", broken)
    code, _, err = _run(["validate", "x.json"], capsys)
    assert code == 1 and "Traceback" not in err
    assert err.strip() == (
        "mctrack validate: unexpected error: ZeroDivisionError: boom (a bug: re-run with "
        "--debug for the traceback and report it)"
    )
    with pytest.raises(ZeroDivisionError):
        main(["--debug", "validate", "x.json"])


# ---------------------------------------------------------------------------------------------
# runs that succeed but must say something


def test_kitti_without_poses_says_so_and_shows_classes_without_ground_truth_as_absent(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    stock = tmp_path / "stock"
    shutil.copytree(SAMPLE_KIT, stock, ignore=shutil.ignore_patterns("pose_orbslam3"))
    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(stock), "--seqs", "0001", "--poses", "none"]
    code, printed, err = _run([*argv, "--out", str(out)], capsys)
    assert code == 0, err
    assert "--poses none" in err and "relative to the moving ego vehicle" in err
    summary = json.loads((out / "summary.json").read_text())
    # sequence 0001 has no cyclist: its scores would only count false positives
    assert set(summary["metrics"]) == {"car", "pedestrian"}
    assert list(summary["metrics_absent"]) == ["cyclist"]
    assert "cyclist" in printed and "absent: no ground-truth cyclist" in printed
    assert "-200" not in printed


def test_a_frame_range_that_empties_some_scenes_warns_and_tracks_the_rest(
    caplog: pytest.LogCaptureFixture,
) -> None:
    from app.track import select_scenes

    scenes = {"long": list(range(10)), "short": list(range(3))}  # (frames: only counted)
    with caplog.at_level(logging.WARNING):
        chosen = select_scenes(scenes, None, slice(5, 8), source="in.json")  # type: ignore[arg-type]
    assert chosen == {"long": [5, 6, 7], "short": []}
    assert "in.json: --frames 5:8 selects no frame of 1 scene(s): 'short' 0:3" in caplog.text
    with pytest.raises(InputError, match="no frame of any scene"):
        select_scenes(scenes, None, slice(20, 30), source="in.json")  # type: ignore[arg-type]


def test_track_writes_nothing_for_an_input_without_frames(
    files: F, capsys: pytest.CaptureFixture[str]
) -> None:
    """An input without frames is refused before any output: no tracks.json of nothing."""
    for name in ("no_scenes", "no_frames"):
        code, printed, _ = _run(["track", str(files[name]), "--out", str(files["out"])], capsys)
        assert code == 2 and printed == ""
        assert not files["out"].exists()  # (was left behind, empty)


def test_view_says_which_scenes_it_records_without_labels(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--labels with a label file for some scenes only: the others are recorded without, and
    say so (they were silently left without KITTI matching)."""
    import gzip

    frames = json.loads(gzip.decompress((SAMPLE / "detections.json.gz").read_bytes()))["0001"]
    two = tmp_path / "two.json"
    two.write_text(json.dumps({"0001": frames[:3], "0002": frames[:3]}))
    labels = tmp_path / "labels"
    labels.mkdir()
    shutil.copy(SAMPLE / "raw" / "training" / "label_02" / "0001.txt", labels)
    argv = ["view", str(two), "--labels", str(labels), "--no-motion"]
    code, printed, err = _run([*argv, "--save", str(tmp_path / "x.rrd")], capsys)
    assert code == 0, err
    assert f"scene 0002: no label file in {labels}; recording without its labels" in printed
    assert "scene 0001: no label file" not in printed
    # (the ID events by TrackEval's KITTI protocol: per class, for the labelled scene alone)
    assert "scene 0001: 3 frames" in printed and "car: 0 ID switches" in printed
    assert "scene 0002: 3 frames" in printed and "car:" not in printed.split("scene 0002: 3")[1]


def test_view_records_a_scene_whose_label_file_is_empty_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An empty label file is a scene without labelled objects (valid KITTI; `mctrack eval`
    scores it): the recording is made, and a line says the scene has no labels."""
    labels = tmp_path / "labels"
    labels.mkdir()
    (labels / "0001.txt").write_bytes(b"")
    argv = ["view", str(SAMPLE / "detections.json.gz"), "--frames", "0:2", "--no-motion"]
    code, printed, err = _run([*argv, "--labels", str(labels), "--save", str(tmp_path / "x.rrd")],
                              capsys)  # fmt: skip
    assert code == 0, err
    assert f"scene 0001: {labels / '0001.txt'} holds no labels" in printed
    assert (tmp_path / "x.rrd").is_file()


def test_view_says_which_scenes_it_records_without_images(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--images with images of one scene's frames only: the other is recorded without, and
    says so (as a scene without labels); the images are recorded for the scene they fit."""
    frames = _sample_frames()
    two = tmp_path / "two.json"
    two.write_text(json.dumps({"early": frames[:3], "late": frames[9:12]}))  # images: 10
    path = tmp_path / "x.rrd"
    argv = ["view", str(two), "--images", str(SAMPLE / "image_02"), "--no-motion"]
    code, printed, err = _run([*argv, "--save", str(path)], capsys)
    assert code == 0, err
    image_02 = SAMPLE / "image_02"
    assert f"scene early: no image of its frames in {image_02}; recording without them" in printed
    assert "scene late: no image" not in printed
    from rerun.chunk import RrdReader

    for scene, has_images in (("early", False), ("late", True)):
        chunks = RrdReader(str(tmp_path / f"x_{scene}.rrd")).stream().to_chunks()
        entities = {str(c.entity_path) for c in chunks}
        assert ("/cameras/CAM_FRONT/image" in entities) is has_images, scene


def test_view_of_several_scenes_that_fails_on_a_later_one_leaves_no_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A run of two scenes that fails on the second leaves neither scene's recording: a folder
    where the second's goes is refused (naming it) before any recording, an earlier recording
    at the first scene's path kept; Ctrl-C while the second records leaves no recording, no
    temporary file and no folder of its own."""
    frames = _sample_frames()[:3]
    two = tmp_path / "two.json"
    two.write_text(json.dumps({"a": frames, "b": frames}))
    out = tmp_path / "out"
    (out / "x_b.rrd").mkdir(parents=True)
    (out / "x_a.rrd").write_text("an earlier recording\n")
    argv = ["view", str(two), "--no-motion", "--save", str(out / "x.rrd")]
    code, printed, err = _run(argv, capsys)
    _assert_one_line_error(code, err, "view", f"{out / 'x_b.rrd'}: is a folder")
    assert "wrote" not in printed
    assert _tree(out) == {"x_a.rrd": b"an earlier recording\n", "x_b.rrd": None}

    import viz.record

    recorded = []

    def stopped_on_the_second(*args: object, **kwargs: object) -> object:
        if recorded:
            raise KeyboardInterrupt
        recorded.append(record_scene(*args, **kwargs))
        return recorded[-1]

    record_scene = viz.record.record_scene
    monkeypatch.setattr(viz.record, "record_scene", stopped_on_the_second)
    new = tmp_path / "new"
    code, _, err = _run([*argv[:-1], str(new / "x.rrd")], capsys)
    assert code == 130 and "interrupted" in err and recorded
    assert not new.exists()


@pytest.mark.parametrize("scenes", [("0001",), ("a", "b")])
def test_view_refuses_a_folder_at_a_recordings_path_before_recording(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    scenes: tuple[str, ...],
) -> None:
    """--save naming a folder (or, with several scenes, a folder at one scene's file name) is
    one line naming it before any scene is tracked (every scene was recorded first, then the
    run failed)."""
    import viz.record

    frames = _sample_frames()[:3]
    data = tmp_path / "in.json"
    data.write_text(json.dumps(dict.fromkeys(scenes, frames)))
    out = tmp_path / "out"
    folder = out / ("x.rrd" if len(scenes) == 1 else f"x_{scenes[-1]}.rrd")
    folder.mkdir(parents=True)
    recorded: list[object] = []
    monkeypatch.setattr(viz.record, "record_scene", lambda *a, **k: recorded.append(a))
    argv = ["view", str(data), "--no-motion", "--save", str(out / "x.rrd")]
    code, printed, err = _run(argv, capsys)
    _assert_one_line_error(code, err, "view", f"--save {folder}: is a folder, expected a file")
    assert printed == "" and not recorded
    assert _tree(out) == {folder.name: None}


@pytest.mark.parametrize("scenes", [("0001",), ("0001", "0006")])
def test_view_refuses_save_naming_a_folder_however_many_scenes(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    scenes: tuple[str, ...],
) -> None:
    """--save DIR, an existing folder, is one line naming it before the input is read, with
    several scenes too: they were recorded beside it, as extension-less DIR_0001, DIR_0006."""
    import tracker.io.baseversion

    data = tmp_path / "in.json"
    data.write_text(json.dumps(dict.fromkeys(scenes, _sample_frames()[:3])))
    folder = tmp_path / "conv"
    folder.mkdir()
    read: list[object] = []
    real = tracker.io.baseversion.read_baseversion

    def reading(*args: object, **kwargs: object) -> object:
        read.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(tracker.io.baseversion, "read_baseversion", reading)
    code, printed, err = _run(["view", str(data), "--no-motion", "--save", str(folder)], capsys)
    _assert_one_line_error(code, err, "view", f"--save {folder}: is a folder, expected a file")
    assert printed == "" and not read
    assert sorted(p.name for p in tmp_path.iterdir()) == ["conv", "in.json"]


@pytest.mark.parametrize(
    ("save", "named"), [("conv", "conv.rrd"), ("conv.RRD", "conv.rrd"), ("run.v2", "run.v2.rrd")]
)
@pytest.mark.parametrize("scenes", [("0001",), ("0001", "0006")])
def test_view_refuses_save_without_the_rrd_suffix(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    scenes: tuple[str, ...],
    save: str,
    named: str,
) -> None:
    """--save conv wrote a recording named conv (conv_0001, conv_0006 with several scenes),
    which `mctrack inspect --list` of its folder and a file dialog do not take for one, exit 0:
    now one line naming the option and a name that works, before the input is read."""
    import tracker.io.baseversion

    monkeypatch.chdir(tmp_path)
    data = tmp_path / "in.json"
    data.write_text(json.dumps(dict.fromkeys(scenes, _sample_frames()[:3])))
    monkeypatch.setattr(
        tracker.io.baseversion, "read_baseversion", lambda *a, **k: pytest.fail("read")
    )
    code, printed, err = _run(["view", str(data), "--no-motion", "--save", save], capsys)
    _assert_one_line_error(
        code, err, "view", f"--save {save}: a recording file's name ends in .rrd (e.g. {named})"
    )
    assert printed == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.json"]


@pytest.mark.parametrize("bad", ["broken link", "folder"])
@pytest.mark.parametrize("given", ["--images", "image_02 beside the input"])
def test_view_refuses_an_unreadable_image_of_a_recorded_frame(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bad: str, given: str
) -> None:
    """An image file of a recorded frame that cannot be read (a broken link, a folder by an
    image's name) is one line naming it, before any recording (Rerun warned, the frame went
    without its image, exit 0); the same file at a frame outside --frames is not read."""
    data = tmp_path / "kit"
    shutil.copytree(SAMPLE / "image_02", data / "image_02")  # images of frames 10, 15, 20
    shutil.copy(SAMPLE / "detections.json.gz", data)
    image = data / "image_02" / "000012.png"
    if bad == "broken link":
        image.symlink_to(data / "image_02" / "missing.png")
    else:
        image.mkdir()
    why = "a link to a missing file" if bad == "broken link" else "Is a directory"
    argv = ["view", str(data / "detections.json.gz"), "--no-motion"]
    if given == "--images":
        argv += ["--images", str(data / "image_02")]
    path = tmp_path / "x.rrd"
    code, printed, err = _run([*argv, "--frames", "8:14", "--save", str(path)], capsys)
    _assert_one_line_error(
        code, err, "view", f"{image}: image of frame 12 (camera CAM_FRONT) cannot be read: {why}"
    )
    assert printed == "" and not path.exists()
    code, printed, err = _run([*argv, "--frames", "8:12", "--save", str(path)], capsys)
    assert code == 0 and path.is_file(), err


@pytest.mark.parametrize("bad", ["truncated PNG", "truncated JPEG", "not an image"])
def test_view_refuses_an_image_that_does_not_decode(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bad: str
) -> None:
    """An image of a recorded frame that reads but does not decode (a PNG or JPEG cut short,
    which still opens; bytes that are no image) is one line naming it, before any recording
    (the viewer showed nothing for that frame, exit 0); outside --frames it is not decoded."""
    from PIL import Image

    data = tmp_path / "kit"
    shutil.copytree(SAMPLE / "image_02", data / "image_02")  # images of frames 10, 15, 20
    shutil.copy(SAMPLE / "detections.json.gz", data)
    good = data / "image_02" / "000010.png"
    image = data / "image_02" / ("000012.jpg" if bad == "truncated JPEG" else "000012.png")
    if bad == "not an image":
        image.write_text("not an image\n")
    else:
        with Image.open(good) as im:
            im.convert("RGB").save(image, format="JPEG" if bad == "truncated JPEG" else "PNG")
        body = image.read_bytes()
        image.write_bytes(body[: len(body) // 2])
        with Image.open(image) as im:  # it opens (its header is whole)
            assert im.size == (1242, 375)
    argv = ["view", str(data / "detections.json.gz"), "--no-motion"]
    path = tmp_path / "x.rrd"
    code, printed, err = _run([*argv, "--frames", "8:14", "--save", str(path)], capsys)
    prefix = f"{image}: image of frame 12 (camera CAM_FRONT) cannot be decoded: "
    assert err.startswith("mctrack view: error: " + prefix), err
    _assert_one_line_error(code, err, "view", err.split("error: ", 1)[1].rstrip("\n"))
    assert printed == "" and not path.exists()
    code, printed, err = _run([*argv, "--frames", "8:12", "--save", str(path)], capsys)
    assert code == 0 and path.is_file(), err


@pytest.mark.parametrize("bad", ["truncated PNG", "broken link"])
def test_kitti_record_leaves_out_an_image_it_cannot_show(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
    bad: str,
) -> None:
    """kitti --record logged a camera image of image_02 that does not decode (a PNG cut short,
    which still opens) as it was: the viewer showed nothing at that frame, exit 0, without a
    word (a broken link: Rerun only warned). It is left out of the recording, named in a
    warning and in summary.json; the run and the other images go on."""
    from tests.test_viz import entity_table
    from viz import paths

    kit = tmp_path / "kit"
    shutil.copytree(SAMPLE_KIT, kit)
    images = kit / "training" / "image_02" / "0001"
    shutil.copytree(SAMPLE / "image_02", images)  # images of frames 10, 15, 20
    if bad == "truncated PNG":
        image, frame = images / "000015.png", 15
        body = image.read_bytes()
        image.write_bytes(body[: len(body) // 2])
        why = "cannot be decoded: "
    else:
        image, frame = images / "000012.png", 12
        image.symlink_to(images / "missing.png")
        why = "cannot be read: a link to a missing file"
    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(kit), "--seqs", "0001", "--record", "--out", str(out)]
    with caplog.at_level(logging.WARNING):
        code, _, err = _run(argv, capsys)
    assert code == 0, err
    (line,) = json.loads((out / "summary.json").read_text())["recording_skipped_images"]["0001"]
    assert line.startswith(f"{image}: image of frame {frame} (camera CAM_FRONT) {why}"), line
    assert f"recording 0001: without {line}" in caplog.text
    table = entity_table(out / "recordings" / "0001.rrd", paths.camera_image("CAM_FRONT"))
    frames = table[paths.FRAME].to_pylist()
    opacity = table["EncodedImage:opacity"].to_pylist()
    shown = {f for f, o in zip(frames, opacity, strict=True) if o and o[0] == 1.0}
    assert shown == {10, 15, 20} - {frame}


def test_view_refuses_two_image_folders_for_one_camera(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two --images folders for the same camera: one usage error naming both, before any
    recording (the last one was used, without a word). A folder without CAMERA= is the first
    camera's, so it repeats --images CAM_FRONT=... on the sample."""
    image_02 = SAMPLE / "image_02"
    other = tmp_path / "other_images"
    shutil.copytree(image_02, other)
    argv = ["view", str(SAMPLE / "detections.json.gz"), "--frames", "10:12", "--no-motion"]
    for images, said in (
        (["CAM_FRONT=" + str(image_02), "CAM_FRONT=" + str(other)], ""),
        ([str(image_02), "CAM_FRONT=" + str(other)],
         " (without CAMERA=: scene 0001's first camera)"),
        ([str(image_02), str(other)], " (without CAMERA=: scene 0001's first camera)"),
    ):  # fmt: skip
        path = tmp_path / "x.rrd"
        options = [word for folder in images for word in ("--images", folder)]
        code, printed, err = _run([*argv, *options, "--save", str(path)], capsys)
        _assert_one_line_error(
            code,
            err,
            "view",
            f"--images: camera 'CAM_FRONT' given twice, {image_02} and {other}{said}: give one "
            "folder per camera",
        )
        assert printed == "" and not list(tmp_path.glob("*.rrd*")), images


def test_kitti_into_an_earlier_runs_folder_replaces_that_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A sequence the new run leaves out does not keep its old results beside the new ones;
    files the runs do not write stay, and a run refused on its inputs changes nothing."""
    from app.outputs import FILES
    from tracker.eval.motion_eval import MOTION_PLOT

    assert MOTION_PLOT in FILES["kitti"]
    out = tmp_path / "out"
    (out / "data").mkdir(parents=True)
    (out / "recordings").mkdir()
    for earlier in ("data/0099.txt", "recordings/0099.rrd", "motion.md",
                    "recordings/.0099.rrd.123.abc.tmp"):  # (a run stopped by Ctrl-C)  # fmt: skip
        (out / earlier).write_text("an earlier run's\n")
    # (a run's: it says so, and which files it wrote, as a --record run's summary does)
    earlier_summary = json.dumps(
        {"command": "kitti", "sequences": ["0099"], "recordings": {"0099": "r/recordings/0099.rrd"}}
    )
    (out / "summary.json").write_text(earlier_summary)
    (out / "notes.txt").write_text("mine\n")
    (out / ".notes.tmp").write_text("mine\n")
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--out", str(out)]
    bad = tmp_path / "bad.toml"  # refused once read, as a bad --profile is
    bad.write_text('base = "kitti"\n[category.car]\nscore_min = 1.5\n')
    for refused in (["--detector", "nope"], ["--config", str(bad)]):
        code, _, err = _run([*argv, *refused], capsys)
        assert code == 2 and (out / "data" / "0099.txt").is_file(), err
        assert (out / "summary.json").read_text() == earlier_summary
    code, _, err = _run(argv, capsys)
    assert code == 0, err
    assert sorted(p.name for p in (out / "data").iterdir()) == ["0001.txt"]
    assert not (out / "recordings" / "0099.rrd").exists() and not (out / "motion.md").exists()
    assert not (out / "recordings").exists()  # the temporary file too, then the empty folder
    assert (out / ".notes.tmp").read_text() == "mine\n"  # a hidden file of another name stays
    assert (out / "notes.txt").read_text() == "mine\n"
    assert json.loads((out / "summary.json").read_text())["sequences"] == ["0001"]


def test_kitti_refused_after_the_tracking_leaves_no_partial_outputs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The motion metrics refusing after the tracking (an InputError, exit 2) into an earlier
    run's --out: the run's own outputs go too (data/*.txt, tracks.json and the recordings were
    left without the summary.json that marks a complete run, the earlier run's outputs already
    removed); files of other names stay. Into a new --out: nothing is left."""
    import tracker.eval.motion_eval

    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001"]
    code, _, err = _run([*argv, "--no-eval", "--out", str(out)], capsys)
    assert code == 0 and (out / "summary.json").is_file(), err
    (out / "notes.txt").write_text("mine\n")

    def refuse(*args: object, **kwargs: object) -> None:
        raise InputError("refused by the motion metrics")

    monkeypatch.setattr(tracker.eval.motion_eval, "evaluate_motion", refuse)
    code, _, err = _run([*argv, "--motion", "--record", "--out", str(out)], capsys)
    _assert_one_line_error(code, err, "kitti", "refused by the motion metrics")
    assert _tree(out) == {"notes.txt": b"mine\n"}
    new = tmp_path / "new"
    code, _, err = _run([*argv, "--motion", "--out", str(new / "out")], capsys)
    assert code == 2 and not new.exists(), err


def test_track_into_an_earlier_runs_folder_replaces_that_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """track --kitti-results into the --out of a run of more scenes: the scene the new run
    leaves out does not keep its data/<scene>.txt beside the new ones (nor the earlier
    --profile self's self_profile.toml); files of other names stay, and a run refused on its
    inputs changes nothing."""
    frames = _sample_frames()[:3]
    two, one = tmp_path / "two.json", tmp_path / "one.json"
    two.write_text(json.dumps({"a": frames, "b": frames}))
    one.write_text(json.dumps({"a": frames}))
    out = tmp_path / "out"
    code, _, err = _run(["track", str(two), "--kitti-results", "--profile", "self",
                         "--out", str(out)], capsys)  # fmt: skip
    assert code == 0, err
    (out / "notes.txt").write_text("mine\n")
    earlier = _tree(out)
    assert {"data/a.txt", "data/b.txt", "self_profile.toml"} <= set(earlier)
    argv = ["track", str(one), "--kitti-results", "--out", str(out)]
    code, _, err = _run([*argv, "--frames", "x"], capsys)
    assert code == 2 and _tree(out) == earlier, err
    code, _, err = _run(argv, capsys)
    assert code == 0, err
    assert sorted(_tree(out)) == ["data", "data/a.txt", "notes.txt", "summary.json", "tracks.json"]
    assert (out / "notes.txt").read_text() == "mine\n"
    listed = [o["path"] for o in json.loads((out / "summary.json").read_text())["outputs"]]
    assert listed == ["data/a.txt", "tracks.json"]


def test_track_into_a_kitti_runs_folder_leaves_nothing_of_that_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A track run into a kitti run's folder removed only the outputs track writes: kitti's
    motion.md, velocity PNG, recordings and self_profile.toml, and an evaluation of its tracks,
    stayed beside the new tracks (the folder mixed two runs). Now every command's outputs of
    a run folder go (one list per command, app/outputs.py); files of other names stay."""
    from app.common import _outputs
    from app.outputs import FILES, outputs_of

    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--motion", "--record",
            "--profile", "self", "--out", str(out)]  # fmt: skip
    code, _, err = _run(argv, capsys)
    assert code == 0, err
    kitti_files = {p for p, data in _tree(out).items() if data is not None}
    assert {"motion.md", "recordings/0001.rrd", "self_profile.toml"} <= kitti_files
    # every file the kitti run wrote is one of its listed outputs
    assert {p.relative_to(out).as_posix() for p in _outputs(out, outputs_of("kitti"))} == (
        kitti_files
    )
    for name in FILES["eval"][:2]:  # `mctrack eval OUT/tracks.json` writes beside the run's
        (out / name).write_text("an evaluation of the kitti run's tracks\n")
    (out / "notes.txt").write_text("mine\n")
    detections = tmp_path / "one.json"
    detections.write_text(json.dumps({"a": _sample_frames()[:3]}))
    code, _, err = _run(["track", str(detections), "--out", str(out)], capsys)
    assert code == 0, err
    assert sorted(_tree(out)) == ["notes.txt", "summary.json", "tracks.json"]
    assert (out / "notes.txt").read_text() == "mine\n"


def test_the_output_lists_name_the_files_and_temporary_files_written(tmp_path: Path) -> None:
    """The one list per command (app/outputs.py) holds the names the commands write under, and
    brings each file's temporary files (tracker.io.fileio.temp_name) with it."""
    from app.common import _outputs
    from app.eval import EVAL_SUBMISSION
    from app.outputs import FILES, RUN_COMMANDS, RUN_PARTS, outputs_of
    from app.scenes import PARTS_DIR
    from tracker.eval.motion_eval import MOTION_PLOT
    from tracker.io.fileio import temp_name

    assert RUN_PARTS == PARTS_DIR
    assert EVAL_SUBMISSION in FILES["eval"] and MOTION_PLOT in FILES["eval"]
    assert all(f"{PARTS_DIR}/*" in FILES[command] for command in RUN_COMMANDS)
    result = tmp_path / "data" / "0001.txt"
    temp = result.parent / f"{temp_name(result)}abc123.tmp"
    part = tmp_path / PARTS_DIR / f".000001.json.{os.getpid()}.abc.tmp"
    for path in (result, temp, part):
        path.parent.mkdir(exist_ok=True)
        path.write_text("x")
    assert _outputs(tmp_path, outputs_of("track")) == {result, temp, part}


def test_only_a_runs_summary_or_scene_parts_make_a_folder_a_runs(tmp_path: Path) -> None:
    """A results.json (or tracks.json) alone could be anyone's: only a summary.json naming a
    run's command (or, written before that field, holding a run's detection_fates), or a
    run's scene parts folder, make a run folder whose files a new run removes."""
    from app.outputs import holds_a_run

    def holds(name: str, text: str) -> bool:
        folder = tmp_path / str(len(list(tmp_path.iterdir())))
        folder.mkdir()
        (folder / name).write_text(text)
        return holds_a_run(folder)

    assert not holds("results.json", "{}") and not holds("tracks.json", "{}")
    assert not holds("summary.json", "{}") and not holds("summary.json", "an earlier run's")
    assert not holds("summary.json", '{"command": "eval"}')
    assert not holds("summary.json", '{"command": "track", "detection_fates": {}}'[:20])
    assert not holds("summary.json", "[1]")
    (tmp_path / "bytes").mkdir()
    (tmp_path / "bytes" / "summary.json").write_bytes(b'{"command": "track\xff"}')
    assert not holds_a_run(tmp_path / "bytes")  # (not UTF-8: not a run's)
    assert holds("summary.json", '{"command": "waymo"}')
    assert holds("summary.json", '{"frames": 1, "detection_fates": {}}')  # (an older run's)
    (tmp_path / "cut_short" / ".scenes").mkdir(parents=True)
    assert holds_a_run(tmp_path / "cut_short")


def test_track_into_a_folder_of_anyones_results_json_keeps_every_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A folder holding a results.json counted as a run's: track removed every command's
    files from it (results.json, gt.json, eval.md). A folder without a run's summary.json
    keeps all it holds but what the run writes; with one, the earlier run's files go (and
    the new summary.json names its command)."""
    out = tmp_path / "w"
    out.mkdir()
    for name, text in (("results.json", "{}\n"), ("gt.json", "gt\n"), ("eval.md", "n\n")):
        (out / name).write_text(text)
    argv = ["track", str(SAMPLE / "detections.json.gz"), "--frames", "0:5", "--out", str(out)]
    code, _, err = _run(argv, capsys)
    assert code == 0, err
    assert {n: (out / n).read_text() for n in ("results.json", "gt.json", "eval.md")} == {
        "results.json": "{}\n",
        "gt.json": "gt\n",
        "eval.md": "n\n",
    }
    assert json.loads((out / "summary.json").read_text())["command"] == "track"
    code, _, err = _run(argv, capsys)  # now a run's folder: the earlier run's files go
    assert code == 0, err
    assert not any((out / n).exists() for n in ("results.json", "gt.json", "eval.md"))


def test_an_input_named_as_another_commands_output_is_refused_only_in_a_runs_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack track w/results.json --out w`, w not a run's folder: nothing removes
    results.json (track does not write it), so it is read as any input; in a run's folder it
    goes with the earlier run, and the refusal says so."""
    out = tmp_path / "w"
    out.mkdir()
    (out / "results.json").write_bytes(
        gzip.decompress((SAMPLE / "detections.json.gz").read_bytes())
    )
    argv = ["track", str(out / "results.json"), "--frames", "0:5", "--out", str(out)]
    code, _, err = _run(argv, capsys)
    assert code == 0, err
    assert (out / "results.json").is_file() and (out / "tracks.json").is_file()
    code, _, err = _run(argv, capsys)  # (summary.json now marks w a run's)
    _assert_one_line_error(
        code,
        err,
        "track",
        f"{out / 'results.json'}: INPUT is an earlier run's output, which this run removes"
        f" from {out}",
    )
    assert (out / "results.json").is_file()


def test_an_input_in_data_is_refused_only_where_the_run_writes_or_removes_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack track w/data/dets.txt --out w`, w holding no run: track writes data/<scene>.txt
    of its own scenes alone (with --kitti-results), never data/dets.txt, yet every data/*.txt
    was refused as "a file this run writes". Now a file of a scene it writes is refused, and in
    a run's folder the data/*.txt the earlier run wrote (its summary lists them), which a run
    removes."""
    from app.outputs import outputs_at_stake

    detections = gzip.decompress((SAMPLE / "detections.json.gz").read_bytes())
    out = tmp_path / "w"
    (out / "data").mkdir(parents=True)
    dets = out / "data" / "dets.txt"
    dets.write_bytes(detections)
    argv = ["track", str(dets), "--frames", "0:5", "--out", str(out)]
    for extra in ([], ["--kitti-results"]):
        code, _, err = _run([*argv, *extra], capsys)
        assert code == 0, err
        assert dets.read_bytes() == detections
        (out / "summary.json").unlink()  # (w again a folder of anyone's files)
    assert (out / "data" / "0001.txt").is_file()
    # now a run's folder, whose summary lists data/dets.txt among the run's outputs
    listed = [{"path": "data/dets.txt", "bytes": 1}, {"path": "data/0001.txt", "bytes": 1}]
    (out / "summary.json").write_text(json.dumps({"command": "track", "outputs": listed}))
    code, _, err = _run(argv, capsys)
    _assert_one_line_error(
        code, err, "track", f"{dets}: INPUT is an earlier run's output, which this run removes"
    )
    # a scene's own file, in a folder holding no run: refused only where the run writes it
    scene = tmp_path / "v" / "data" / "0001.txt"
    scene.parent.mkdir(parents=True)
    scene.write_bytes(detections)
    argv = ["track", str(scene), "--frames", "0:5", "--out", str(tmp_path / "v")]
    code, _, err = _run([*argv, "--kitti-results"], capsys)
    _assert_one_line_error(
        code, err, "track", f"{scene}: INPUT is a file this run writes in {tmp_path / 'v'}"
    )
    assert scene.read_bytes() == detections
    code, _, err = _run(argv, capsys)
    assert code == 0 and scene.read_bytes() == detections, err
    # kitti alike: data/<seq>.txt of its sequences in a folder holding no run
    anyones = outputs_at_stake("kitti", tmp_path / "new", ["0001"])
    assert "data/0001.txt" in anyones and "data/*.txt" not in anyones
    in_run = outputs_at_stake("kitti", out, ["0002"])  # (w holds a run: its files too)
    assert {"data/dets.txt", "data/0001.txt", "data/0002.txt"} <= set(in_run)
    assert "data/*.txt" not in in_run


def _sample_run_argv(out: Path, *extra: str) -> list[str]:
    return [
        "track",
        str(SAMPLE / "detections.json.gz"),
        "--frames",
        "0:5",
        "--out",
        str(out),
        *extra,
    ]


def test_a_run_into_an_earlier_runs_folder_keeps_a_data_file_it_did_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run into a folder holding an earlier run removed every data/*.txt, a user's own
    data/notes.txt too. Now, of data/*.txt, the files the earlier run wrote go (its summary
    lists them: track's "outputs", kitti's "sequences"), this run's are rewritten, anyone's
    other file stays."""
    out = tmp_path / "w"
    code, _, err = _run(_sample_run_argv(out, "--kitti-results"), capsys)
    assert code == 0, err
    notes = out / "data" / "notes.txt"
    notes.write_text("mine\n")
    for extra in (["--kitti-results"], []):  # (its 0001.txt rewritten, then removed)
        code, _, err = _run(_sample_run_argv(out, *extra), capsys)
        assert code == 0, err
        assert notes.read_text() == "mine\n"
    assert sorted(p.name for p in (out / "data").iterdir()) == ["notes.txt"]
    # an earlier kitti run's sequences (its summary has no "outputs"): theirs go, notes stay
    (out / "summary.json").write_text(json.dumps({"command": "kitti", "sequences": ["0007"]}))
    (out / "data" / "0007.txt").write_text("kitti's\n")
    code, _, err = _run(_sample_run_argv(out), capsys)
    assert code == 0, err
    assert sorted(p.name for p in (out / "data").iterdir()) == ["notes.txt"]


def test_kitti_into_an_earlier_runs_folder_keeps_a_data_file_it_did_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack kitti` alike: its sequences' data/<seq>.txt (the name normalised: --seqs 1 is
    0001) and the earlier run's go, a user's data/notes.txt stays."""
    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--no-eval", "--out", str(out)]
    code, _, err = _run([*argv, "--seqs", "0001"], capsys)
    assert code == 0, err
    (out / "data" / "notes.txt").write_text("mine\n")
    (out / "data" / "0001.txt").write_text("stale\n")
    code, _, err = _run([*argv, "--seqs", "1"], capsys)
    assert code == 0, err
    assert (out / "data" / "notes.txt").read_text() == "mine\n"
    assert (out / "data" / "0001.txt").read_text().startswith("0 ")  # (this run's, rewritten)


@pytest.mark.parametrize("earlier", ["cut short", "summary without a list"])
def test_a_data_file_of_an_earlier_run_not_known_is_refused(
    earlier: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Where the earlier run does not say which data/*.txt are its own (cut short: its scene
    parts and no summary.json; a summary listing neither outputs nor sequences), a data file
    this run does not write is refused, naming it, before any work: it may be a user's (kept,
    or removed). This run's own files are no obstacle; without any other, the run goes on."""
    out = tmp_path / "w"
    (out / "data").mkdir(parents=True)
    if earlier == "cut short":
        (out / ".scenes").mkdir()
        why = "it was cut short (.scenes/ is there, no summary.json)"
    else:
        (out / "summary.json").write_text('{"command": "track"}')
        why = "its summary.json does not list its data/*.txt files"
    (out / "data" / "0001.txt").write_text("this run's scene\n")
    notes = out / "data" / "notes.txt"
    notes.write_text("mine\n")
    before = _tree(out)
    code, printed, err = _run(_sample_run_argv(out, "--kitti-results"), capsys)
    _assert_one_line_error(
        code,
        err,
        "track",
        f"{notes}: {out} holds an earlier run, and {why}: this file may be anyone's; move or "
        "remove it, or give another --out",
    )
    assert printed == "" and _tree(out) == before
    notes.unlink()
    code, _, err = _run(_sample_run_argv(out, "--kitti-results"), capsys)
    assert code == 0, err
    assert sorted(p.name for p in (out / "data").iterdir()) == ["0001.txt"]
    assert (out / "data" / "0001.txt").read_text() != "this run's scene\n"


def test_a_summary_lists_data_files_of_the_folder_alone(tmp_path: Path) -> None:
    """A summary.json is anyone's to edit: a listed path outside data/, with a glob character
    or a folder, is no file of the run's (never a pattern that reaches other files)."""
    from app.outputs import earlier_scene_files

    listed = ["data/0001.txt", "data/*.txt", "../x/data/a.txt", "data/a/b.txt", "data/.x.txt"]
    outputs = [{"path": p, "bytes": 1} for p in listed]
    (tmp_path / "summary.json").write_text(json.dumps({"command": "track", "outputs": outputs}))
    assert earlier_scene_files(tmp_path) == ["data/0001.txt"]
    (tmp_path / "summary.json").write_text(json.dumps({"command": "kitti", "sequences": ["*"]}))
    assert earlier_scene_files(tmp_path) == ["data/%2A.txt"]
    (tmp_path / "summary.json").write_text('{"command": "waymo"}')
    assert earlier_scene_files(tmp_path) == []
    (tmp_path / "summary.json").write_text('{"command": "kitti"}')
    assert earlier_scene_files(tmp_path) is None


def test_a_run_into_an_earlier_runs_folder_keeps_a_recording_it_did_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run into a folder holding an earlier run removed every recordings/*.rrd and
    eval/*.json, a user's recordings/mine.rrd too. Now, as of data/*.txt, only the recordings
    the earlier run's summary lists go (and of eval/ only the devkit's two file names): a
    user's files there stay."""
    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--no-eval"]
    code, _, err = _run([*argv, "--record", "--out", str(out)], capsys)
    assert code == 0, err
    assert (out / "recordings" / "0001.rrd").is_file()
    (out / "recordings" / "mine.rrd").write_text("mine\n")
    (out / "eval").mkdir()
    (out / "eval" / "mine.json").write_text("{}\n")
    (out / "eval" / "metrics_summary.json").write_text("{}\n")  # (the devkit's: goes)
    code, _, err = _run([*argv, "--out", str(out)], capsys)
    assert code == 0, err
    assert sorted(p.name for p in (out / "recordings").iterdir()) == ["mine.rrd"]
    assert (out / "recordings" / "mine.rrd").read_text() == "mine\n"
    assert sorted(p.name for p in (out / "eval").iterdir()) == ["mine.json"]
    # a `track` run into it alike (a `kitti` summary without recordings: none of them its)
    code, _, err = _run(_sample_run_argv(out), capsys)
    assert code == 0, err
    assert (out / "recordings" / "mine.rrd").read_text() == "mine\n"


def test_kitti_without_record_keeps_a_recording_of_its_sequence(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """recordings/<seq>.rrd was put at stake whether or not the run records: `kitti --seqs 0001`
    without --record into a run folder deleted a user's recordings/0001.rrd (and refused it
    as an input). Now only a --record run writes (and so replaces) it."""
    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--no-eval"]
    code, _, err = _run([*argv, "--out", str(out)], capsys)
    assert code == 0, err
    mine = out / "recordings" / "0001.rrd"
    mine.parent.mkdir()
    mine.write_text("mine\n")
    code, _, err = _run([*argv, "--out", str(out)], capsys)
    assert code == 0, err
    assert mine.read_text() == "mine\n"
    code, _, err = _run([*argv, "--labels", str(mine.parent), "--out", str(out)], capsys)
    assert code == 0, err  # (nor is a folder holding it refused as an input)
    assert mine.read_text() == "mine\n"


def test_a_recording_of_a_run_cut_short_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run cut short (its scene parts, no summary.json) does not say which recordings are
    its own: a recordings/*.rrd the new run does not write is refused, naming it, before any
    work, as a data/*.txt is."""
    out = tmp_path / "out"
    (out / ".scenes").mkdir(parents=True)
    (out / "recordings").mkdir()
    mine = out / "recordings" / "mine.rrd"
    mine.write_text("mine\n")
    before = _tree(out)
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--no-eval"]
    code, printed, err = _run([*argv, "--out", str(out)], capsys)
    _assert_one_line_error(
        code,
        err,
        "kitti",
        f"{mine}: {out} holds an earlier run, and it was cut short (.scenes/ is there, no "
        "summary.json): this file may be anyone's; move or remove it, or give another --out",
    )
    assert printed == "" and _tree(out) == before


def test_every_unknown_file_of_a_run_cut_short_is_counted(tmp_path: Path) -> None:
    """The refusal named the first unknown file alone: a user moved it, ran again, and was
    refused on the next. Now it says how many more there are, so all go in one go."""
    from app.outputs import outputs_at_stake

    (tmp_path / ".scenes").mkdir()
    for name in ("data/0001.txt", "data/notes.txt", "recordings/a.rrd", "recordings/b.rrd"):
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text("x\n")
    with pytest.raises(InputError) as caught:
        outputs_at_stake("kitti", tmp_path, ["0001"])
    assert str(caught.value) == (
        f"{tmp_path / 'data' / 'notes.txt'} (and 2 more): {tmp_path} holds an earlier run, and "
        f"it was cut short (.scenes/ is there, no summary.json): these files may be anyone's; "
        "move or remove them, or give another --out"
    )


def test_a_summary_lists_recordings_and_results_of_the_folder_alone(tmp_path: Path) -> None:
    """A summary.json (and a compare.json) is anyone's to edit: a listed recording is taken
    by its name alone, a safe one in a recordings/ folder, never a pattern or another folder;
    a Waymo run's results are those of its segments."""
    from app.outputs import earlier_named_files, outputs_replaced_by

    listed = [
        "/abs/run/recordings/0001.rrd",
        "rel/recordings/0002.rrd",
        "recordings/*.rrd",
        "recordings/.x.rrd",
        "elsewhere/0003.rrd",
        "recordings/notes.txt",
        "recordings/sub/0004.rrd",
    ]
    summary = {"command": "nuscenes", "recordings": listed}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    (tmp_path / "compare.json").write_text(json.dumps({"recordings": {"7": "o/recordings/7.rrd"}}))
    assert earlier_named_files(tmp_path) == [
        "recordings/0001.rrd",
        "recordings/0002.rrd",
        "recordings/7.rrd",
    ]
    replaced = outputs_replaced_by("kitti", tmp_path, ["0009"])
    assert "recordings/*.rrd" not in replaced and "recordings/0009.rrd" in replaced
    assert "eval/*.json" not in replaced and "eval/metrics_details.json" in replaced
    (tmp_path / "compare.json").unlink()
    waymo = {"command": "waymo", "segments": ["seg-1", "../x"], "recordings": {"a": 1}}
    (tmp_path / "summary.json").write_text(json.dumps(waymo))
    assert earlier_named_files(tmp_path) == sorted(
        f"results/{t}/{n}.npz"
        for t in ("vehicle", "pedestrian", "cyclist")
        for n in ("seg-1", "%2E.%2Fx")  # (safe_filename: no other folder)
    )
    (tmp_path / "summary.json").unlink()
    (tmp_path / ".scenes").mkdir()
    assert earlier_named_files(tmp_path) is None


def test_a_compare_json_is_read_as_guarded_as_a_summary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The compare.json beside a run's summary is read as the summary is: a FIFO of that name
    hung every run into the folder, a link to /dev/zero filled its memory (MemoryError, "a
    bug"); now only a regular file of at most the summary's size is read, else it lists none."""
    import threading

    from app import outputs

    summary = {"command": "kitti", "recordings": {"1": "r/recordings/0001.rrd"}}
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    compare = tmp_path / "compare.json"
    os.mkfifo(compare)
    found: list[object] = []
    reader = threading.Thread(
        target=lambda: found.append(outputs.earlier_named_files(tmp_path)), daemon=True
    )
    reader.start()
    reader.join(5)
    if reader.is_alive():  # (the old read blocks until a writer comes: let it end)
        os.close(os.open(compare, os.O_WRONLY))
        reader.join(5)
        pytest.fail("a FIFO named compare.json was read")
    assert found == [["recordings/0001.rrd"]]
    compare.unlink()
    compare.write_text(json.dumps({"recordings": {"7": "o/recordings/7.rrd"}}))
    assert outputs.earlier_named_files(tmp_path) == ["recordings/0001.rrd", "recordings/7.rrd"]
    monkeypatch.setattr(outputs, "_SUMMARY_MAX_BYTES", compare.stat().st_size - 1)
    (tmp_path / "summary.json").write_text(json.dumps({"command": "kitti"}))  # (within it)
    assert outputs.earlier_named_files(tmp_path) == []  # (the compare.json over the cap)


def test_an_input_among_another_commands_outputs_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run removes every command's outputs of the earlier run in its folder: an input among
    them (a nuscenes run's gt.json as track's INPUT, its self_profile.toml as --profile) would
    be lost. Refused before any work, saying so; the files kept."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text('{"command": "nuscenes"}')  # an earlier run's folder
    (out / "gt.json").write_text(json.dumps({"a": _sample_frames()[:3]}))
    profile = out / "self_profile.toml"
    profile.write_text("a profile\n")
    earlier = _tree(out)
    code, _, err = _run(["track", str(out / "gt.json"), "--out", str(out)], capsys)
    _assert_one_line_error(
        code,
        err,
        "track",
        f"{out / 'gt.json'}: INPUT is an earlier run's output, which this run removes from {out}",
    )
    detections = tmp_path / "one.json"
    detections.write_text(json.dumps({"a": _sample_frames()[:3]}))
    argv = ["track", str(detections), "--profile", str(profile), "--out", str(out)]
    code, _, err = _run(argv, capsys)
    _assert_one_line_error(
        code, err, "track", f"{profile}: --profile is a file this run writes in {out}"
    )
    assert _tree(out) == earlier


def test_scenes_whose_files_differ_only_in_case_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Scenes A and a wrote data/A.txt and data/a.txt: one file on a case-insensitive
    filesystem (the second scene's over the first's), and a folder that does not survive a
    copy to one. Refused up front, on every filesystem, naming both; a run that writes no file
    per scene (track without --kitti-results) is not refused."""
    from tracker.io.fileio import case_collision

    assert case_collision(["A", "b", "a"]) == ("A", "a")
    assert case_collision(["x/Y", "X/y"]) == ("x/Y", "X/y")  # (as escaped: x%2FY, X%2Fy)
    assert case_collision(["0001", "0002", "\u00e9", "\u00c9"]) is None  # (%C3%A9, %C3%89)
    frames = _sample_frames()[:3]
    both = tmp_path / "both.json"
    both.write_text(json.dumps({"A": frames, "b": frames, "a": frames}))
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text("an earlier run's\n")
    code, _, err = _run(["track", str(both), "--kitti-results", "--out", str(out)], capsys)
    _assert_one_line_error(
        code, err, "track", f"{both}: scenes 'A' and 'a' differ only in case", "(A.txt, a.txt)"
    )
    assert _tree(out) == {"summary.json": b"an earlier run's\n"}
    code, _, err = _run(["track", str(both), "--out", str(out)], capsys)
    assert code == 0, err
    assert sorted(json.loads((out / "tracks.json").read_text())) == ["A", "a", "b"]

    code, _, err = _run(["kitti", "--seqs", "ab,AB", "--out", str(tmp_path / "k")], capsys)
    _assert_one_line_error(code, err, "kitti", "sequences 'ab' and 'AB' differ only in case")
    root = tmp_path / "waymo"
    for sub in ("ts_info", "ego_info", "dets"):
        (root / sub).mkdir(parents=True)
    argv = ["waymo", "--data-root", str(root), "--detections", str(root / "dets"),
            "--segments", "seg,SEG", "--out", str(tmp_path / "w")]  # fmt: skip
    code, _, err = _run(argv, capsys)
    _assert_one_line_error(
        code, err, "waymo", "--segments: segments 'seg' and 'SEG' differ only in case"
    )


def test_view_refuses_scenes_whose_recordings_differ_only_in_case(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """view writes a recording per scene (mctrack_<scene>.rrd, or OUT_<scene>.rrd with
    --save): scenes A and a were two files here and one on macOS or Windows. Refused before
    any recording, with the check the other commands use."""
    frames = _sample_frames()[:3]
    both = tmp_path / "both.json"
    both.write_text(json.dumps({"A": frames, "b": frames, "a": frames}))
    monkeypatch.chdir(tmp_path)  # (the default recordings' folder)
    for save in ([], ["--save", str(tmp_path / "out.rrd")]):
        code, _, err = _run(["view", str(both), "--no-motion", *save], capsys)
        _assert_one_line_error(
            code, err, "view", f"{both}: scenes 'A' and 'a' differ only in case", "(A.rrd, a.rrd)"
        )
        assert sorted(p.name for p in tmp_path.iterdir()) == ["both.json"]


def test_track_stopped_after_its_scenes_leaves_no_partial_outputs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C once the scenes are tracked (their data/*.txt and scene parts written, tracks.json
    not yet): the run's files stayed without the summary.json that marks a complete run. Now
    they go, the folders the run made with them; files of other names stay."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine\n")
    detections = tmp_path / "two.json"
    frames = _sample_frames()[:3]
    detections.write_text(json.dumps({"a": frames, "b": frames}))

    def interrupted(out: Path, ok: object) -> None:
        assert (out / "data" / "a.txt").is_file() and (out / ".scenes").is_dir()
        raise KeyboardInterrupt

    monkeypatch.setattr("app.scenes.write_tracks", interrupted)
    argv = ["track", str(detections), "--kitti-results", "--out", str(out)]
    code, _, err = _run(argv, capsys)
    assert code == 130 and "interrupted" in err, err
    assert _tree(out) == {"notes.txt": b"mine\n"}


def test_a_run_made_with_a_relative_kit_is_reported_from_anywhere(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """summary.json kept --kitti-root as typed, so 'mctrack report RUN' from another directory
    looked for the labels relative to it: "labels folder sample_data/.../label_02 not found"."""
    monkeypatch.chdir(ROOT)
    run = tmp_path / "run"
    kit = str(SAMPLE_KIT.relative_to(ROOT))
    argv = ["kitti", "--kitti-root", kit, "--seqs", "0001", "--classes", "car", "--out", str(run)]
    code, _, err = _run(argv, capsys)
    assert code == 0, err
    summary = json.loads((run / "summary.json").read_text())
    assert summary["kitti_root"] == str(SAMPLE_KIT) and Path(summary["labels"]).is_absolute()
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(["report", "run", "--out", "report"], capsys)
    assert code == 0, err
    assert (tmp_path / "report" / "index.html").is_file()


def test_a_folder_no_run_wrote_keeps_its_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--out . in a project of one's own: its data/*.txt are not an earlier run's."""
    out = tmp_path / "project"
    (out / "data").mkdir(parents=True)
    (out / "data" / "notes.txt").write_text("mine\n")
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--out", str(out)]
    code, _, err = _run(argv, capsys)
    assert code == 0, err
    assert (out / "data" / "notes.txt").read_text() == "mine\n"


def test_earlier_outputs_are_removed_inside_the_folder_only(tmp_path: Path) -> None:
    """A linked sub-folder may lead anywhere: its files are not the folder's to remove."""
    from app.common import remove_earlier_outputs

    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "keep.txt").write_text("x")
    out = tmp_path / "out"
    (out / "runs" / "a").mkdir(parents=True)
    (out / "runs" / "a" / "old.txt").write_text("x")
    (out / "runs" / "linked").symlink_to(outside)
    assert remove_earlier_outputs(out, ["runs/*/*.txt"]) == 1
    assert (outside / "keep.txt").is_file() and not (out / "runs" / "a").exists()


def test_inputs_are_refused_by_the_glob_that_removes_outputs(tmp_path: Path) -> None:
    """An input is refused where the run's globs (as remove_earlier_outputs reads them) reach
    it: ``data/*.txt`` holds data/0001.txt, not data/sub/notes.txt one folder deeper."""
    from app.common import refuse_inputs_among_outputs

    out = tmp_path / "out"
    (out / "data" / "sub").mkdir(parents=True)
    (out / "data" / "0001.txt").write_text("x")
    (out / "data" / "sub" / "notes.txt").write_text("x")
    refuse_inputs_among_outputs(out, ["data/*.txt"], {"INPUT": out / "data" / "sub"})
    with pytest.raises(InputError, match=r"INPUT holds data/0001\.txt, a file this run writes"):
        refuse_inputs_among_outputs(out, ["data/*.txt"], {"INPUT": out / "data"})


def test_kitti_root_defaults_to_the_environment_variable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("MCTRACK_KITTI_ROOT", str(tmp_path / "from_env"))
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(["kitti", "--out", "o"], capsys)
    _assert_one_line_error(code, err, "kitti", str(tmp_path / "from_env"), "MCTRACK_KITTI_ROOT")


def test_kernel_cache_check_sees_a_cold_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("numba")
    monkeypatch.delenv("MCTRACK_NUMBA", raising=False)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "empty"))
    assert cli.kernels_cold()
    cli._mark_kernels_warm()  # what a warm-up leaves behind
    assert not cli.kernels_cold()
    stamp = cli._kernel_stamp()
    assert stamp is not None and stamp[0].is_relative_to(tmp_path / "empty")
    # any edit to a kernel source (a shared helper too) changes the hash: cold again
    stamp[0].write_text("0" * 64 + "\n", encoding="utf-8")
    assert cli.kernels_cold()
    # the message names where they are cached (was "first run on this machine only": the
    # cache is per copy of the source, so a new checkout compiles again)
    import tracker.geometry
    import tracker.kernels

    monkeypatch.setattr(tracker.kernels, "load", lambda: None)  # (not 20-60 s of compiling)
    monkeypatch.setattr(tracker.geometry, "prepare_kernels", lambda: None)
    cli._warm_kernels()
    said = capsys.readouterr().err
    assert f"(cached in {stamp[0].parent}: later runs of this copy of the source" in said, said
    assert "machine" not in said and not cli.kernels_cold()
    monkeypatch.setattr(cli.os, "access", lambda *args: False)  # (root may write anywhere)
    assert cli._kernel_cache_note(stamp[0].parent).startswith(
        f"cached in numba's user-wide folder: {stamp[0].parent} is not writable"
    )  # (was "on every run": numba falls back to its user-wide cache, and loads them from it)
    monkeypatch.setenv("MCTRACK_NUMBA", "0")  # numpy only: nothing to compile
    assert not cli.kernels_cold()


def test_validate_reports_every_error_with_the_count(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A missing lwh in one frame does not hide a score of 1.5 in another; the cap is honoured."""
    box = {"category": "car", "global_xyz": [0, 0, 0], "lwh": [4, 2, 1.5], "global_yaw": 0}
    frames = [
        {"frame_id": 0, "timestamp": 0.0, "bboxes": [{**box, "detection_score": 1.5}]},
        {"frame_id": 1, "timestamp": 0.1, "bboxes": [{**box, "detection_score": 0.5}]},
        {"frame_id": 2, "timestamp": 0.2, "bboxes": [{"category": "car", "detection_score": 0.5,
                                                      "global_xyz": [0, 0, 0], "global_yaw": 0}]},
    ]  # fmt: skip
    path = tmp_path / "two_errors.json"
    path.write_text(json.dumps({"s": frames}))
    code, _, err = _run(["validate", str(path)], capsys)
    assert code == 2
    assert "outside [0, 1]" in err and "missing key 'lwh'" in err
    assert err.strip().splitlines()[-1].endswith("2 errors")
    code, _, err = _run(["validate", "--max-errors", "1", str(path)], capsys)
    assert code == 2 and "missing key 'lwh'" not in err and "2 errors (1 shown)" in err


def test_a_reader_that_closes_the_pipe_stops_the_command_quietly() -> None:
    """`mctrack validate F | head -2`: the reader goes away before the output is written; the
    command stops with the shell's SIGPIPE status and says nothing (was 'unexpected error:
    BrokenPipeError', exit 1)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "validate", str(SAMPLE / "detections.json.gz")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # before the command writes a byte
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == cli.EXIT_PIPE
    assert "error" not in err and "Exception ignored" not in err, err


def test_a_broken_pipe_of_the_commands_own_is_an_unexpected_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A BrokenPipeError that is not stdout's reader going away (a worker's or the viewer's pipe)
    is a bug to report, not a quiet exit 141."""
    import app.validate

    def broken(args: argparse.Namespace) -> int:
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(app.validate, "run", broken)
    code, _, err = _run(["validate", str(SAMPLE / "detections.json.gz")], capsys)
    assert code == cli.EXIT_BUG and "unexpected error: BrokenPipeError" in err


def test_track_refuses_an_input_it_would_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack track OUT/tracks.json --out OUT`: the run would overwrite the file it reads with
    its tracks; refused before any work, the file kept (it was overwritten)."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "tracks.json").write_text(json.dumps({"0001": _sample_frames()[:3]}))
    before = (out / "tracks.json").read_bytes()
    code, _, err = _run(["track", str(out / "tracks.json"), "--out", str(out)], capsys)
    assert code == 2
    assert f"{out / 'tracks.json'}: INPUT is a file this run writes in {out}" in err
    assert (out / "tracks.json").read_bytes() == before
    # another name in the same folder is fine
    (out / "tracks.json").rename(out / "dets.json")
    code, _, err = _run(["track", str(out / "dets.json"), "--out", str(out)], capsys)
    assert code == 0, err


def test_kitti_refuses_inputs_among_its_outputs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`mctrack kitti --labels OUT/data --out OUT`: the run wrote its data/<seq>.txt over the
    label files (and scored its tracks against themselves); --profile OUT/self_profile.toml
    was deleted with the earlier run's outputs, --poses OUT/data overwritten too. Each refused
    before any work, the files kept."""
    out = tmp_path / "out"
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--out", str(out)]
    code, _, err = _run([*argv, "--no-eval", "--profile", "self"], capsys)
    assert code == 0 and (out / "self_profile.toml").is_file(), err
    shutil.copy(SAMPLE_KIT / "training" / "label_02" / "0001.txt", out / "data" / "0001.txt")
    earlier = _tree(out)
    pose_dir = SAMPLE_KIT / "training" / "pose_orbslam3"
    for option, value, what in (
        ("--labels", out / "data", "holds data/0001.txt,"),
        ("--profile", out / "self_profile.toml", "is"),
        ("--poses", out / "data", "holds data/0001.txt,"),
    ):
        code, _, err = _run([*argv, option, str(value)], capsys)
        _assert_one_line_error(
            code, err, "kitti", f"{value}: {option} {what} a file this run writes in {out}"
        )
        assert _tree(out) == earlier
    # the same files outside --out are inputs as any other
    labels, profile, poses = tmp_path / "labels", tmp_path / "p.toml", tmp_path / "poses"
    shutil.copytree(out / "data", labels)
    shutil.copy(out / "self_profile.toml", profile)
    shutil.copytree(pose_dir, poses)
    extra = ["--labels", str(labels), "--profile", str(profile), "--poses", str(poses)]
    code, _, err = _run([*argv, *extra], capsys)
    assert code == 0 and (labels / "0001.txt").read_bytes() == earlier["data/0001.txt"], err


def test_track_says_which_scenes_have_no_frames(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A scene without frames beside scenes with frames is kept in tracks.json without tracks,
    and said (it was silent)."""
    path = tmp_path / "two.json"
    path.write_text(json.dumps({"0001": _sample_frames()[:3], "0002": []}))
    code, printed, err = _run(["track", str(path), "--out", str(tmp_path / "out")], capsys)
    assert code == 0, err
    assert "1 scene(s) without frames, written without tracks: 0002" in printed
    assert json.loads((tmp_path / "out" / "tracks.json").read_text())["0002"] == []


def test_track_says_the_scenes_a_frame_range_empties_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture
) -> None:
    """With --frames, the scenes the window leaves empty are select_scenes' warning, not said
    again by run()."""
    path = tmp_path / "two.json"
    path.write_text(json.dumps({"0001": _sample_frames()[:3], "0002": []}))
    argv = ["track", str(path), "--frames", "1:3", "--out", str(tmp_path / "out")]
    with caplog.at_level(logging.WARNING):
        code, printed, err = _run(argv, capsys)
    assert code == 0, err
    assert "--frames 1:3 selects no frame of 1 scene(s): '0002' 0:0" in caplog.text
    assert "without frames" not in printed
    assert json.loads((tmp_path / "out" / "tracks.json").read_text())["0002"] == []


def test_validate_frame_rate_help_says_what_its_default_means(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Its default is None, which the help formatter does not show: the help says it."""
    with pytest.raises(SystemExit):
        main(["validate", "--help"])
    assert "(default: none: such frames get no time, NaN)" in " ".join(
        capsys.readouterr().out.split()
    )


def test_help_shows_a_default_of_zero(capsys: pytest.CaptureFixture[str]) -> None:
    """The help formatter left out every default equal to False, so 0 too (`0 == False`):
    `tune --seed`'s and `report --shots`' defaults did not show."""
    for command, option in (("tune", "sampler seed"), ("report", "0: no shots")):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert f"{option} (default: 0)" in text, (command, text)


@pytest.mark.parametrize(
    "file",
    [
        "training/calib/0001.txt",
        "training/label_02/0001.txt",
        "detections/pointrcnn/training/Car/0001.txt",
    ],
)
def test_a_kitti_file_that_is_not_utf8_is_named(
    file: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A calib, label or detection file holding bytes that are not UTF-8 was refused as "not a
    text file (invalid start byte)", naming no file. Now the one-line error names the file, the
    line and the byte offset of the first bad byte."""
    kit = tmp_path / "kit"
    shutil.copytree(SAMPLE_KIT, kit)
    path = kit / file
    data = path.read_bytes()
    line = data.count(b"\n") + 1  # (the bad line is appended after the last)
    path.write_bytes(data + b"0 -1 Car\xff 0 0\n")
    byte = len(data) + len(b"0 -1 Car")
    argv = ["kitti", "--kitti-root", str(kit), "--seqs", "0001", "--out", str(tmp_path / "o")]
    code, _, err = _run(argv, capsys)
    _assert_one_line_error(
        code,
        err,
        "kitti",
        f"{path}:{line}: not a UTF-8 text file (byte {byte}: invalid start byte)",
    )
