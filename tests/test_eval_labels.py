"""Label files checked before any tracking or scoring (one line naming file, line and field;
TrackEval's own failures one line too), and `mctrack eval` scoring what the tracks file covers:
its frames (a `mctrack track --frames` window) and its labelled sequences."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import pytest

from app.cli import main
from tracker.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "kitti-0001"
SAMPLE_KIT = SAMPLE / "raw"  # one sequence, 0001: 447 poses, labels, pointrcnn detections
LABEL = SAMPLE_KIT / "training" / "label_02" / "0001.txt"
GOOD_ROW = next(r for r in LABEL.read_text().splitlines() if " Car " in r)


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(argv)
    return code, capsys.readouterr().err


def _one_line_error(code: int, err: str, *fragments: str) -> None:
    assert code == 2, err
    assert "Traceback" not in err and "unexpected error" not in err, err
    errors = [line for line in err.splitlines() if ": error:" in line]
    assert len(errors) == 1 and err.rstrip().endswith(errors[0]), err
    for fragment in fragments:
        assert fragment in errors[0], err


def _labels(folder: Path, extra: str) -> Path:
    """The sample's labels with one line appended (line 2 of the file + ...)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "0001.txt").write_text(LABEL.read_text() + extra + "\n")
    return folder


N_LINES = len(LABEL.read_text().splitlines())
BAD_LABELS = {  # (the line appended, what the error names)
    "short line": ("3 2 Car 0 0", (f"0001.txt:{N_LINES + 1}", "'columns'", "17 or 18")),
    "frame beyond the poses": (
        "447" + GOOD_ROW[GOOD_ROW.index(" ") :],
        (f"0001.txt:{N_LINES + 1}", "'frame'", "447 frames"),
    ),
    "type TrackEval rejects": (
        GOOD_ROW.replace(" Car ", " Person_sitting "),
        (f"0001.txt:{N_LINES + 1}", "'type'", "Person_sitting"),
    ),
    "an object twice in one frame": (GOOD_ROW, (f"0001.txt:{N_LINES + 1}", "'track_id'")),
    "a location beyond the bound": (  # (finite: 1e300 m overflowed the motion metrics)
        " ".join([*GOOD_ROW.split()[:13], "1e300", *GOOD_ROW.split()[14:]]),
        (
            f"0001.txt:{N_LINES + 1}: field 'x': 1e300 (frame {GOOD_ROW.split()[0]}) is beyond "
            "±1e+08 m",
        ),
    ),
}
#: The error on the sample's labels with GOOD_ROW appended, after "<label file>:".
TWICE = (
    f"{N_LINES + 1}: field 'track_id': frame {GOOD_ROW.split()[0]}: track id {GOOD_ROW.split()[1]}"
    f" (Car) is also on line {LABEL.read_text().splitlines().index(GOOD_ROW) + 1}: one object"
    " twice in one frame"
)


