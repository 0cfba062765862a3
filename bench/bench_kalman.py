"""Micro-benchmark: µs per batched predict + update of the pose, size and heading filters.

Run ``python bench/bench_kalman.py``. For B = 10, 20, 50, 200 tracks it times one frame of
filtering for every track (predict, align the detector yaw, θ_vel, update) with nuScenes car
noise, detector velocity and some rows without velocity:

- ``fast``: the tracker's path, :func:`tracker.kalman.motion_predict` + ``motion_update`` (CV);
- ``fast CA``: the same with the paper's constant-acceleration pose model;
- ``3 filters``: the reference layout, ``pose_*`` + ``size_*`` + ``heading_*`` (generic matmul).
- ``tracker``, ``tracker CA``: what the tracker runs on KITTI: one ``dt`` for the whole frame,
  positions and sizes without velocity, then the heading with θ_vel (``motion_update`` twice).
"""

from __future__ import annotations

import timeit
from collections.abc import Callable

import numpy as np

from tracker import kalman as kf

DT_NOMINAL_SECS = 0.5
MIN_SPEED_MPS = 1.0
#: nuScenes car noise (mctrack_reference.md §3.2); CA uses the config's (unused) CA pose noise.
POSE_CV = kf.DiagonalNoise(
    p0_diag=[1, 1, 10, 10], q_diag=[0.5, 0.5, 1.5, 1.5], r_diag=[0.7, 0.7, 0.5, 0.5]
)
POSE_CA = kf.DiagonalNoise(
    p0_diag=[1] * 6, q_diag=[2, 2, 1, 0.5, 1, 1.5], r_diag=[0.5, 0.5, 0.5, 0.5]
)
SIZE = kf.DiagonalNoise(p0_diag=[1, 1, 10, 10], q_diag=[0.5, 0.5, 1.5, 1.5], r_diag=[2, 2])
HEADING = kf.DiagonalNoise(p0_diag=[0.1, 0.1], q_diag=[0.1, 0.1], r_diag=[0.2, 5.0])


