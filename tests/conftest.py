"""Shared fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

#: The real KITTI tracking kit, next to the project checkout (see /work/shared/data/README.md).
DEFAULT_KITTI_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti" / "tracking"


@pytest.fixture(scope="session")
def kitti_root() -> Path:
    """The KITTI tracking kit: ``$MCTRACK_KITTI_ROOT`` or ``../shared/data/kitti/tracking``."""
    env = os.environ.get("MCTRACK_KITTI_ROOT")
    root = (Path(env) if env else DEFAULT_KITTI_ROOT).resolve()
    if not (root / "training" / "calib").is_dir():
        source = "MCTRACK_KITTI_ROOT" if env else "the default location"
        pytest.skip(f"KITTI tracking kit not found at {root} ({source}); set MCTRACK_KITTI_ROOT")
    return root


@pytest.fixture(scope="session")
def real_runs(kitti_root: Path):
    """Two real runs of validation sequence 0016 (pedestrian): ``root/reference`` with
    kitti_reference, ``root/kitti`` with the tuned config, recorded and with motion metrics
    (tests/test_compare.py, tests/test_report.py). Yields (root, summary A, summary B)."""
    import shutil
    import tempfile

    from app.kitti import run_kitti

    root = Path(tempfile.mkdtemp(prefix="mctrack-test-compare-"))
    common = dict(kitti_root=kitti_root, seqs=["0016"], classes=["pedestrian"], quiet=True)
    ref = run_kitti(config_name="kitti_reference", out=root / "reference", **common)
    tuned = run_kitti(
        config_name="kitti",
        out=root / "kitti",
        record=root / "kitti" / "recordings",
        motion=True,
        **common,
    )
    yield root, ref, tuned
    shutil.rmtree(root, ignore_errors=True)
