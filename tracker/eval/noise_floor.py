"""What the robustness benchmark's jitter costs perfect boxes (labels only, no detector).

Command: ``python bench/noise_floor.py``; its table is in docs/results.md.

The benchmark jitters each detection's BEV centre and heading and moves its 2D box with its 3D
box (``tracker/eval/perturb.py``); the KITTI protocol scores 2D boxes. Here the "detections" are
the ground-truth boxes themselves with their own ids (perfect detection and association), written
through the tracker's KITTI writer with the shipped ``kitti`` config's 2D box widths, and scored:

- ``clean``: the ground truth as written (its HOTA is below 100: a written box is a projected
  cuboid, the annotation a hand-drawn 2D box);
- ``jittered``: the same boxes after the jitter of a level (its drops and false positives left
  out): what a tracker that reports each box as detected would score;
- ``online filter``: each ground-truth track's jittered centres through a causal
  constant-velocity Kalman filter that knows the jitter's variance (r = σ²), best of a few
  process noises q per row (an optimistic bound: chosen on these labels);
- ``offline smoother``: the same filter's Rauch-Tung-Striebel smoother (uses the future).

The Δ of the online filter from ``clean`` is what a perfect online tracker, with an ideal
constant-velocity filter, loses to the jitter alone; drops and false positives add to it. It is
not a floor for a tracker on real detections: their boxes are noisy already and independent
errors add in variance, so the same jitter costs such a tracker less (PointRCNN's cars lose less
than half of what perfect boxes lose: docs/results.md). It gives the scale of what the jitter does
to the written 2D boxes and how much of it filtering can take back.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tracker.categories import category_index
from tracker.config import load_config
from tracker.eval.kitti import evaluate_kitti
from tracker.eval.perturb import NOISE_LEVELS, PerturbSpec, perturb_frames
from tracker.events import TrackOutput
from tracker.frame import Frame
from tracker.io.convert.kitti import VALIDATION_SEQS, convert_kitti
from tracker.io.fileio import work_folder
from tracker.io.writers import write_kitti_sequence

DT = 0.1  # s, KITTI's frame period
Q_CHOICES = (0.01, 0.1, 1.0)  # m²/s³, white-acceleration spectral density
KEPT = ("HOTA", "DetA", "AssA", "LocA")


def jitter_only(level: str) -> PerturbSpec:
    """The centre and heading jitter of a benchmark level, without its drops and false
    positives."""
    spec = NOISE_LEVELS[level]
    return PerturbSpec(centre_sigma_m=spec.centre_sigma_m, yaw_sigma_deg=spec.yaw_sigma_deg)


def cv_filter(z: np.ndarray, q: float, r: float, *, smooth: bool) -> np.ndarray:
    """Constant-velocity Kalman filter (or, with ``smooth``, its RTS smoother) of each row of
    ``z`` (S, T) positions at ``DT`` spacing; NaN = no measurement (predict only). Rows are
    independent series (one axis of one track each) and run as one batch. Returns (S, T)
    filtered positions (NaN before a row's first measurement)."""
    S, T = z.shape
    F = np.array([[1.0, DT], [0.0, 1.0]])
    Q = q * np.array([[DT**3 / 3, DT**2 / 2], [DT**2 / 2, DT]])
    x = np.zeros((S, 2))
    P = np.zeros((S, 2, 2))
    started = np.zeros(S, dtype=bool)
    xf, Pf = np.full((T, S, 2), np.nan), np.zeros((T, S, 2, 2))
    xp, Pp = np.full((T, S, 2), np.nan), np.zeros((T, S, 2, 2))
    for t in range(T):
        x = x @ F.T
        P = F @ P @ F.T + Q
        xp[t], Pp[t] = x, P
        seen = ~np.isnan(z[:, t])
        new = seen & ~started
        x[new] = np.column_stack([z[new, t], np.zeros(new.sum())])
        P[new] = np.diag([r, 4.0])  # velocity unknown: ± 2 m/s
        upd = seen & started
        innovation = z[upd, t] - x[upd, 0]
        gain = P[upd, :, 0] / (P[upd, 0, 0] + r)[:, None]
        x[upd] += gain * innovation[:, None]
        P[upd] -= gain[:, :, None] * P[upd, 0][:, None, :]
        started |= seen
        x[~started], P[~started] = 0.0, 0.0
        xf[t], Pf[t] = np.where(started[:, None], x, np.nan), P
    if smooth:
        xs = xf.copy()
        for t in range(T - 2, -1, -1):
            both = started & ~np.isnan(xf[t, :, 0]) & ~np.isnan(xp[t + 1, :, 0])
            C = Pf[t][both] @ F.T @ np.linalg.inv(Pp[t + 1][both])
            xs[t, both] = xf[t, both] + np.einsum(
                "sij,sj->si", C, xs[t + 1, both] - xp[t + 1, both]
            )
        xf = xs
    return xf[:, :, 0].T


def _filtered(frames: Sequence[Frame], q: float, r: float, smooth: bool) -> list[Frame]:
    """Each ground-truth track's BEV centre filtered over the sequence (rows keep their ids)."""
    ids = np.unique(np.concatenate([f.boxes.track_id for f in frames]))
    z = np.full((2 * len(ids), len(frames)), np.nan)
    where = []
    for t, f in enumerate(frames):
        k = np.searchsorted(ids, f.boxes.track_id)
        z[2 * k, t], z[2 * k + 1, t] = f.boxes.xyz[:, 0], f.boxes.xyz[:, 1]
        where.append(k)
    est = cv_filter(z, q, r, smooth=smooth)
    out = []
    for t, (f, k) in enumerate(zip(frames, where, strict=True)):
        xyz = f.boxes.xyz.copy()
        xyz[:, 0], xyz[:, 1] = est[2 * k, t], est[2 * k + 1, t]
        out.append(dataclasses.replace(f, boxes=f.boxes.replace(xyz=xyz)))
    return out


def _score(root: Path, scenes: dict[str, list[Frame]], cls: str, width: np.ndarray) -> dict:
    with work_folder("noise") as tmp:
        for seq, frames in scenes.items():
            outputs = [
                TrackOutput(f.scene, f.frame_id, 0.0, f.boxes, np.full((len(f.boxes), 2), np.nan),
                            np.ones(len(f.boxes), np.int8), np.full(len(f.boxes), -1),
                            np.zeros(len(f.boxes), np.int8))
                for f in frames
            ]  # fmt: skip
            write_kitti_sequence(tmp / f"{seq}.txt", outputs, frames, width_scale=width)
        metrics = evaluate_kitti(
            label_dir=root / "training" / "label_02",
            result_dir=tmp,
            seq_lengths={s: len(f) for s, f in scenes.items()},
            classes=[cls],
        )[cls]
    return {k: round(float(metrics[k]), 2) for k in KEPT}


def noise_floor(
    root: Path, classes: Sequence[str], levels: Sequence[str] = ("noise", "double"), seed: int = 0
) -> list[dict[str, Any]]:
    """One row per (class, level): HOTA etc. of the clean, jittered, filtered and smoothed
    ground truth."""
    width = load_config("kitti").image_width_scales()
    _, gt = convert_kitti(root, seqs=VALIDATION_SEQS, classes=list(classes), with_gt=True)
    assert gt is not None
    rows = []
    for cls in classes:
        cid = category_index(cls)
        clean = {
            s: [dataclasses.replace(f, boxes=f.boxes[f.boxes.category == cid]) for f in frames]
            for s, frames in gt.items()
        }
        base = _score(root, clean, cls, width)
        for level in levels:
            spec = jitter_only(level)
            noisy = {s: perturb_frames(f, spec, seed=seed) for s, f in clean.items()}
            row: dict[str, Any] = {"class": cls, "level": level, "spec": dataclasses.asdict(spec)}
            row["clean"], row["jittered"] = base, _score(root, noisy, cls, width)
            r = spec.centre_sigma_m**2
            for name, smooth in (("online filter", False), ("offline smoother", True)):
                best = max(
                    (
                        (_score(root, {s: _filtered(f, q, r, smooth) for s, f in noisy.items()},
                                cls, width), q)
                        for q in Q_CHOICES
                    ),
                    key=lambda mq: mq[0]["HOTA"],
                )  # fmt: skip
                row[name] = {**best[0], "q": best[1]}
            rows.append(row)
            print(f"{cls} {level}: {row}", flush=True)
    return rows


def markdown(rows: list[dict[str, Any]]) -> list[str]:
    """The table of :func:`noise_floor`: HOTA and its drop from clean."""
    lines = [
        "| class | jitter (level) | ground truth, clean | jittered | online filter (q) |"
        " offline smoother (q) |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        spec, clean = row["spec"], row["clean"]["HOTA"]

        def cell(name: str, row: dict[str, Any] = row, clean: float = clean) -> str:
            m = row[name]
            q = f" ({m['q']:g})" if "q" in m else ""
            return f"{m['HOTA']:.2f} (Δ {m['HOTA'] - clean:+.2f}){q}"

        lines.append(
            f"| {row['class']} | σ {spec['centre_sigma_m']:g} m, {spec['yaw_sigma_deg']:g}° "
            f"({row['level']}) | {clean:.2f} | {cell('jittered')} | {cell('online filter')} | "
            f"{cell('offline smoother')} |"
        )
    return [*lines, ""]
