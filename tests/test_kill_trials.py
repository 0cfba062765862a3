"""bench/kill_trials.py: where its trials run (the kills themselves are docs/reliability.md's
manual trial)."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import kill_trials


@pytest.fixture
def quick_trials(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """The trials with every run replaced by writing its --out folder's tracks.json; the
    folders the runs were given, in order."""
    given: list[Path] = []

    def run(args: list[str]) -> float:
        out = Path(args[args.index("--out") + 1])
        out.mkdir(parents=True, exist_ok=True)
        (out / "tracks.json").write_text("{}")
        given.append(out)
        return 0.01

    monkeypatch.setattr(kill_trials, "_timed_run", run)
    monkeypatch.setattr(kill_trials, "_kill_after", lambda args, secs: run(args) > 1)
    state = {"files": 2, "temps": 0, "summary.json": "lists sizes on disk"}
    monkeypatch.setattr(kill_trials, "_inspect", lambda out: state)
    return given


def test_kill_trials_leave_nothing_behind_without_out(
    quick_trials: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Without --out the trials run in a work folder of their own, removed at the end (they
    ran in a fixed /tmp/mctrack-kill, left behind and shared by two runs at once)."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    assert kill_trials.main(["--trials", "1"]) == 0
    roots = {p.parent for p in quick_trials}
    assert len(roots) == 1 and next(iter(roots)).name.startswith("mctrack-kill-")
    assert next(iter(roots)).parent == tmp_path
    assert list(tmp_path.iterdir()) == []


def test_kill_trials_keep_what_out_held(quick_trials: list[Path], tmp_path: Path) -> None:
    """--out DIR: each run's trials in a new folder under DIR, kept; DIR's own files stay (it
    was removed whole first), and a second run does not take over the first's folder."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    for _ in range(2):
        assert kill_trials.main(["--trials", "1", "--out", str(out)]) == 0
    first, second = quick_trials[0].parent, quick_trials[-1].parent
    assert first != second and first.parent == second.parent == out
    assert (out / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in out.iterdir()) == sorted(["notes.txt", first.name, second.name])
    assert (first / "track-0" / "tracks.json").is_file()
