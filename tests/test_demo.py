"""`mctrack demo`: the README's first command, run here (no prebuilt artifact needed)."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from app.cli import main
from viz import paths

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "kitti-0001" / "detections.json.gz"


def _entity_paths(rrd: Path) -> set[str]:
    from rerun.chunk import RrdReader

    return {c.entity_path for c in RrdReader(str(rrd)).stream().to_chunks()}


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """`mctrack demo` itself on the first 40 frames (the camera images are at frames 10-20):
    the recording and what it printed."""
    if not SAMPLE.is_file():
        pytest.fail(f"{SAMPLE} missing: the sample data is part of the repository")
    out = tmp_path_factory.mktemp("demo")
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(["demo", "--out", str(out), "--frames", "0:40"]) == 0
    return out / "demo.rrd", printed.getvalue()


def test_demo_writes_a_recording_and_says_how_to_open_it(demo_run: tuple[Path, str]) -> None:
    rrd, out = demo_run
    assert rrd.is_file()
    assert f"rerun {rrd}" in out
    assert "tracks:" in out and "ID switches (car):" in out and "HOTA" in out and "MOTA" in out


def test_demo_recording_holds_every_debug_view(demo_run: tuple[Path, str]) -> None:
    rrd, _ = demo_run
    from rerun.chunk import RrdReader

    assert len(RrdReader(str(rrd)).blueprints()) >= 1
    found = _entity_paths(rrd)
    expected = [
        paths.DETECTIONS_RAW,
        paths.DETECTIONS_KEPT,
        paths.TRACKS_PREDICTED,
        paths.TRACKS_UPDATED,
        paths.TRACKS_VELOCITY,
        paths.TRAILS,
        paths.EGO,
        paths.GT,
        paths.MATCHES_BEV,
        paths.COST_BEV,
        paths.COST_RV,
        paths.camera_image("CAM_FRONT"),
        paths.camera_detections("CAM_FRONT"),
        paths.camera_tracks("CAM_FRONT"),
        paths.EVENTS_LIFECYCLE,
        paths.SUMMARY,
        paths.SHOT_INDEX,
    ]
    missing = [p for p in expected if paths.entity(p) not in found]
    assert not missing, missing
    assert any(p.startswith("/tracks/") and p.endswith("/gt_speed") for p in found)


def test_demo_on_frames_without_labels_says_so(tmp_path: Path) -> None:
    """Frames 440-446 of 0001 hold no labelled box (a range past the end is cut there): the
    recording is written and the car row says why there is no score, not HOTA 0."""
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(["demo", "--out", str(tmp_path), "--frames", "440:2000"]) == 0
    assert (tmp_path / "demo.rrd").is_file()
    assert "7 frames" in printed.getvalue()
    assert "no labelled car in these frames, not scored" in printed.getvalue()


def test_demo_frames_beyond_the_sample_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["demo", "--out", str(tmp_path), "--frames", "500:600"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["mctrack demo: error: --frames 500:600: the sample has frames 0:447"]
