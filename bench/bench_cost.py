"""Time one ``ro_gdiou_bev`` call on random KITTI-like scenes (cars spread over 80 m × 80 m).

Run: ``python bench/bench_cost.py``. "all pairs" scores every track × detection pair; "gated"
passes the mask the tracker builds (same category and BEV centres closer than 10 m, the config's
``gate_distance_m``). Prints the best of several repeats, in milliseconds per call.
"""

from __future__ import annotations

import timeit

import numpy as np

from tracker.boxes import Boxes
from tracker.cost import ro_gdiou_bev

SIZES = (10, 50, 200)
GATE_M = 10.0


def scene(n: int, rng: np.random.Generator) -> tuple[Boxes, Boxes]:
    """n predicted tracks and the n detections they came from (moved by ~0.5 m, yaw by ~0.1)."""
    xy = rng.uniform(0.0, 80.0, (n, 2))
    lwh = np.column_stack([rng.uniform(3.5, 5.0, n), rng.uniform(1.6, 2.0, n), np.full(n, 1.5)])
    yaw = rng.uniform(-np.pi, np.pi, n)
    tracks = Boxes.create(
        xyz=np.column_stack([xy, np.zeros(n)]), lwh=lwh, yaw=yaw, category=np.zeros(n)
    )
    dets = Boxes.create(
        xyz=np.column_stack([xy + rng.normal(0.0, 0.5, (n, 2)), np.zeros(n)]),
        lwh=lwh * rng.uniform(0.95, 1.05, (n, 3)),
        yaw=yaw + rng.normal(0.0, 0.1, n),
        category=np.zeros(n),
    )
    return tracks, dets


def best_ms(tracks: Boxes, dets: Boxes, mask: np.ndarray | None, number: int) -> float:
    def call() -> None:
        ro_gdiou_bev(tracks, dets, w1=1.0, w2=1.0, mask=mask)

    return min(timeit.repeat(call, number=number, repeat=9)) / number * 1e3


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"{'M x N':>9} {'all pairs':>11} {'gated':>9} {'gated pairs':>12}")
    for n in SIZES:
        tracks, dets = scene(n, rng)
        centre_dist = np.linalg.norm(tracks.xyz[:, None, :2] - dets.xyz[None, :, :2], axis=-1)
        mask = (tracks.category[:, None] == dets.category[None, :]) & (centre_dist < GATE_M)
        number = max(1, 2000 // (n * n) * 5)
        t_all = best_ms(tracks, dets, None, number)
        t_gated = best_ms(tracks, dets, mask, number)
        print(f"{n:>4} x {n:<4}{t_all:>9.3f}ms {t_gated:>7.3f}ms {int(mask.sum()):>12}")


if __name__ == "__main__":
    main()
