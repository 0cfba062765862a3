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
