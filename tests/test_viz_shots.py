"""Headless screenshots: a real PNG of a real view, not a blank one (needs Mesa lavapipe)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.test_viz import recording
from viz.layout import VIEW_BEV
from viz.shots import (
    PlannedShot,
    image_variance,
    plan_shots,
    read_shot_index,
    renderer_available,
    take_shots,
)

ARTIFACT_SHOTS = Path(__file__).resolve().parents[1] / "artifacts" / "shots"
#: A blank (single-colour) view has variance 0; the dark viewer background with a grid and a few
#: boxes is in the hundreds.
MIN_VARIANCE = 20.0


def test_shot_plan_comes_from_the_recording() -> None:
    path, result = recording()
    index = read_shot_index(path)
    switches = [e.frame_id for e in result.id_evaluation.id_switches]
    assert index.id_switch_frames == switches
    assert result.lag is not None and index.lag_frame == result.lag.frame_id
    plan = plan_shots(index, max_events=2)
    first = [k for k, kind in enumerate(index.event_kinds) if kind == 0][:2]
    focused = [PlannedShot(index.event_shot_frames[k], "id_switch", k) for k in first]
    assert plan == [*focused, PlannedShot(result.lag.frame_id, "lag")]


def test_screenshot_is_not_blank(tmp_path: Path) -> None:
    ok, why = renderer_available()
    if not ok:
        pytest.skip(f"no software renderer: {why}")
    path, result = recording()
    frame = result.id_evaluation.id_switches[0].frame_id
    shots = take_shots(
        path, tmp_path, plan=[(frame, "id_switch")], views=(VIEW_BEV,), full_viewer=False
    )
    assert [s.view for s in shots] == [VIEW_BEV]
    png = shots[0].path
    assert png.stat().st_size > 10_000
    assert image_variance(png) > MIN_VARIANCE


def test_ci_artifact_shots_are_not_blank() -> None:
    pngs = sorted(ARTIFACT_SHOTS.glob("*.png"))
    if not pngs:
        pytest.skip(f"no screenshots in {ARTIFACT_SHOTS} (made by .ci/run when lavapipe is there)")
    for png in pngs:
        assert png.stat().st_size > 5_000, png
        assert image_variance(png) > MIN_VARIANCE, png


def test_headless_viewer_logs_warnings_only_unless_told(monkeypatch: pytest.MonkeyPatch) -> None:
    """mctrack shots printed a dozen of the viewer's INFO lines (its gRPC address, "Connect by
    running rerun --connect ...", each temporary layout file it loaded) under its own output.
    The spawned viewer now gets RUST_LOG=warn, unless the user set RUST_LOG."""
    import contextlib
    import os

    from viz import shots
    from viz.shots import headless_viewer

    seen: list[str | None] = []

    def spawn(**kwargs: object) -> contextlib.AbstractContextManager[None]:
        seen.append(os.environ.get("RUST_LOG"))
        return contextlib.nullcontext()

    monkeypatch.setattr(shots, "running_viewer_client", spawn)
    monkeypatch.delenv("RUST_LOG", raising=False)
    with headless_viewer():
        pass
    assert seen == ["warn"] and "RUST_LOG" not in os.environ
    monkeypatch.setenv("RUST_LOG", "debug")
    with headless_viewer():
        pass
    assert seen == ["warn", "debug"] and os.environ["RUST_LOG"] == "debug"
