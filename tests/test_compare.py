"""`mctrack compare`: event matching, hand-made runs with known differences, and two real runs
of a KITTI validation sequence with different configs."""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path

import pytest

from app.cli import main
from tests.report_fixtures import RUN_A, SEQ, make_runs, write_run
from tracker.eval.compare import match_events


def _event(frame: int, gt: int = 1, kind: str = "IDSW", seq: str = "0001", cls: str = "car"):
    return {
        "sequence": seq,
        "kind": kind,
        "frame": frame,
        "class": cls,
        "gt_id": gt,
        "old_track": 1,
        "new_track": 2,
        "cause": None,
        "event": None,
    }


def _statuses(pairs):
    return [(p["status"], (p["a"] or p["b"])["frame"]) for p in pairs]


def test_match_events_tolerance_is_inclusive_and_closest_first() -> None:
    a = [_event(10), _event(20)]
    b = [_event(12), _event(19), _event(40)]
    pairs = match_events(a, b, tolerance=2)
    # 20 pairs with 19 (1 apart), 10 with 12 (2 apart: inside), 40 has no partner
    kept = sorted((p["a"]["frame"], p["b"]["frame"]) for p in pairs if p["status"] == "kept")
    assert kept == [(10, 12), (20, 19)]
    assert [p["b"]["frame"] for p in pairs if p["status"] == "introduced"] == [40]
    assert not [p for p in pairs if p["status"] == "fixed"]
    # one frame less tolerance: 10 and 12 are different events
    pairs = match_events(a, b, tolerance=1)
    assert sorted(_statuses(pairs)) == [
        ("fixed", 10),
        ("introduced", 12),
        ("introduced", 40),
        ("kept", 20),
    ]


def test_match_events_needs_same_sequence_kind_class_and_gt() -> None:
    a = [_event(5), _event(5, gt=2), _event(5, kind="Frag"), _event(5, seq="0002")]
    b = [_event(5, gt=3), _event(5, cls="pedestrian")]
    pairs = match_events(a, b)
    assert [p["status"] for p in pairs].count("kept") == 0
    assert [p["status"] for p in pairs].count("fixed") == 4
    assert [p["status"] for p in pairs].count("introduced") == 2
    with pytest.raises(ValueError):
        match_events(a, b, tolerance=-1)


def test_compare_hand_made_runs(tmp_path: Path, capsys) -> None:
    a, b, _ = make_runs(tmp_path)
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    result = json.loads((out / "compare.json").read_text())
    got = {
        p["status"]: (
            (p["a"] or p["b"])["gt_id"],
            p["a"] and p["a"]["frame"],
            p["b"] and p["b"]["frame"],
        )
        for p in result["events"]
    }
    assert len(result["events"]) == 3
    assert got == {"fixed": (1, 5, None), "kept": (2, 3, 4), "introduced": (3, None, 6)}
    fixed = next(p["a"] for p in result["events"] if p["status"] == "fixed")
    assert (fixed["old_track"], fixed["new_track"], fixed["kind"]) == (1, 2, "IDSW")
    assert result["counts"][SEQ]["car IDSW"] == {"fixed": 1, "introduced": 1, "kept": 1}
    assert result["metrics"]["car"]["HOTA"] == {"a": 90.0, "b": 95.0, "delta": 5.0}
    assert (
        result["metrics"]["car"]["IDSW"]["delta"] == 0
    )  # 2 -> 2: the same count, not the same switches
    md = (out / "compare.md").read_text()
    assert "- 0001 f5 car GT1 T1->T2 IDSW" in md and "- 0001 f6 car GT3 T5->T6 IDSW" in md
    # a tolerance of 0: the kept switch moved one frame, so it counts as fixed + introduced
    assert main(["compare", str(a), str(b), "--out", str(out), "--tolerance", "0"]) == 0
    result = json.loads((out / "compare.json").read_text())
    assert result["counts"]["total"]["car IDSW"] == {"fixed": 2, "introduced": 2, "kept": 0}
    # the recorded command repeats the comparison: --tolerance (and the other options) included
    assert result["command"] == shlex.join(
        ["mctrack", "compare", str(a), str(b), "--out", str(out), "--tolerance", "0"]
    )
    assert f"`{result['command']}`" in (out / "compare.md").read_text()


