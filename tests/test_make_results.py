"""bench/make_results.py's text that is not a measurement: the quoted summary.json."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from make_results import QUOTE_LEFT_OUT, summary_quote

SAMPLE_KIT = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001" / "raw"


def test_the_summary_quote_leaves_out_what_it_says_and_no_machine_path() -> None:
    summary = {
        "command": "kitti",
        "kitti_root": "/home/me/work/../shared/kit",
        "labels": "/home/me/work/../shared/kit/training/label_02",
        "skipped_at_load": {},
        "evaluated_sequences": ["0001"],
        **{k: {"long": 1} for k in QUOTE_LEFT_OUT},
    }
    lines = summary_quote(summary, cwd=Path("/home/me/work"))
    text = "\n".join(lines)
    quoted = json.loads(text.split("```json\n")[1].split("\n```")[0])
    assert quoted == {
        "command": "kitti",
        "kitti_root": "../shared/kit",
        "labels": "../shared/kit/training/label_02",
        "skipped_at_load": {},
        "evaluated_sequences": ["0001"],
    }
    prose = " ".join(lines[0].split())
    assert all(f"`{k}`" in prose for k in QUOTE_LEFT_OUT) and "relative to the folder" in prose


def test_the_summary_quote_of_a_run_without_labels_says_what_is_absent() -> None:
    """A run without labels (--no-eval, or none found) has no metrics nor
    per_sequence_metrics, and a summary may lack the paths: the prose said they were left out
    or made relative all the same (a None "labels" was an AttributeError). Now it names only
    what is there, and says the metrics are absent, with the run's own note when it has one."""
    summary = {
        "command": "kitti",
        "kitti_root": "/home/me/work/kit",
        "labels": None,
        "config": {"long": 1},
        "tracker_fps": 100.0,
    }
    lines = summary_quote(summary, cwd=Path("/home/me/work"))
    quoted = json.loads("\n".join(lines).split("```json\n")[1].split("\n```")[0])
    assert quoted == {"command": "kitti", "kitti_root": "kit", "labels": None, "tracker_fps": 100.0}
    assert lines[0] == (
        "The `summary.json` that `mctrack kitti --out DIR` wrote for the online run (its `config`"
        " entry, the resolved `kitti` config, left out here; `kitti_root`, absolute in the file,"
        " is shown relative to the folder the command ran in; `tracker_fps` is one run on this"
        " machine, the speed section below is the best of several; the run has no `metrics`:"
        " not scored, without labels or with --no-eval):"
    )
    skipped = {"command": "kitti", "evaluation": "skipped: no labels for ['0001'] in lab"}
    assert summary_quote(skipped)[0] == (
        "The `summary.json` that `mctrack kitti --out DIR` wrote for the online run (the run has"
        " no `metrics`: skipped: no labels for ['0001'] in lab):"
    )


def test_the_results_refuse_an_unscored_run_naming_it_and_what_is_absent(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every table reads the runs' metrics of each class: an unscored run (a kit without labels,
    --no-eval) crashed main() with KeyError 'metrics' after the first run. Now it is one line
    naming the run, its summary.json and what it lacks (with the run's own evaluation note),
    exit status 2, and no page is written. The summary is a real one: the sample kit's
    sequence 0001 run without its labels."""
    import make_results

    from app.kitti import run_kitti

    kit = tmp_path / "kit"
    shutil.copytree(SAMPLE_KIT, kit, ignore=shutil.ignore_patterns("label_02"))
    summary = run_kitti(kitti_root=kit, seqs=["0001"], classes=["car"], out=tmp_path / "run",
                        quiet=True)  # fmt: skip
    assert "metrics" not in summary and "no labels" in summary["evaluation"]
    calls: list[dict[str, object]] = []

    def unscored(**kw: object) -> dict[str, object]:
        calls.append(kw)
        return summary

    monkeypatch.setattr(make_results, "run_kitti", unscored)
    out = tmp_path / "results.md"
    monkeypatch.setattr(
        sys, "argv", ["make_results.py", "--kitti-root", str(kit), "--out", str(out)]
    )
    assert make_results.main() == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(
        f"make_results.py: error: `mctrack kitti` run of {kit} (classes car pedestrian cyclist): "
        f"its summary.json has no `metrics` ({summary['evaluation']}); the results tables need "
        "scored runs"
    )
    assert len(calls) == 1 and not out.exists()
    # a summary scored for some classes only names those it lacks
    with pytest.raises(make_results.InputError, match=r"has no `metrics` of cyclist \(not scored"):
        make_results.require_metrics(
            {"metrics": {"car": {}, "pedestrian": {}}}, ["car", "pedestrian", "cyclist"], "run"
        )
    make_results.require_metrics({"metrics": {"car": {"HOTA": 1.0}}}, ["car"], "run")
    # a scored run lacking a class of no ground truth says so, not "not scored"
    absent = "no ground-truth cyclist in these sequences; 3 tracked boxes, all false positives"
    scored = {"metrics": {"car": {}}, "metrics_absent": {"cyclist": absent}}
    with pytest.raises(make_results.InputError) as caught:
        make_results.require_metrics(scored, ["car", "cyclist"], "run")
    assert f"has no `metrics` of cyclist ({absent}); the results" in str(caught.value)
