"""A KITTI kit whose detector keeps only its detections at or above a raw score: the detection
sets "distributed above a score cut" of docs/results.md (VirConv and SECOND-IoU cut at raw >= 0).

    python bench/cut_detections.py --detector virconv --out CUT_KIT [--kitti-root ROOT]
        [--min-raw 0] [--seqs 0001,0006,...]
    mctrack kitti --kitti-root CUT_KIT --detector virconv_cut --classes car --profile self \\
        --out DIR

``CUT_KIT/training`` links to the kit's own; ``CUT_KIT/detections/<detector>_cut/training/``
holds, per sequence, the lines of ``<seq>.txt`` (one file per sequence, the KITTI tracking
result format, raw score last) whose score is >= ``--min-raw``. bench/make_results.py makes
its table's kit with :func:`cut_kit`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.inputs import default_kitti_root  # noqa: E402

CUT_RAW = 0.0  # the cut of docs/results.md: raw >= 0 (sigmoid 0.5)


def cut_kit(
    root: Path,
    detector: str,
    out: Path,
    *,
    min_raw: float = CUT_RAW,
    seqs: Sequence[str] | None = None,
) -> str:
    """Write ``out`` as a kit (``training`` linked to ``root``'s) with ``<detector>_cut``: the
    detector's lines of each sequence (``seqs``, default every ``<seq>.txt`` it has) with raw
    score >= ``min_raw``. Returns the cut detector's name. Several detectors may share ``out``."""
    source = root / "detections" / detector / "training"
    names = list(seqs) if seqs is not None else sorted(p.stem for p in source.glob("*.txt"))
    if not names:
        raise SystemExit(
            f"{source}: no <seq>.txt files (the cut reads one file per sequence, score last)"
        )
    training = out / "training"
    if not training.exists():
        out.mkdir(parents=True, exist_ok=True)
        training.symlink_to((root / "training").resolve())
    cut = f"{detector}_cut"
    folder = out / "detections" / cut / "training"
    folder.mkdir(parents=True, exist_ok=True)
    for seq in names:
        lines = (source / f"{seq}.txt").read_text().splitlines()
        kept = [ln for ln in lines if ln.strip() and float(ln.split()[-1]) >= min_raw]
        (folder / f"{seq}.txt").write_text("".join(f"{ln}\n" for ln in kept))
    return cut


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kitti-root", type=Path, default=None, help="default: mctrack's kit")
    parser.add_argument("--detector", required=True, help="a detector of the kit (virconv, ...)")
    parser.add_argument("--min-raw", type=float, default=CUT_RAW, help="keep raw >= this")
    parser.add_argument("--seqs", default=None, help="comma-separated (default: all it has)")
    parser.add_argument("--out", type=Path, required=True, help="the new kit's folder")
    args = parser.parse_args()
    root = args.kitti_root or default_kitti_root()
    seqs = [s.strip().zfill(4) for s in args.seqs.split(",")] if args.seqs else None
    cut = cut_kit(root, args.detector, args.out, min_raw=args.min_raw, seqs=seqs)
    print(f"wrote {args.out / 'detections' / cut}: mctrack kitti --kitti-root {args.out} "
          f"--detector {cut} ...")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