def _detections(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    velocity_xy = rng.normal(size=(n, 2)) * 3.0
    velocity_xy[::7] = np.nan  # some detections without velocity (masked exactly)
    return {
        "dt_secs": np.full(n, DT_NOMINAL_SECS),
        "xy": rng.normal(size=(n, 2)),
        "velocity_xy": velocity_xy,
        "lw": rng.uniform(1.0, 5.0, size=(n, 2)),
        "yaw_rad": rng.uniform(-3.0, 3.0, size=n),
    }


def _fast_frame(model: kf.MotionModel, n: int, rng: np.random.Generator) -> Callable[[], None]:
    pose = POSE_CV if model is kf.MotionModel.CV else POSE_CA
    noise = kf.motion_noise(pose=pose, size=SIZE, heading=HEADING, model=model)
    det = _detections(rng, n)
    x0, p0 = kf.motion_init(
        xy=det["xy"], lw=det["lw"], yaw_rad=det["yaw_rad"], p0_diag=noise.p0_diag
    )

    def frame() -> None:
        x, P = kf.motion_predict(
            x0, p0, dt_secs=det["dt_secs"], q_diag=noise.q_diag, dt_nominal_secs=DT_NOMINAL_SECS
        )
        yaw_vel, moving = kf.velocity_heading(det["velocity_xy"], min_speed_mps=MIN_SPEED_MPS)
        kf.motion_update(
            x,
            P,
            xy=det["xy"],
            lw=det["lw"],
            yaw_det_rad=det["yaw_rad"],
            r_diag=noise.r_diag,
            velocity_xy=det["velocity_xy"],
            yaw_vel_rad=yaw_vel,
            yaw_vel_valid=moving,
            align_yaw_det=True,
        )

    return frame


def _three_filters_frame(n: int, rng: np.random.Generator) -> Callable[[], None]:
    det = _detections(rng, n)
    pose0 = kf.pose_init(det["xy"], p0_diag=POSE_CV.p0_diag)
    size0 = kf.size_init(det["lw"], p0_diag=SIZE.p0_diag)
    heading0 = kf.heading_init(det["yaw_rad"], p0_diag=HEADING.p0_diag)
    common = {"dt_secs": det["dt_secs"], "dt_nominal_secs": DT_NOMINAL_SECS}

    def frame() -> None:
        px, pP = kf.pose_predict(*pose0, q_diag=POSE_CV.q_diag, **common)
        kf.pose_update(px, pP, xy=det["xy"], velocity_xy=det["velocity_xy"], r_diag=POSE_CV.r_diag)
        sx, sP = kf.size_predict(*size0, q_diag=SIZE.q_diag, **common)
        kf.size_update(sx, sP, lw=det["lw"], r_diag=SIZE.r_diag)
        hx, hP = kf.heading_predict(*heading0, q_diag=HEADING.q_diag, **common)
        yaw_vel, moving = kf.velocity_heading(det["velocity_xy"], min_speed_mps=MIN_SPEED_MPS)
        kf.heading_update(
            hx,
            hP,
            yaw_det_rad=kf.align_heading(det["yaw_rad"], hx[:, 0]),
            yaw_vel_rad=yaw_vel,
            yaw_vel_valid=moving,
            r_diag=HEADING.r_diag,
        )

    return frame


def _tracker_frame(model: kf.MotionModel, n: int, rng: np.random.Generator) -> Callable[[], None]:
    pose = kf.DiagonalNoise(
        p0_diag=[1.0] * (2 * model.order), q_diag=[0.5] * (2 * model.order), r_diag=[0.1, 0.1]
    )
    noise = kf.motion_noise(pose=pose, size=SIZE, heading=HEADING, model=model)
    det = _detections(rng, n)
    x0, p0 = kf.motion_init(
        xy=det["xy"], lw=det["lw"], yaw_rad=det["yaw_rad"], p0_diag=noise.p0_diag
    )
    q = np.broadcast_to(noise.q_diag, x0.shape)
    moving = rng.uniform(size=n) < 0.5

    def frame() -> None:
        x, P = kf.motion_predict(x0, p0, dt_secs=0.1, q_diag=q, dt_nominal_secs=0.1)
        x, P = kf.motion_update(x, P, xy=det["xy"], lw=det["lw"], r_diag=noise.r_diag)
        kf.motion_update(
            x,
            P,
            yaw_det_rad=det["yaw_rad"],
            yaw_vel_rad=det["yaw_rad"],
            yaw_vel_valid=moving,
            r_diag=noise.r_diag,
        )

    return frame


def _micros(fn: Callable[[], None], number: int = 50, repeat: int = 200) -> float:
    """Best-of-``repeat`` mean time of one call, µs: many short windows, as the minimum is the
    least noisy estimate on a shared machine."""
    return min(timeit.repeat(fn, number=number, repeat=repeat)) / number * 1e6


def main() -> None:
    rng = np.random.default_rng(0)
    print("µs per frame (predict + update of pose, size and heading for all B tracks)")
    header = ("B", "fast", "fast CA", "3 filters", "tracker", "tracker CA")
    print(" ".join(f"{h:>10}" for h in header))
    for n in (10, 20, 50, 200):
        fast = _micros(_fast_frame(kf.MotionModel.CV, n, rng))
        fast_ca = _micros(_fast_frame(kf.MotionModel.CA, n, rng))
        three = _micros(_three_filters_frame(n, rng))
        tracker = _micros(_tracker_frame(kf.MotionModel.CV, n, rng))
        tracker_ca = _micros(_tracker_frame(kf.MotionModel.CA, n, rng))
        print(
            f"{n:>10}"
            + "".join(f" {v:>10.1f}" for v in (fast, fast_ca, three, tracker, tracker_ca))
        )


if __name__ == "__main__":
    main()
