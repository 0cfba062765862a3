"""Turn your own Waymo preprocessing files (ImmortalTracker / MCTrack, pickled object arrays)
into the pickle-free layout ``mctrack convert waymo`` reads.

    python bench/waymo_flatten_npz.py IN_FOLDER OUT_FOLDER

Every ``IN_FOLDER/*.npz`` (an ``ego_info``, detection or ground-truth folder) is written to
``OUT_FOLDER`` with the same name: ``ego_infos`` becomes ``ego2global`` / ``cam_extrinsics`` /
``cam_intrinsics``, the per-frame ``bboxes``/``types``/``ids``/``velos`` one row per box with a
``frame_index`` (``tracker.io.convert.waymo.flatten_per_frame``; layouts in
docs/nuscenes_waymo.md).

**Only run it on files you trust**: it loads them with ``allow_pickle=True``, which runs any code
a crafted file carries. That is why the converter itself never does, and refuses such files.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tracker.io.convert.waymo import flatten_per_frame
from tracker.io.fileio import write_bytes_atomic


def flatten_file(src: Path, dst: Path) -> None:
    """One trusted file → its pickle-free twin (written atomically)."""
    import io

    with np.load(src, allow_pickle=True) as npz:  # the user's own files: see the docstring
        arrays = {key: npz[key] for key in npz.files}
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **flatten_per_frame(arrays))
    write_bytes_atomic(dst, buffer.getvalue())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("src", type=Path, help="folder of pickled .npz files (trusted)")
    parser.add_argument("dst", type=Path, help="output folder (files keep their names)")
    args = parser.parse_args(argv)
    files = sorted(args.src.glob("*.npz"))
    if not files:
        print(f"waymo_flatten_npz: {args.src}: no .npz files", file=sys.stderr)
        return 2
    if args.dst.resolve() == args.src.resolve():
        print("waymo_flatten_npz: OUT_FOLDER must differ from IN_FOLDER", file=sys.stderr)
        return 2
    for src in files:
        flatten_file(src, args.dst / src.name)
    print(f"{len(files)} files written to {args.dst}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
