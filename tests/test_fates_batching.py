"""The detection fates counted in batches of frames equal the counts frame by frame."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from tracker.config import load_config
from tracker.eval.fates import FateCounter
from tracker.io.baseversion import read_baseversion
from tracker.pipeline import run_scene

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "kitti-0001"


@pytest.mark.parametrize("config_name", ["kitti", "kitti_reference"])
def test_batch_size_does_not_change_the_counts(config_name: str, monkeypatch) -> None:
    if not SAMPLE.is_dir():
        pytest.skip("sample_data/kitti-0001 missing")
    frames = read_baseversion(SAMPLE / "detections.json.gz")["0001"][:120]
    # two scenes: the unconfirmed-track count is per scene (ids restart)
    other = [dataclasses.replace(f, scene="copy") for f in frames[:60]]
    config = load_config(config_name)
    summaries = []
    for batch in (1, 7, 10_000):
        monkeypatch.setattr(FateCounter, "BATCH_FRAMES", batch)
        counter = FateCounter(rv_gate_consumes=config.rv_reference)
        run_scene(frames, config, observer=counter)
        run_scene(other, config, observer=counter)
        summaries.append(counter.summary())
    assert summaries[0] == summaries[1] == summaries[2]
    s = summaries[0]
    assert s["detections"] == sum(len(f.boxes) for f in frames + other)
    assert sum(s["per_fate"].values()) == s["detections"]
    assert s["per_fate"]["matched_bev"] > 0 and s["per_fate"]["born"] > 0
    if config_name == "kitti_reference":
        assert s["per_fate"]["unused_rv_gate"] > 0
