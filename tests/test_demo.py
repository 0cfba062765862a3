"""`mctrack demo`: the README's first command, and the CI artifacts it leaves."""

from __future__ import annotations

from pathlib import Path

import pytest

from app.cli import main
from viz import paths

ROOT = Path(__file__).resolve().parents[1]
ARTIFACT = ROOT / "artifacts" / "demo.rrd"


def _entity_paths(rrd: Path) -> set[str]:
    from rerun.chunk import RrdReader

    return {c.entity_path for c in RrdReader(str(rrd)).stream().to_chunks()}


def test_demo_writes_a_recording_and_says_how_to_open_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    if not (ROOT / "sample_data" / "kitti-0001" / "detections.json.gz").is_file():
        pytest.skip("sample data missing")
    assert main(["demo", "--out", str(tmp_path), "--frames", "0:40"]) == 0
    out = capsys.readouterr().out
    rrd = tmp_path / "demo.rrd"
    assert rrd.is_file()
    assert f"rerun {rrd}" in out
    assert "tracks:" in out and "ID switches (car):" in out and "HOTA" in out and "MOTA" in out
    found = _entity_paths(rrd)
    for path in (paths.TRACKS_UPDATED, paths.GT, paths.SUMMARY, paths.EVENTS_LIFECYCLE):
        assert paths.entity(path) in found


def test_ci_artifact_recording() -> None:
    if not ARTIFACT.is_file():
        pytest.skip(f"{ARTIFACT} not built (.ci/run makes it with `mctrack demo --out artifacts`)")
    from rerun.chunk import RrdReader

    assert len(RrdReader(str(ARTIFACT)).blueprints()) >= 1
    found = _entity_paths(ARTIFACT)
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