def test_compare_bad_input_is_one_line(tmp_path: Path, capsys) -> None:
    a, b, _ = make_runs(tmp_path)
    (b / "summary.json").write_text('{"command": "kitti", "sequences": "0001"}')
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "summary.json" in err and "'sequences'" in err
    shutil.rmtree(b)
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "o")]) == 2
    assert "not found" in capsys.readouterr().err
    # a result file with a non-numeric frame names the file and the line
    a2, b2, _ = make_runs(tmp_path / "again")
    data = b2 / "data" / f"{SEQ}.txt"
    data.write_text("x" + data.read_text())
    assert main(["compare", str(a2), str(b2), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"{SEQ}.txt" in err and "line 1" in err
    # a sequence name from summary.json never leaves the run folder
    a3, b3, _ = make_runs(tmp_path / "third")
    s = json.loads((b3 / "summary.json").read_text())
    s["sequences"] = ["../../etc/passwd"]
    (b3 / "summary.json").write_text(json.dumps(s))
    assert main(["compare", str(a3), str(b3), "--out", str(tmp_path / "o")]) == 2
    assert "missing" in capsys.readouterr().err


def test_compare_record_refused_writes_nothing(tmp_path: Path, capsys) -> None:
    """--record of runs without tracks.json is refused before compare.json and compare.md are
    written (they were left behind, without the recordings, by the failed command)."""
    a, b, _ = make_runs(tmp_path)
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "--out", str(out), "--record"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"mctrack compare: error: {a / 'tracks.json'}: missing (--record draws each run's "
        "tracks from it)"
    )
    assert not out.exists()  # (was left behind, empty)


def _as_if_recorded(out: Path) -> None:
    """``out``'s comparison as a --record one leaves it: recordings/<SEQ>.rrd, listed in its
    compare.json (hand-made runs have no tracks.json to record)."""
    (out / "recordings").mkdir(exist_ok=True)
    (out / "recordings" / f"{SEQ}.rrd").write_bytes(b"an earlier --record's")
    result = json.loads((out / "compare.json").read_text())
    result["recordings"] = {SEQ: str(out / "recordings" / f"{SEQ}.rrd")}
    (out / "compare.json").write_text(json.dumps(result))


def test_compare_into_an_earlier_comparison_removes_its_recordings(tmp_path: Path) -> None:
    """An earlier --record's recordings/<seq>.rrd (of other runs) do not stay beside the new
    compare.json; a run folder's own recordings are never touched."""
    a, b, _ = make_runs(tmp_path)
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    _as_if_recorded(out)
    (out / "notes.txt").write_text("mine")
    # a refused comparison (--record of runs without tracks.json) keeps the earlier one
    assert main(["compare", str(a), str(b), "--out", str(out), "--record"]) == 2
    assert (out / "recordings" / f"{SEQ}.rrd").is_file() and (out / "compare.json").is_file()
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["compare.json", "compare.md", "notes.txt"]
    # of recordings/, only those its compare.json lists went: a user's stays
    _as_if_recorded(out)
    (out / "recordings" / "mine.rrd").write_bytes(b"mine")
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    assert [p.name for p in (out / "recordings").iterdir()] == ["mine.rrd"]
    assert "recordings" not in json.loads((out / "compare.json").read_text())
    # the output folder is run A itself (it has its summary.json): its recording stays
    (a / "recordings").mkdir()
    (a / "recordings" / f"{SEQ}.rrd").write_bytes(b"run a's own")
    for _ in range(2):
        assert main(["compare", str(a), str(b), "--out", str(a)]) == 0
    assert (a / "recordings" / f"{SEQ}.rrd").read_bytes() == b"run a's own"


def test_compare_into_a_run_folder_removes_the_recordings_its_compare_json_lists(
    tmp_path: Path,
) -> None:
    """A second comparison into a run folder without --record rewrote compare.json without
    "recordings": the first comparison's recordings were listed nowhere and outlived the next
    run there. Now they go first; the run's own (its summary lists them) and a user's stay."""
    a, b, _ = make_runs(tmp_path)
    summary = json.loads((a / "summary.json").read_text())
    summary["recordings"] = {SEQ: str(a / "recordings" / f"{SEQ}.rrd")}
    (a / "summary.json").write_text(json.dumps(summary))
    assert main(["compare", str(a), str(b), "--out", str(a)]) == 0
    result = json.loads((a / "compare.json").read_text())
    result["recordings"] = {s: str(a / "recordings" / f"{s}.rrd") for s in (SEQ, "0007")}
    (a / "compare.json").write_text(json.dumps(result))
    (a / "recordings").mkdir()
    for name in (SEQ, "0007", "mine"):
        (a / "recordings" / f"{name}.rrd").write_bytes(name.encode())
    assert main(["compare", str(a), str(b), "--out", str(a)]) == 0
    assert sorted(p.name for p in (a / "recordings").iterdir()) == [f"{SEQ}.rrd", "mine.rrd"]
    assert (a / "recordings" / f"{SEQ}.rrd").read_bytes() == SEQ.encode()


@pytest.mark.parametrize("which", ["a", "b"])
def test_compare_record_into_a_compared_run_is_refused(which: str, tmp_path: Path, capsys) -> None:
    """--record --out RUN wrote the side-by-side recording over the run's own
    recordings/<seq>.rrd (which compare reads the run's events from): refused before any
    work, naming the run and its file, which stays."""
    runs = dict(zip("ab", make_runs(tmp_path)[:2], strict=True))
    own = runs[which] / "recordings" / f"{SEQ}.rrd"
    own.parent.mkdir()
    own.write_bytes(b"the run's own")
    argv = ["compare", str(runs["a"]), str(runs["b"]), "--out", str(runs[which]), "--record"]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == (
        f"mctrack compare: error: {runs[which]}: RUN_{which.upper()} holds recordings/{SEQ}.rrd,"
        f" a file this run writes in {runs[which]}: move it, or give another --out"
    )
    assert own.read_bytes() == b"the run's own"
    assert not (runs[which] / "compare.json").exists()
    # a run folder without recordings of its own: the comparison's would later be read as its
    own.unlink()
    own.parent.rmdir()
    assert main(argv) == 2
    assert capsys.readouterr().err.strip() == (
        f"mctrack compare: error: {runs[which]}: --out is RUN_{which.upper()}, a run folder: "
        "--record would write the comparison's recordings into the run's own recordings/; give"
        " another --out"
    )
    assert not (runs[which] / "recordings").exists()


def test_compare_record_into_a_third_run_is_refused_over_its_recordings(
    tmp_path: Path, capsys
) -> None:
    """--record --out C, C holding a third run whose summary.json lists recordings/<seq>.rrd:
    the comparison's recording was written over the run's own (still listed as its). Refused
    before anything is written, naming the file, which stays."""
    a, b, labels = make_runs(tmp_path)
    for run in (a, b):  # (tracks.json: what --record draws; no frame is needed to refuse)
        (run / "tracks.json").write_text(json.dumps({SEQ: []}))
    c = write_run(tmp_path / "c", RUN_A, labels, name="c")
    own = c / "recordings" / f"{SEQ}.rrd"
    own.parent.mkdir()
    own.write_bytes(b"run c's own")
    summary = json.loads((c / "summary.json").read_text())
    summary["recordings"] = {SEQ: str(own)}
    (c / "summary.json").write_text(json.dumps(summary))
    assert main(["compare", str(a), str(b), "--out", str(c), "--record"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"mctrack compare: error: {own}: the run in {c} lists it as its own recording (its "
        "summary.json): --record would overwrite it with the comparison's; give another --out"
    )
    assert own.read_bytes() == b"run c's own"
    assert sorted(p.name for p in c.iterdir()) == ["data", "recordings", "summary.json"]


@pytest.mark.parametrize(
    ("field", "value", "named"),
    [
        ("metrics", "absent", "field 'metrics': expected an object"),
        ("metrics", {"car": "x"}, "field 'metrics' 'car': expected an object"),
        ("per_sequence_metrics", {SEQ: "x"}, f"field 'per_sequence_metrics' '{SEQ}': expected"),
        ("per_sequence", {SEQ: {"car": [1]}}, f"field 'per_sequence' '{SEQ}' 'car': expected"),
        ("motion", {"metrics": {"kalman": "x"}}, "field 'motion' 'metrics' 'kalman': expected"),
        # a value shown, plotted and subtracted (a hand-edited "x" was shown as "x → 79.177")
        ("metrics", {"car": {"HOTA": "x"}}, "field 'metrics' 'car' 'HOTA': expected a number, got"),
        (
            "per_sequence",
            {SEQ: {"car": {"IDSW": True}}},
            f"field 'per_sequence' '{SEQ}' 'car' 'IDSW': expected a number, got True",
        ),
        (
            "motion",
            {"metrics": {"kalman": {"car": {"vae_deg": "1.5", "note": "n/a"}}}},
            "field 'motion' 'metrics' 'kalman' 'car' 'vae_deg': expected a number, got '1.5'",
        ),
        ("failed", 3, "field 'failed': expected an object"),
        ("failed", SEQ, "field 'failed': expected an object"),  # ("1" in "0001": failed)
        ("config", "x", "field 'config': expected an object"),
        ("labels", 3, "field 'labels': expected a folder path"),  # (was: the default kit's)
        ("sequences", [SEQ, SEQ], f"field 'sequences': {SEQ} listed more than once"),
        ("evaluated_sequences", ["0002"], "field 'evaluated_sequences': 0002 not in 'sequences'"),
    ],
)
def test_compare_and_report_name_a_malformed_summary_field(
    tmp_path: Path, capsys, field: str, value: object, named: str
) -> None:
    """Each shape compare and report index into is checked on reading (these were 'unexpected
    error: AttributeError', or a sequence listed twice had its events counted twice)."""
    a, b, _ = make_runs(tmp_path)
    summary = json.loads((b / "summary.json").read_text())
    (b / "summary.json").write_text(json.dumps({**summary, field: value}))
    for args in (["compare", str(a), str(b)], ["report", str(a), "--compare", str(b)]):
        assert main([*args, "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1
        assert err.startswith(f"mctrack {args[0]}: error: {b / 'summary.json'}: {named}")


@pytest.mark.parametrize(
    "foreign",
    [
        {"sequences": [SEQ], "classes": ["car"], "tool": "another"},  # (was a half-filled table)
        {"command": "eval", "sequences": [SEQ], "classes": ["car"]},  # (not a run's command)
        {},
    ],
)
def test_compare_and_report_refuse_a_foreign_summary(tmp_path: Path, capsys, foreign: dict) -> None:
    """A folder whose summary.json is not a run's (app.outputs.is_run_summary, the rule by
    which a run replaces a folder's files) is refused in one line naming the file; one holding
    a run's field names was compared as a run with no metrics (B's column all '–')."""
    a, b, _ = make_runs(tmp_path)
    (b / "summary.json").write_text(json.dumps(foreign))
    for args in (["compare", str(a), str(b)], ["report", str(a), "--compare", str(b)]):
        assert main([*args, "--out", str(tmp_path / "o")]) == 2
        assert capsys.readouterr().err.strip() == (
            f"mctrack {args[0]}: error: {b / 'summary.json'}: not a run's summary.json (no "
            '"command" naming an mctrack run: another tool\'s file?): pass a `mctrack kitti '
            "--out` folder"
        )
        assert not (tmp_path / "o").exists()


def test_compare_into_a_folder_with_a_foreign_summary_replaces_its_earlier_comparison(
    tmp_path: Path,
) -> None:
    """--out holding anyone's summary.json is not a run folder: an earlier comparison's
    recordings there go with it, as in any other folder (they stayed, as a run's own)."""
    a, b, _ = make_runs(tmp_path)
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    (out / "summary.json").write_text('{"mine": true}')
    _as_if_recorded(out)
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["compare.json", "compare.md", "summary.json"]
    assert (out / "summary.json").read_text() == '{"mine": true}'


def _with_second_sequence(run: Path, labels: Path, *, failed: bool = False) -> None:
    """Run a hand-made run over "0002" too (a copy of "0001": the same two ID switches in A),
    or, with ``failed``, a run whose "0002" failed (no result file, no metrics)."""
    shutil.copy(labels / f"{SEQ}.txt", labels / "0002.txt")
    summary = json.loads((run / "summary.json").read_text())
    summary["sequences"] = [SEQ, "0002"]
    if failed:
        summary["failed"] = {"0002": "ValueError: boom"}
        del summary["metrics"]  # (app.kitti skips the evaluation of a run with a failure)
    else:
        shutil.copy(run / "data" / f"{SEQ}.txt", run / "data" / "0002.txt")
        summary["per_sequence"]["0002"] = summary["per_sequence"][SEQ]
    (run / "summary.json").write_text(json.dumps(summary))


def test_compare_leaves_out_a_sequence_one_run_did_not_track(tmp_path: Path, capsys) -> None:
    """A's switches on a sequence B never tracked are not "fixed", and A's HOTA shown is over
    the shared sequence (scored again from its result file), not over both of A's."""
    from tracker.eval.kitti import evaluate_kitti

    a, b, labels = make_runs(tmp_path)
    _with_second_sequence(a, labels)
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == (
        f"Compared the 1 sequence(s) both runs tracked and scored ({SEQ}); left out: 0002 "
        "(not in b); metrics of a scored again on them"
    )
    result = json.loads((out / "compare.json").read_text())
    assert {(p["a"] or p["b"])["sequence"] for p in result["events"]} == {SEQ}
    assert result["counts"]["total"]["car IDSW"] == {"fixed": 1, "introduced": 1, "kept": 1}
    assert result["sequences_left_out"] == {"0002": "not in b"}
    alone = evaluate_kitti(label_dir=labels, result_dir=a / "data", seq_lengths={SEQ: 10},
                           classes=["car"])["car"]["HOTA"]  # fmt: skip
    assert result["metrics"]["car"]["HOTA"]["a"] == alone != 90.0  # (90: A's summary, both)
    assert result["metrics"]["car"]["HOTA"]["b"] == 95.0  # B's summary: over SEQ exactly
    assert list(result["per_sequence"]) == [SEQ]
    assert "- Scope: compared the 1 sequence(s)" in (out / "compare.md").read_text()
    # the report of the same pair says so above its metrics
    report = tmp_path / "report"
    assert main(["report", str(a), "--compare", str(b), "--out", str(report)]) == 0
    page = (report / "index.html").read_text()
    assert "Compared the 1 sequence(s) both runs tracked and scored" in page


def test_compare_leaves_out_the_events_of_a_class_one_run_did_not_track(
    tmp_path: Path, capsys
) -> None:
    """B tracked pedestrians only: A's car switches are not "fixed" by B."""
    a, b, _ = make_runs(tmp_path)
    for run, classes in ((a, ["car", "pedestrian"]), (b, ["pedestrian"])):
        summary = json.loads((run / "summary.json").read_text())
        (run / "summary.json").write_text(json.dumps({**summary, "classes": classes}))
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == (
        "Events of classes one run did not track are not compared: car (not tracked in b)"
    )
    result = json.loads((out / "compare.json").read_text())
    assert result["events"] == [] and result["classes_left_out"] == {"car": "not tracked in b"}


def test_compare_leaves_out_a_sequence_that_failed_in_one_run(tmp_path: Path, capsys) -> None:
    a, b, labels = make_runs(tmp_path)
    _with_second_sequence(a, labels)
    _with_second_sequence(b, labels, failed=True)
    out = tmp_path / "cmp"
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    assert (
        "left out: 0002 (failed in b); metrics of a and b scored again" in capsys.readouterr().out
    )
    result = json.loads((out / "compare.json").read_text())
    assert result["counts"]["total"]["car IDSW"] == {"fixed": 1, "introduced": 1, "kept": 1}
    hota = result["metrics"]["car"]["HOTA"]
    assert hota["a"] is not None and hota["b"] is not None  # (B had no metrics at all)


def _repeat_a_track_id(result: Path) -> None:
    """``result`` with its first row twice: a track id twice in frame 0, which TrackEval reads
    but refuses (its preprocessing raises)."""
    rows = result.read_text().splitlines(keepends=True)
    result.write_text(rows[0] + "".join(rows))


def test_compare_names_a_result_file_trackeval_refuses(tmp_path: Path, capsys) -> None:
    """A result file TrackEval reads but refuses is one line naming it, whether the events
    (loading the run) or the metrics (scoring it again on the shared sequences) meet it."""
    from app.compare import compare_result
    from app.runs import load_run
    from tracker.errors import InputError

    a, b, labels = make_runs(tmp_path)
    _with_second_sequence(a, labels)
    run_a, run_b = load_run(a, name="a"), load_run(b, name="b")
    _repeat_a_track_id(a / "data" / "0002.txt")  # (not compared: not scored again)
    assert compare_result(run_a, run_b, tolerance=2)["rescored"] == ["a"]
    _repeat_a_track_id(a / "data" / f"{SEQ}.txt")
    with pytest.raises(InputError) as excinfo:  # (the run's events were read before)
        compare_result(run_a, run_b, tolerance=2)
    # its line, frame and id (TrackEval's words: "frame: 1, ids: 0", 1-based and renumbered)
    first = (a / "data" / f"{SEQ}.txt").read_text().split(maxsplit=2)
    named = (
        f"{a / 'data' / f'{SEQ}.txt'}:2: field 'track_id': frame {first[0]}: track id {first[1]}"
        " (Car) is also on line 1: one track twice in one frame"
    )
    assert str(excinfo.value) == named
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == f"mctrack compare: error: {named}\n"


def test_compare_refuses_runs_without_a_shared_sequence(tmp_path: Path, capsys) -> None:
    a, b, labels = make_runs(tmp_path)
    shutil.copy(labels / f"{SEQ}.txt", labels / "0002.txt")
    (b / "data" / f"{SEQ}.txt").rename(b / "data" / "0002.txt")
    summary = json.loads((b / "summary.json").read_text())
    summary["sequences"] = ["0002"]
    (b / "summary.json").write_text(json.dumps(summary))
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"mctrack compare: error: {b}: no sequence that both runs tracked and scored (a: {SEQ}; "
        "b: 0002): compare runs of the same sequences"
    )


def test_compare_and_report_say_a_track_folder_is_the_wrong_kind(tmp_path: Path, capsys) -> None:
    """Each with advice it can follow: report, which has no --gt, advised `report
    t/tracks.json --gt GT.json` (as compare does), an unrecognized argument."""
    sample = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"
    track = tmp_path / "t"
    args = ["track", str(sample / "detections.json.gz"), "--frames", "0:20", "--out", str(track)]
    assert main(args) == 0
    a, _, _ = make_runs(tmp_path)
    capsys.readouterr()
    assert main(["compare", str(a), str(track), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"mctrack compare: error: {track}: a `mctrack track` output folder; compare reads "
        f"`mctrack kitti --out` folders, or tracks files with their ground truth "
        f"({track / 'tracks.json'} --gt GT.json)"
    )
    for args in ([str(track)], [str(a), "--compare", str(track)]):
        assert main(["report", *args, "--out", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err.strip()
        assert err == (
            f"mctrack report: error: {track}: a `mctrack track` output folder; report reads "
            "`mctrack kitti --out` folders (compare its tracks file with another: mctrack "
            f"compare {track / 'tracks.json'} OTHER_TRACKS --gt GT.json --out DIR)"
        )


# ---------------------------------------------------------------------------------------------
# Two real runs of a validation sequence: the tuned config (recorded) and kitti_reference


def test_compare_real_runs_accounts_for_every_switch(real_runs, capsys) -> None:
    root, ref, tuned = real_runs
    out = root / "cmp"
    args = ["compare", str(root / "reference"), str(root / "kitti"), "--out", str(out), "--record"]
    assert main(args) == 0
    result = json.loads((out / "compare.json").read_text())
    total = result["counts"]["total"]
    for kind in ("IDSW", "Frag"):
        c = total.get(f"pedestrian {kind}", {"fixed": 0, "introduced": 0, "kept": 0})
        # every event of A is fixed or kept, every event of B introduced or kept
        assert c["fixed"] + c["kept"] == ref["metrics"]["pedestrian"][kind]
        assert c["introduced"] + c["kept"] == tuned["metrics"]["pedestrian"][kind]
    assert ref["metrics"]["pedestrian"]["IDSW"] != tuned["metrics"]["pedestrian"]["IDSW"]
    hota = result["metrics"]["pedestrian"]["HOTA"]
    assert hota["delta"] == pytest.approx(
        tuned["metrics"]["pedestrian"]["HOTA"] - ref["metrics"]["pedestrian"]["HOTA"], abs=1e-3
    )
    assert result["per_sequence"]["0016"]["pedestrian"]["HOTA"]["a"] == pytest.approx(
        ref["metrics"]["pedestrian"]["HOTA"]
    )
    # B was recorded: its events carry causes and their #K in the recording; A's do not
    b_events = [p["b"] for p in result["events"] if p["b"] is not None]
    assert b_events and all(e["cause"] and e["event"] is not None for e in b_events)
    assert all(p["a"]["cause"] is None for p in result["events"] if p["a"] is not None)
    # the side-by-side recording: both runs' tracks and the fixed / introduced events
    from tests.test_viz import entity_table

    rrd = Path(result["recordings"]["0016"])
    assert rrd.is_file()
    for entity in ("/world/a/tracks", "/world/b/tracks", "/world/gt"):
        assert entity_table(rrd, entity).num_rows > 100
    log = entity_table(rrd, "/events")
    n_listed = sum(p["status"] != "kept" for p in result["events"])
    assert log.num_rows == n_listed > 0


def test_events_read_from_the_recording_equal_the_trackeval_replay(real_runs) -> None:
    """A recorded run's events come from its recording (fast); they are TrackEval's."""
    from app import runs
    from tracker.eval.id_switches import result_file_id_events

    root, _, tuned = real_runs
    folder = root / "kitti"
    run = runs.load_run(folder)
    assert run.recordings  # the fast path was available
    label = Path(tuned["labels"]) / "0016.txt"
    replay = result_file_id_events(folder / "data" / "0016.txt", label, classes=["pedestrian"])
    index = runs._recording_index(run.recordings["0016"])
    slow = runs._with_causes("0016", replay.events, index)

    def key(e):
        return tuple(
            e[k]
            for k in ("frame", "class", "gt_id", "kind", "old_track", "new_track", "cause", "event")
        )

    assert sorted(map(key, run.events)) == sorted(map(key, slow))
    assert len(slow) == sum(tuned["metrics"]["pedestrian"][k] for k in ("IDSW", "Frag"))


def test_compare_tracks_files_against_the_same_ground_truth(tmp_path: Path) -> None:
    """Two tracks.json with --gt: the ground truth itself (no switch) and a copy in which one
    object changes id at frame 100 (one switch, introduced), by the BEV-IoU CLEAR replay."""
    from dataclasses import replace

    import numpy as np

    from tracker.io.baseversion import read_baseversion, write_baseversion

    gt_file = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001" / "gt.json.gz"
    gt = read_baseversion(gt_file, fallback_frame_rate_hz=10.0)
    frames = gt["0001"]
    target = int(frames[100].boxes.track_id[0])
    changed = []
    for f in frames:
        ids = f.boxes.track_id.copy()
        if f.frame_id >= 100:
            ids[ids == target] = 10_000
        changed.append(replace(f, boxes=f.boxes.replace(track_id=ids)))
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    write_baseversion(tmp_path / "a" / "tracks.json", gt)
    write_baseversion(tmp_path / "b" / "tracks.json", {"0001": changed})
    out = tmp_path / "cmp"
    args = ["compare", str(tmp_path / "a" / "tracks.json"), str(tmp_path / "b" / "tracks.json")]
    assert main([*args, "--gt", str(gt_file), "--out", str(out)]) == 0
    result = json.loads((out / "compare.json").read_text())
    assert [p["status"] for p in result["events"]] == ["introduced"]
    e = result["events"][0]["b"]
    assert (e["frame"], e["gt_id"], e["new_track"], e["kind"]) == (100, target, 10_000, "IDSW")
    assert np.isclose(result["metrics"][e["class"]]["IDSW"]["delta"], 1)
    # without --gt: one line saying what is missing
    assert main([*args, "--out", str(out)]) == 2


def test_compare_tracks_files_of_part_of_the_ground_truths_frames(tmp_path: Path) -> None:
    """Tracks files that cover the ground truth's first 20 frames only (`track --frames 0:20`):
    the replay's frames without output took `gt[:0]`, which Boxes refused (IndexError, "an
    unexpected error")."""
    from tracker.io.baseversion import read_baseversion, write_baseversion

    gt_file = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001" / "gt.json.gz"
    gt = read_baseversion(gt_file, fallback_frame_rate_hz=10.0)
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        write_baseversion(tmp_path / name / "tracks.json", {"0001": gt["0001"][:20]})
    args = ["compare", str(tmp_path / "a" / "tracks.json"), str(tmp_path / "b" / "tracks.json")]
    assert main([*args, "--gt", str(gt_file), "--out", str(tmp_path / "cmp")]) == 0
    result = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert result["events"] == []


def test_compare_refuses_an_option_of_the_other_kind_of_run(tmp_path: Path, capsys) -> None:
    """--labels with tracks files (compared by the BEV-IoU replay against --gt) and --gt with
    run folders (scored against their labels) changed nothing, and compare.md's "Made by"
    line listed them: a usage error, one line, saying what the option is for."""
    a, b, labels = make_runs(tmp_path)
    sample = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"
    gt = sample / "gt.json.gz"
    out = tmp_path / "cmp"
    tracks = []
    for name in ("ta", "tb"):  # (the ground truth as both runs' tracks: no event)
        (tmp_path / name).mkdir()
        tracks.append(str(shutil.copy(gt, tmp_path / name / "tracks.json.gz")))
    args = ["compare", *tracks, "--gt", str(gt), "--out", str(out)]
    assert main([*args, "--labels", str(labels)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"mctrack compare: error: --labels {labels}: only with run folders (`mctrack kitti "
        "--out`: the KITTI labels their result files are scored against); tracks files are "
        "compared against --gt, by the CLEAR replay with BEV IoU"
    )
    assert not out.exists()
    assert main(args) == 0  # (without it: compared)
    args = ["compare", str(a), str(b), "--out", str(tmp_path / "runs")]
    assert main([*args, "--gt", str(gt)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mctrack compare: error: --gt {gt}: only with tracks files")
    assert len(err.splitlines()) == 1 and not (tmp_path / "runs").exists()
    assert main([*args, "--labels", str(labels)]) == 0