@pytest.mark.parametrize("case", list(BAD_LABELS))
@pytest.mark.parametrize("where", ["--labels", "the kit's label_02"])
def test_kitti_refuses_bad_labels_before_tracking_and_keeps_the_earlier_run(
    case: str, where: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    extra, fragments = BAD_LABELS[case]
    kit = SAMPLE_KIT
    argv = ["kitti", "--seqs", "0001", "--classes", "car"]
    if where == "--labels":
        argv += ["--labels", str(_labels(tmp_path / "labels", extra))]
    else:
        kit = tmp_path / "kit"
        shutil.copytree(SAMPLE_KIT, kit)
        _labels(kit / "training" / "label_02", extra)
    out = tmp_path / "out"
    (out / "data").mkdir(parents=True)
    (out / "summary.json").write_text('{"command": "kitti"}\n')  # an earlier run's
    code, err = _run([*argv, "--kitti-root", str(kit), "--out", str(out)], capsys)
    _one_line_error(code, err, *fragments)
    assert (out / "summary.json").read_text() == '{"command": "kitti"}\n'
    assert not list((out / "data").iterdir())  # nothing tracked


@pytest.mark.parametrize(
    "repeat",
    [
        "\n".join(2 * [GOOD_ROW.replace(" 0 Car ", " 900 Van ", 1)]),  # a distractor, twice
        " ".join([*GOOD_ROW.split()[:4], "3", *GOOD_ROW.split()[5:]]),  # occluded beyond 2
        " ".join([*GOOD_ROW.split()[:3], "1", *GOOD_ROW.split()[4:]]),  # truncated
    ],
    ids=["van", "occluded", "truncated"],
)
def test_a_repeat_trackeval_does_not_score_is_accepted_as_trackeval_accepts_it(
    repeat: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """TrackEval checks one id per frame only among the ground truth it scores (Kitti2DBox's
    preprocessing keeps a scored class, occluded at most 2, not truncated): a repeat outside it
    is scored, not refused, so the check before tracking must not refuse it either."""
    from tracker.eval.kitti import check_label_file, evaluate_kitti

    labels = _labels(tmp_path / "labels", repeat)
    assert check_label_file(labels / "0001.txt", 447) == 447
    with pytest.raises(InputError, match="one object twice in one frame"):  # (the rule's edge)
        check_label_file(_labels(tmp_path / "scored", GOOD_ROW) / "0001.txt", 447)
    result = tmp_path / "result"
    result.mkdir()
    rows = [r for r in LABEL.read_text().splitlines() if " DontCare " not in r]
    result.joinpath("0001.txt").write_text("".join(f"{r} 1\n" for r in rows))  # (with a score)
    metrics = evaluate_kitti(
        label_dir=labels, result_dir=result, seq_lengths={"0001": 447}, classes=["car"]
    )
    assert metrics["car"]["HOTA"] > 99  # (the labels scored against themselves)


@pytest.mark.parametrize(
    "repeat",
    [
        " ".join([*GOOD_ROW.split()[:4], "3", *GOOD_ROW.split()[5:]]),  # an occluded car
        GOOD_ROW.replace(" Car ", " Van ", 1),  # the same id on a Van
    ],
    ids=["occluded", "another type"],
)
@pytest.mark.parametrize("no_eval", [False, True])
def test_kitti_motion_refuses_an_object_twice_in_a_frame_that_trackeval_would_not_score(
    repeat: str, no_eval: bool, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The motion metrics follow every labelled object by its id alone, so a repeat TrackEval
    does not score (an occluded car, the id on a row of another type) stops a `--motion` run at
    once, with or without the static metrics, naming the label file (it was a ValueError of the
    motion metrics after the tracking); the static metrics alone score it as TrackEval does."""
    kit = tmp_path / "kit"
    shutil.copytree(SAMPLE_KIT, kit)
    labels = _labels(kit / "training" / "label_02", repeat)
    argv = ["kitti", "--kitti-root", str(kit), "--seqs", "0001", "--classes", "car"]
    extra = ["--no-eval"] if no_eval else []
    code, err = _run([*argv, "--motion", *extra, "--out", str(tmp_path / "m")], capsys)
    _one_line_error(code, err, f"{labels / '0001.txt'}:{N_LINES + 1}: field 'track_id'")
    code, err = _run([*argv, *extra, "--out", str(tmp_path / "s")], capsys)
    assert code == 0, err


@pytest.mark.parametrize("command", ["kitti", "robustness"])
def test_a_repeat_in_a_class_the_run_does_not_score_is_accepted(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """TrackEval looks for a repeated id in the classes it scores alone: a run of cars accepts
    labels with one pedestrian twice in a frame; a run of pedestrians refuses them."""
    ped = GOOD_ROW.replace(" 0 Car ", " 900 Pedestrian ", 1)
    kit = tmp_path / "kit"
    shutil.copytree(SAMPLE_KIT, kit)
    _labels(kit / "training" / "label_02", f"{ped}\n{ped}")
    argv = [command, "--kitti-root", str(kit), "--seqs", "0001"]
    if command == "robustness":
        argv += ["--levels", "clean", "--seeds", "0"]
    code, err = _run([*argv, "--classes", "car", "--out", str(tmp_path / "car")], capsys)
    assert code == 0, err
    code, err = _run([*argv, "--classes", "pedestrian", "--out", str(tmp_path / "ped")], capsys)
    _one_line_error(code, err, f"0001.txt:{N_LINES + 2}: field 'track_id'")


def test_repeated_track_id_scopes(tmp_path: Path) -> None:
    """Where a repeat counts: per type over every row (result files), per type among the rows
    TrackEval scores for the classes asked (labels), over every type (the motion metrics)."""
    from tracker.eval.kitti import repeated_track_id
    from tracker.io.convert.kitti import read_kitti_labels

    def rows(*lines: str) -> object:
        path = tmp_path / "labels.txt"
        path.write_text("".join(f"{line}\n" for line in lines))
        return read_kitti_labels(path)

    car = "0 5 Car 0 0 -1 10 20 110 80 1.5 1.6 3.9 2.9 1.6 6.4 0.1"
    occluded = car.replace(" Car 0 0 ", " Car 0 3 ")
    truncated = car.replace(" Car 0 0 ", " Car 1 0 ")
    ped = car.replace(" Car ", " Pedestrian ")
    for first, second, per_type, scored, any_type in [
        (car, car, True, True, True),
        (car, car.replace(" Car ", " Car_2 "), True, True, True),  # (Car_2 is a Car)
        (car, occluded, True, False, True),
        (car, truncated, True, False, True),
        (car, car.replace(" Car ", " Van "), False, False, True),
        (ped, ped, True, True, True),
        (car, "1" + car[1:], False, False, False),  # (another frame)
    ]:
        objects = rows(first, second)
        assert (repeated_track_id(objects) is not None) == per_type, (first, second)
        assert (repeated_track_id(objects, "scored") is not None) == scored, (first, second)
        assert (repeated_track_id(objects, "any") is not None) == any_type, (first, second)
    assert repeated_track_id(rows(ped, ped), "scored", ["car"]) is None  # (not scored)
    assert repeated_track_id(rows(car, ped, car), "type") == (2, 0)


def test_eval_motion_refuses_ground_truth_with_an_object_twice_in_a_frame(
    sample_tracks: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """(was a ValueError of the motion metrics: "unexpected error")"""
    import gzip

    gt = json.loads(gzip.open(SAMPLE / "gt.json.gz").read())
    frame = gt["0001"][5]
    frame["bboxes"].append(dict(frame["bboxes"][0]))
    bad = tmp_path / "gt.json"
    bad.write_text(json.dumps(gt))
    argv = ["eval", str(sample_tracks["all"]), "--gt", str(bad), "--motion"]
    code, err = _run([*argv, "--out", str(tmp_path / "o")], capsys)
    _one_line_error(
        code,
        err,
        f"{bad}: scene 0001 frame {frame['frame_id']}: track id"
        f" {frame['bboxes'][0]['track_id']} is on 2 boxes: one object twice in one frame",
    )


@pytest.mark.parametrize("field", ["global_xyz", "lwh"])
def test_eval_refuses_ground_truth_beyond_the_bound_detections_have(
    field: str, sample_tracks: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A GT box at (or as large as) 1e300 m, finite but farther than anything on Earth: one line
    naming the file, scene, frame, box and field, as for a detection (was scored: numpy overflow
    warnings and the box's samples silently lost)."""
    import gzip

    gt = json.loads(gzip.open(SAMPLE / "gt.json.gz").read())
    gt["0001"][5]["bboxes"][1][field] = [3.0, 1e300, 1.5]
    bad = tmp_path / "gt.json"
    bad.write_text(json.dumps(gt))
    for what in (["--labels", str(LABEL.parent)], ["--motion"]):  # (one of them: else nothing)
        argv = ["eval", str(sample_tracks["all"]), "--gt", str(bad), *what]
        code, err = _run([*argv, "--out", str(tmp_path / "o")], capsys)
        _one_line_error(
            code,
            err,
            f"{bad}: scene '0001', frame index 5, box 1: field '{field}' = [3.0, 1e+300, 1.5]: "
            "beyond ±1e+08 m",
        )
        assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["eval", "view", "compare", "robustness", "tune"])
def test_an_object_twice_in_one_frame_is_named_in_its_label_file_by_every_command(
    command: str,
    sample_tracks: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """TrackEval refuses labels holding one track id twice in a frame ("Ground-truth has the
    same ID more than once ...", its frame 1-based, its id renumbered): every command that
    scores names the label file, line, frame and id, in the same words, before scoring (`mctrack
    kitti`: BAD_LABELS). `mctrack compare` named the run's result file instead; robustness and
    tune stop before tracking, the earlier run's outputs kept (tune: no trial's traceback)."""
    from tests.report_fixtures import make_runs

    labels = _labels(tmp_path / "labels", GOOD_ROW)
    expected = f"{labels / '0001.txt'}:{TWICE}"
    if command == "eval":
        argv = ["eval", str(sample_tracks["all"]), "--gt", str(SAMPLE / "gt.json.gz")]
        argv += ["--labels", str(labels), "--out", str(tmp_path / "o")]
    elif command == "view":
        argv = ["view", str(SAMPLE / "detections.json.gz"), "--labels", str(labels)]
        argv += ["--save", str(tmp_path / "v.rrd")]
    elif command == "compare":
        a, b, labels = make_runs(tmp_path / "runs")  # (their summaries name these labels)
        rows = labels.joinpath("0001.txt").read_text().splitlines(keepends=True)
        labels.joinpath("0001.txt").write_text("".join(rows) + rows[0])
        expected = (
            f"{labels / '0001.txt'}:{len(rows) + 1}: field 'track_id': frame 0: track id 1 (Car)"
            " is also on line 1: one object twice in one frame"
        )
        argv = ["compare", str(a), str(b), "--out", str(tmp_path / "o")]
    else:  # the kit's labels; tune's two folds need two sequences (0002: a copy of 0001)
        kit = tmp_path / "kit"
        shutil.copytree(SAMPLE_KIT, kit)
        for path in list(kit.rglob("0001.txt")):
            shutil.copy(path, path.with_name("0002.txt"))
        labels = _labels(kit / "training" / "label_02", GOOD_ROW)
        expected = f"{labels / '0001.txt'}:{TWICE}"
        argv = [command, "--kitti-root", str(kit), "--out", str(tmp_path / "o")]
        (tmp_path / "o").mkdir()
        (tmp_path / "o" / f"{command}.json").write_text("an earlier run's\n")
        if command == "robustness":
            argv += ["--seqs", "0001", "--classes", "car", "--levels", "clean", "--seeds", "1"]
        else:
            argv += ["--seqs", "0001,0002", "--detectors", "pointrcnn", "--trials", "1"]
            argv += ["--folds", "2"]
    code, err = _run(argv, capsys)
    _one_line_error(code, err)
    assert err.splitlines()[-1] == f"mctrack {command}: error: {expected}"
    if command in ("robustness", "tune"):
        assert (tmp_path / "o" / f"{command}.json").read_text() == "an earlier run's\n"
        assert not (tmp_path / "o" / "runs").exists()  # (robustness: nothing tracked)


def test_a_label_refusal_never_names_the_result_file(tmp_path: Path) -> None:
    """Labels said to be checked (``labels_checked``) that TrackEval refuses (an object twice in
    a frame) are named, with line, frame and id, even where a refused result file is named."""
    from tracker.eval.kitti import evaluate_kitti

    labels = _labels(tmp_path / "labels", GOOD_ROW)
    data = tmp_path / "data"
    data.mkdir()
    data.joinpath("0001.txt").write_text(
        "0 1 Car 0 0 -1 10 20 110 80 1.5 1.6 3.9 2.9 1.6 6.4 0.1 0.9\n"
    )
    for name_refused_results in (False, True):
        with pytest.raises(InputError) as excinfo:
            evaluate_kitti(
                label_dir=labels, result_dir=data, seq_lengths={"0001": 447}, classes=["car"],
                labels_checked=True, name_refused_results=name_refused_results,
            )  # fmt: skip
        assert str(excinfo.value) == f"{labels / '0001.txt'}:{TWICE}"


def test_kitti_refuses_detections_given_as_labels(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    detections = SAMPLE_KIT / "detections" / "pointrcnn" / "training" / "Car"  # AB3DMOT CSV
    argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--labels"]
    code, err = _run([*argv, str(detections), "--out", str(tmp_path / "o")], capsys)
    _one_line_error(code, err, str(detections / "0001.txt") + ":1: field 'columns'")


def test_trackeval_failures_are_one_line_and_quiet(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file our reader takes but TrackEval cannot (a tab-separated line after space-separated
    ones): an InputError naming the label file, without TrackEval's printed traceback; and any
    TrackEvalException reaching the CLI is one line, exit 2."""
    import trackeval

    from app import validate
    from tracker.eval.kitti import evaluate_kitti_sequence

    frame, _, *rest = GOOD_ROW.split()  # (another track id: not the same object twice)
    labels = _labels(tmp_path / "labels", "\t".join([frame, "999", *rest]))
    with pytest.raises(
        InputError,
        match=r"labels/0001.txt: TrackEval cannot read it: File 0001.txt cannot be read",
    ):
        evaluate_kitti_sequence(
            label_file=labels / "0001.txt", result_file=None, num_timesteps=447, classes=["car"]
        )
    assert "Traceback" not in capfd.readouterr().err
    # beside a good result file, the file holding the row TrackEval could not read is named
    good_result = tmp_path / "good" / "0001.txt"
    good_result.parent.mkdir()
    good_result.write_text("0 1 Car 0 0 -1 10 20 110 80 1.5 1.6 3.9 2.9 1.6 6.4 0.1 0.9\n")
    with pytest.raises(InputError, match=r"labels/0001.txt: TrackEval cannot read it"):
        evaluate_kitti_sequence(
            label_file=labels / "0001.txt", result_file=good_result, num_timesteps=447,
            classes=["car"],
        )  # fmt: skip
    # a result row cut short (TrackEval's numpy fails on it): our reader names file and line
    short = tmp_path / "short" / "0001.txt"
    short.parent.mkdir()
    short.write_text(good_result.read_text() + "1 1 Car 0 0\n")
    with pytest.raises(InputError) as excinfo:
        evaluate_kitti_sequence(
            label_file=LABEL, result_file=short, num_timesteps=447, classes=["car"]
        )
    assert str(excinfo.value).startswith(f"{short}:2: field 'columns': expected 17 or 18")
    # a result file TrackEval cannot read is named, not the (checked) label file
    bad_result = tmp_path / "run" / "0001.txt"
    bad_result.parent.mkdir()
    box = "0 0 -1 10 20 110 80 1.5 1.6 3.9 2.9 1.6 6.4 0.1 0.9"
    bad_result.write_text(f"0 1 Car {box}\n1 1 Bogus {box}\n")
    with pytest.raises(InputError) as excinfo:
        evaluate_kitti_sequence(
            label_file=LABEL, result_file=bad_result, num_timesteps=447,
            classes=["car"],
        )  # fmt: skip
    assert str(excinfo.value).startswith(f"{bad_result}: TrackEval cannot read it: ")

    def refused(args: argparse.Namespace) -> int:
        raise trackeval.utils.TrackEvalException("File x.txt\ncannot be read")

    monkeypatch.setattr(validate, "run", refused)
    assert main(["validate", "x.json"]) == 2
    assert (
        capfd.readouterr().err == "mctrack validate: error: TrackEval: File x.txt cannot be read\n"
    )


def test_evaluate_kitti_names_a_refused_result_file_when_asked(tmp_path: Path) -> None:
    """A result file TrackEval loads but refuses (a track id twice in one frame): with
    ``name_refused_results`` (a run's own files: `mctrack compare`) an InputError naming it,
    its line, frame and id (TrackEval's words: "frame: 3, ids: 0", its frame 1-based and its
    ids renumbered), or by the name given for a temporary copy (`mctrack eval`); without,
    TrackEval's own exception, as before."""
    import trackeval

    from tracker.eval.kitti import evaluate_kitti

    data = tmp_path / "data"
    data.mkdir()
    row = "2 7 Car 0 0 -1 10 20 110 80 1.5 1.6 3.9 2.9 1.6 6.4 0.1 0.9\n"
    (data / "0001.txt").write_text(row.replace("2 7", "1 7") + row + row)
    args = dict(label_dir=LABEL.parent, result_dir=data, seq_lengths={"0001": 447}, classes=["car"])
    with pytest.raises(trackeval.utils.TrackEvalException, match="frame: 3, ids: 0"):
        evaluate_kitti(**args)
    with pytest.raises(InputError) as excinfo:
        evaluate_kitti(**args, name_refused_results=True)
    assert excinfo.value.path == str(data / "0001.txt")
    assert str(excinfo.value) == (
        f"{data / '0001.txt'}:3: field 'track_id': frame 2: track id 7 (Car) is also on line 2:"
        " one track twice in one frame"
    )
    with pytest.raises(InputError) as excinfo:
        evaluate_kitti(**args, name_refused_results={"0001": "t.json: scene 0001"})
    assert str(excinfo.value) == (
        "t.json: scene 0001 frame 2: track id 7 (Car) twice: one track twice in one frame"
    )


def test_evaluate_kitti_names_an_unreadable_temporary_row_by_its_source(tmp_path: Path) -> None:
    """A row TrackEval cannot read (a type it does not know) in a temporary copy named by its
    source (`mctrack eval`'s backstop; eval itself writes KITTI types alone): the error names
    the source, scene and frame, and the row, not the temporary file."""
    from tracker.eval.kitti import evaluate_kitti

    data = tmp_path / "data"
    data.mkdir()
    row = "2 7 bicycle 0 0 -1 10 20 110 80 1.5 1.6 3.9 2.9 1.6 6.4 0.1 0.9\n"
    (data / "0001.txt").write_text(row)
    with pytest.raises(InputError) as excinfo:
        evaluate_kitti(
            label_dir=LABEL.parent, result_dir=data, seq_lengths={"0001": 447}, classes=["car"],
            name_refused_results={"0001": "t.json: scene 0001"},
        )  # fmt: skip
    message = str(excinfo.value)
    assert message.startswith("t.json: scene 0001 frame 2: TrackEval cannot read"), message
    assert " bicycle " in message and str(data) not in message


@pytest.fixture(scope="module")
def sample_tracks(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The sample tracked whole and on frames 20:40 (`mctrack track --frames`)."""
    out = tmp_path_factory.mktemp("tracks")
    tracks = {}
    for name, frames in (("all", []), ("window", ["--frames=20:40"])):
        argv = ["track", str(SAMPLE / "detections.json.gz"), *frames, "--out", str(out / name)]
        assert main(argv) == 0
        tracks[name] = out / name / "tracks.json"
    return tracks


@pytest.mark.parametrize("motion", [False, True])
def test_eval_refuses_a_detections_file_given_as_the_tracks(
    motion: bool, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A detections file (no box has a track id) given as the tracks was scored as a tracker
    that wrote nothing (HOTA 0), without a word."""
    dets = SAMPLE / "detections.json.gz"
    argv = ["eval", str(dets), "--gt", str(SAMPLE / "gt.json.gz"), "--labels", str(LABEL.parent)]
    code, err = _run([*argv, *(["--motion"] if motion else []), "--out", str(tmp_path)], capsys)
    _one_line_error(code, err, f"{dets}: no box has a track_id (a detections file?")
    assert not (tmp_path / "eval.json").exists()


@pytest.mark.parametrize("motion", [False, True])
def test_eval_refuses_a_detections_file_given_as_the_ground_truth(
    motion: bool,
    sample_tracks: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A detections file (no box has a track id) given as --gt: the motion metrics followed its
    "objects" (every box one without an id), the static ones took its frames as the ground
    truth's, without a word."""
    dets = SAMPLE / "detections.json.gz"
    argv = ["eval", str(sample_tracks["all"]), "--gt", str(dets), "--out", str(tmp_path)]
    argv += ["--motion"] if motion else ["--labels", str(LABEL.parent)]
    code, err = _run(argv, capsys)
    _one_line_error(code, err, f"{dets}: no box has a track_id: not ground truth")
    assert not (tmp_path / "eval.json").exists()


def test_eval_refuses_to_evaluate_nothing(
    sample_tracks: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without --labels and --motion eval computed nothing, wrote an eval.json of nothing and
    exited 0."""
    argv = ["eval", str(sample_tracks["all"]), "--gt", str(SAMPLE / "gt.json.gz")]
    code, err = _run([*argv, "--out", str(tmp_path)], capsys)
    _one_line_error(code, err, "nothing to evaluate: add --labels DIR", "--motion")
    assert not (tmp_path / "eval.json").exists()


def test_eval_prints_the_metrics_as_kitti_does(
    sample_tracks: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The static and motion metrics are printed (it printed only "wrote eval.json and
    eval.md"), in `mctrack kitti`'s table."""
    from app.common import METRIC_COLUMNS

    argv = ["eval", str(sample_tracks["all"]), "--gt", str(SAMPLE / "gt.json.gz"), "--motion"]
    assert main([*argv, "--labels", str(LABEL.parent), "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    record = json.loads((tmp_path / "eval.json").read_text())
    assert lines[1].split() == ["class", *METRIC_COLUMNS]
    car = next(line.split() for line in lines if line.startswith("car "))
    assert car == ["car", *(str(record["static"]["car"][c]) for c in METRIC_COLUMNS)]
    assert any(line.startswith("cyclist       absent: ") for line in lines)
    kalman = next(line.split() for line in lines if line.startswith("kalman "))
    assert float(kalman[1]) == pytest.approx(
        record["motion"]["metrics"]["kalman"]["all"]["vae_deg"], abs=1e-3
    )
    assert lines[-1].startswith("wrote ")


@pytest.mark.parametrize("motion", [False, True])
def test_eval_names_a_track_id_twice_in_one_frame_by_the_tracks_file(
    motion: bool, sample_tracks: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two boxes of one track in a frame of the tracks: one line naming the tracks file, scene,
    frame and id before any scoring. Was TrackEval's line ("Tracker predicts the same ID ...
    frame: 6, ids: ...": its frame 1-based, its ids renumbered) for the static metrics, and
    "unexpected error: ValueError" for the motion metrics."""
    tracks = json.loads(sample_tracks["all"].read_text())
    boxes = tracks["0001"][5]["bboxes"]
    boxes[1]["track_id"] = boxes[0]["track_id"]
    bad = tmp_path / "tracks.json"
    bad.write_text(json.dumps(tracks))
    argv = ["eval", str(bad), "--gt", str(SAMPLE / "gt.json.gz"), "--out", str(tmp_path / "o")]
    argv += ["--motion"] if motion else ["--labels", str(LABEL.parent)]
    code, err = _run(argv, capsys)
    _one_line_error(code, err)
    assert err.splitlines()[-1] == (
        f"mctrack eval: error: {bad}: scene 0001 frame {tracks['0001'][5]['frame_id']}: track id"
        f" {boxes[0]['track_id']} is on 2 boxes: one track twice in one frame"
    )
    assert not (tmp_path / "o" / "eval.json").exists()


@pytest.mark.parametrize("which", ["all", "window"])
def test_eval_leaves_boxes_of_other_classes_out_of_the_kitti_metrics_and_says_so(
    which: str,
    sample_tracks: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A box of a class KITTI does not score (a nuScenes class, bicycle) is left out of the
    KITTI files written for TrackEval, which refuses any other type, with a warning and a count
    in eval.json: the metrics are those of the tracks without it. It used to fail the run."""
    tracks = json.loads(sample_tracks[which].read_text())
    tracks["0001"][5]["bboxes"][0]["category"] = "bicycle"
    bad = tmp_path / "tracks.json"
    bad.write_text(json.dumps(tracks))
    del tracks["0001"][5]["bboxes"][0]
    without = tmp_path / "without.json"
    without.write_text(json.dumps(tracks))
    scored = []
    for name, path in (("with", bad), ("without", without)):
        argv = [
            "eval",
            str(path),
            "--gt",
            str(SAMPLE / "gt.json.gz"),
            "--labels",
            str(LABEL.parent),
        ]
        code, err = _run([*argv, "--out", str(tmp_path / name)], capsys)
        assert code == 0, err
        scored.append(json.loads((tmp_path / name / "eval.json").read_text()))
    assert scored[0]["static"] == scored[1]["static"]
    assert scored[0]["left_out_of_static"] == {"bicycle": 1}
    assert "left_out_of_static" not in scored[1]
    assert (
        f"{bad}: boxes of classes the KITTI metrics do not score, left out of them: 1 bicycle"
        in caplog.text
    )


def _eval(tracks: Path, labels: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> dict:
    argv = ["eval", str(tracks), "--gt", str(SAMPLE / "gt.json.gz"), "--labels", str(labels)]
    code, err = _run([*argv, "--classes", "car,pedestrian", "--out", str(out)], capsys)
    assert code == 0, err
    return json.loads((out / "eval.json").read_text())


def _cut(source: Path, target: Path, first: int, count: int) -> None:
    """The KITTI rows of frames first..first+count-1, renumbered from 0 (the test's own)."""
    rows = [line.split(" ") for line in source.read_text().splitlines()]
    kept = [[str(int(r[0]) - first), *r[1:]] for r in rows if first <= int(r[0]) < first + count]
    target.write_text("".join(" ".join(r) + "\n" for r in kept))


def test_eval_scores_the_frames_the_tracks_file_covers(
    sample_tracks: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    from tracker.eval.kitti import combine_sequences, evaluate_kitti_sequence
    from tracker.io.writers import read_tracks_file, write_kitti_sequence

    labels = LABEL.parent
    result = _eval(sample_tracks["window"], labels, tmp_path / "e", capsys)
    assert result["evaluated_frames"] == {"0001": [20, 39]}
    assert "scored on the frames the tracks file covers alone (0001 20-39)" in caplog.text
    assert "0001 20-39" in (tmp_path / "e" / "eval.md").read_text()
    # the same as TrackEval on both files cut to the window by hand
    frames, outputs = read_tracks_file(sample_tracks["window"])
    write_kitti_sequence(tmp_path / "all.txt", outputs["0001"], frames["0001"])
    (tmp_path / "l").mkdir()
    _cut(LABEL, tmp_path / "l" / "0001.txt", 20, 20)
    _cut(tmp_path / "all.txt", tmp_path / "r.txt", 20, 20)
    classes = ["car", "pedestrian"]
    expected = evaluate_kitti_sequence(
        label_file=tmp_path / "l" / "0001.txt",
        result_file=tmp_path / "r.txt",
        num_timesteps=20,
        classes=classes,
    )
    combined = combine_sequences([expected], classes)
    assert result["static"] == {"car": combined["car"]}  # (no pedestrian in 20-39: absent)
    assert result["static_absent"] == {
        "pedestrian": "no ground-truth pedestrian in these sequences; no tracked pedestrian either"
    }  # (none tracked: not "0 tracked boxes, all false positives")
    assert result["static"]["car"]["FN"] < 50  # (every labelled frame: > 1000)
    # a whole run is scored as before, on every frame, and says nothing
    whole = _eval(sample_tracks["all"], labels, tmp_path / "w", capsys)
    assert "evaluated_frames" not in whole and "evaluation" not in whole
    assert whole["evaluated_sequences"] == ["0001"]


def test_eval_scores_the_labelled_sequences_and_names_the_rest(
    sample_tracks: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A second scene without labels (the sample's, renamed 0002) leaves the static metrics
    those of 0001 alone, and says so (it skipped them all)."""
    two = json.loads(sample_tracks["all"].read_text())
    two["0002"] = two["0001"]
    (tmp_path / "two.json").write_text(json.dumps(two))
    one = _eval(sample_tracks["all"], LABEL.parent, tmp_path / "one", capsys)
    both = _eval(tmp_path / "two.json", LABEL.parent, tmp_path / "both", capsys)
    assert both["static"] == one["static"]
    assert both["evaluated_sequences"] == ["0001"]
    assert both["evaluation"] == f"scored on ['0001']; no labels for ['0002'] in {LABEL.parent}"
    assert both["evaluation"] in caplog.text


@pytest.mark.parametrize("command", ["kitti", "eval"])
def test_a_longer_sequences_labels_are_refused(
    command: str, sample_tracks: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    labels = _labels(tmp_path / "labels", "500" + GOOD_ROW[GOOD_ROW.index(" ") :])
    if command == "kitti":
        argv = ["kitti", "--kitti-root", str(SAMPLE_KIT), "--seqs", "0001", "--labels"]
        code, err = _run([*argv, str(labels), "--out", str(tmp_path / "o")], capsys)
        length = "447 frames (the pose lines of"
    else:
        argv = ["eval", str(sample_tracks["all"]), "--gt", str(SAMPLE / "gt.json.gz")]
        code, err = _run([*argv, "--labels", str(labels), "--out", str(tmp_path / "o")], capsys)
        length = "447 frames (the frames of --gt)"
    _one_line_error(code, err, f"0001.txt:{N_LINES + 1}", "'frame'", "frame 500", length)


def test_kitti_refuses_the_reviewers_label_file(
    kitti_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The review's case: 0012's labels and a 5-column line, with the virconv detections."""
    source = kitti_root / "training" / "label_02" / "0012.txt"
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "0012.txt").write_text(source.read_text() + "3 2 Car 0 0\n")
    argv = ["kitti", "--kitti-root", str(kitti_root), "--detector", "virconv", "--seqs", "0012"]
    argv += ["--classes", "car", "--labels", str(tmp_path / "labels"), "--out", str(tmp_path / "o")]
    code, err = _run(argv, capsys)
    n = len(source.read_text().splitlines()) + 1
    _one_line_error(code, err, f"0012.txt:{n}: field 'columns': expected 17 or 18 columns, got 5")
    # the detections given as labels (was TrackEval's traceback, then "unexpected error")
    detections = kitti_root / "detections" / "virconv" / "training"
    code, err = _run([*argv[:-4], "--labels", str(detections), *argv[-2:]], capsys)
    _one_line_error(code, err, f"{detections / '0012.txt'}:1: field 'track_id': not a number")


def test_eval_shows_a_class_without_ground_truth_as_absent_as_kitti_does(
    sample_tracks: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The sample (0001) has no labelled cyclist: its tracked cyclists are all false positives
    (HOTA 0, MOTA -2300), so eval reports the class absent, with mctrack kitti's rule, wording
    and JSON shape (scored metrics without it, {class: why} beside them); the other classes'
    metrics stay as they were."""
    argv = ["eval", str(sample_tracks["all"]), "--gt", str(SAMPLE / "gt.json.gz")]
    code = main([*argv, "--labels", str(LABEL.parent), "--out", str(tmp_path / "e")])
    printed = capsys.readouterr().out
    assert code == 0
    result = json.loads((tmp_path / "e" / "eval.json").read_text())
    why = "no ground-truth cyclist in these sequences; 23 tracked boxes, all false positives"
    assert result["static_absent"] == {"cyclist": why}
    assert list(result["static"]) == ["car", "pedestrian"]
    assert f"cyclist       absent: {why}" in printed.splitlines()
    assert f"| cyclist | absent: {why} |" in (tmp_path / "e" / "eval.md").read_text()
    scored = _eval(sample_tracks["all"], LABEL.parent, tmp_path / "cp", capsys)
    assert result["static"] == scored["static"] and "static_absent" not in scored


def test_eval_warns_when_the_tracks_file_is_the_ground_truth(
    sample_tracks: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """`mctrack eval GT --gt GT` (or a copy of GT) was scored, without a word, as a near-perfect
    tracker (car HOTA 99.95): one warning says the tracks file looks like the ground truth."""
    import gzip

    gt = SAMPLE / "gt.json.gz"
    (tmp_path / "copy.json").write_bytes(gzip.decompress(gt.read_bytes()))
    for tracks in (gt, tmp_path / "copy.json"):
        caplog.clear()
        result = _eval(tracks, LABEL.parent, tmp_path / f"e_{tracks.name}", capsys)
        assert result["static"]["car"]["HOTA"] > 99
        said = [r.getMessage() for r in caplog.records if "ground truth itself" in r.message]
        assert said == [
            f"{tracks}: the tracks file looks like the ground truth itself (--gt {gt}: the same "
            "boxes and track ids): it is scored as a (near-)perfect tracker"
        ]
    caplog.clear()
    _eval(sample_tracks["all"], LABEL.parent, tmp_path / "tracked", capsys)
    assert "ground truth itself" not in caplog.text


def test_eval_refuses_scenes_whose_files_differ_only_in_case(
    sample_tracks: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Scenes x and X of a tracks file were scored from --labels/x.txt and --labels/X.txt
    through temporary x.txt and X.txt: one file each on a case-insensitive filesystem (macOS's
    /tmp), so X was scored against x's labels, its KITTI file over x's. Refused, as `mctrack
    track --kitti-results` and `mctrack kitti --seqs` refuse them, before any output; without
    --labels (no file per scene) it is not."""
    tracks = json.loads(sample_tracks["all"].read_text())
    both = tmp_path / "both.json"
    both.write_text(json.dumps({"x": tracks["0001"], "X": tracks["0001"]}))
    labels = tmp_path / "labels"
    labels.mkdir()
    shutil.copy(LABEL, labels / "x.txt")
    out = tmp_path / "out"
    argv = ["eval", str(both), "--gt", str(SAMPLE / "gt.json.gz"), "--out", str(out)]
    code, err = _run([*argv, "--labels", str(labels)], capsys)
    _one_line_error(
        code, err, f"{both}: scenes 'x' and 'X' differ only in case: their files (x.txt, X.txt)"
    )
    assert not out.exists()
    code, err = _run([*argv, "--motion"], capsys)  # (no ground truth for x and X: said)
    assert code == 0 and (out / "eval.json").is_file(), err
