"""The noise floor of the robustness benchmark: what its jitter costs perfectly associated
ground-truth boxes, raw, through an online filter and through an offline smoother
(:mod:`tracker.eval.noise_floor`). Labels only, no detector.

    python bench/noise_floor.py [--kitti-root ROOT] [--classes car,pedestrian,cyclist]
        [--seed 0] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.inputs import default_kitti_root  # noqa: E402
from tracker.eval.noise_floor import markdown, noise_floor  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kitti-root", type=Path, default=None)
    parser.add_argument("--classes", default="car,pedestrian,cyclist")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = parser.parse_args()
    root = args.kitti_root or default_kitti_root()
    rows = noise_floor(root, [c.strip() for c in args.classes.split(",")], seed=args.seed)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    print("\n".join(markdown(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
