"""Seeded perturbations of a detection set: the noise model of the robustness benchmark.

Per box: drop with probability ``drop_rate``; jitter the BEV centre (x, y) by N(0, σ) per axis
and the heading by N(0, σ_yaw); add N(0, σ_score) to ``score_raw`` and recompute ``score`` with a
``rescore(category, raw)`` map. By default (``image_boxes="follow"``) the detector's 2D box moves
with its 3D box (by the change of the box's projection), so the image stage sees the same error as
the BEV stage: a LiDAR detector's 2D box is its 3D box's projection. With ``"keep"`` it stays
where the detector put it, as a 2D box from an image head would (independent of the 3D error).

Per frame and class: Poisson(``fp_rate`` × real boxes of that class) false positives (Poisson
clutter, the standard clutter model of the tracking literature). Each is a plausible box of the
class: the size and camera of a real box of the scene, a centre uniform over the depth × lateral
range the scene's real boxes of the class cover in their camera, at that box's height, inside the
camera's view; a uniform heading; the (score, raw score) pair of another real box of the class.
Its 2D box is the projection of its 3D box (FPs that do not project into the image are dropped).

Each class of each scene has its own stream, seeded from ``(seed, sha256(scene name / class
name))``, so a class's noise does not depend on which other scenes or classes are run, or in which
order (`--classes pedestrian` perturbs the pedestrians as `--classes car,pedestrian,cyclist`
does), and the same seed gives the same boxes. Each box draws its drop and jitter variates
whatever the spec, so at one seed a stronger level drops a superset of a weaker level's boxes
(common random numbers across levels); score noise is drawn after the false positives, only when
asked for.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.camera import NEAR_PLANE_M, project_boxes_batched
from tracker.categories import CATEGORIES
from tracker.frame import Frame
from tracker.geometry import wrap_angle
from tracker.io.convert.kitti import _sigmoid

#: ``rescore(category (N,), score_raw (N,), range_m (N,)) -> score (N,)``: raw detector score
#: -> calibrated (``range_m``: BEV distance from the ego, NaN when unknown; e.g.
#: :meth:`tracker.calibration.ScoreProfile.scores`).
Rescore = Callable[[IntArray, FloatArray, FloatArray], FloatArray]

#: What the centre and yaw jitter does to a detection's 2D box: moves it with the 3D box's
#: projection ("follow") or leaves it ("keep").
JitteredBoxes = Literal["follow", "keep"]
JITTERED_BOXES: tuple[JitteredBoxes, ...] = ("follow", "keep")

#: Candidate positions drawn per false positive; the first inside the camera's view is kept.
_FP_TRIES = 8


@dataclass(frozen=True, slots=True)
class PerturbSpec:
    """How much noise to add (all zero: the clean input).

    Attributes
    ----------
    drop_rate : probability that a detection is removed, in [0, 1].
    centre_sigma_m : std of the Gaussian added to the BEV centre x and y, metres.
    yaw_sigma_deg : std of the Gaussian added to the heading, degrees.
    fp_rate : false positives per real box of the same class and frame (a Poisson mean).
    score_sigma : std of the Gaussian added to the raw detector score (``score_raw``).
    """

    drop_rate: float = 0.0
    centre_sigma_m: float = 0.0
    yaw_sigma_deg: float = 0.0
    fp_rate: float = 0.0
    score_sigma: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"PerturbSpec.{f.name}: expected a finite value >= 0, got {value}")
        if self.drop_rate > 1:
            raise ValueError(f"PerturbSpec.drop_rate: expected <= 1, got {self.drop_rate}")

    @property
    def is_clean(self) -> bool:
        return all(getattr(self, f.name) == 0 for f in dataclasses.fields(self))


#: The name of the unperturbed level.
CLEAN = "clean"

#: The benchmark's named levels (issue #11); score noise is off in all, ``--score-sigma`` sets it.
NOISE_LEVELS: dict[str, PerturbSpec] = {
    CLEAN: PerturbSpec(),
    "noise": PerturbSpec(drop_rate=0.10, centre_sigma_m=0.15, yaw_sigma_deg=2.0, fp_rate=0.02),
    "double": PerturbSpec(drop_rate=0.20, centre_sigma_m=0.30, yaw_sigma_deg=5.0, fp_rate=0.05),
}
# ``noise`` taken apart, one kind at a time: which of its perturbations costs what
_NOISE = NOISE_LEVELS["noise"]
NOISE_LEVELS |= {
    "drop": PerturbSpec(drop_rate=_NOISE.drop_rate),
    "jitter": PerturbSpec(centre_sigma_m=_NOISE.centre_sigma_m, yaw_sigma_deg=_NOISE.yaw_sigma_deg),
    "fp": PerturbSpec(fp_rate=_NOISE.fp_rate),
}


def sigmoid_rescore(
    category: IntArray, score_raw: FloatArray, range_m: FloatArray | None = None
) -> FloatArray:
    """The KITTI converter's calibration: ``score = sigmoid(score_raw)`` for every class."""
    del category, range_m  # one map for all classes and ranges
    return _sigmoid(np.asarray(score_raw, dtype=np.float64))


def class_rng(seed: int, scene: str, category: int) -> np.random.Generator:
    """The generator of one class of one scene: from the seed and a stable hash of the scene and
    class names (not ``hash()``, which is salted per process)."""
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    if not 0 <= category < len(CATEGORIES):
        raise ValueError(f"category must index tracker.categories.CATEGORIES, got {category}")
    key = f"{scene}/{CATEGORIES[int(category)]}".encode()
    digest = np.frombuffer(hashlib.sha256(key).digest()[:16], dtype=np.uint32)
    return np.random.default_rng([seed, *(int(x) for x in digest)])


def perturb_frames(
    frames: Sequence[Frame],
    spec: PerturbSpec,
    *,
    seed: int,
    rescore: Rescore | None = None,
    image_boxes: JitteredBoxes = "follow",
) -> list[Frame]:
    """Perturbed copies of detection frames (one or more scenes, each in time order).

    Parameters
    ----------
    frames : detection frames; each scene's frames are perturbed together.
    spec : the noise; a clean spec returns the input frames unchanged.
    seed : >= 0; with the scene and class names it seeds each class's generator
        (:func:`class_rng`).
    rescore : raw score -> ``score`` after score noise (default :func:`sigmoid_rescore`).
    image_boxes : "follow": the jitter moves each detector 2D box with its 3D box's projection;
        "keep": 2D boxes stay as given (see the module docstring).

    Returns
    -------
    The frames in input order, with new boxes: the kept real boxes (their order kept) followed
    by the frame's false positives (``track_id`` -1, velocity 0).

    Raises
    ------
    ValueError : score noise on boxes without a raw score (``score_raw`` NaN), or an unknown
        ``image_boxes``.
    """
    if image_boxes not in JITTERED_BOXES:
        raise ValueError(f"image_boxes: expected one of {JITTERED_BOXES}, got {image_boxes!r}")
    out = list(frames)
    if spec.is_clean:
        return out
    by_scene: dict[str, list[int]] = {}
    for i, frame in enumerate(frames):
        by_scene.setdefault(frame.scene, []).append(i)
    for scene, rows in by_scene.items():
        perturbed = _perturb_scene(
            [frames[i] for i in rows],
            spec,
            functools.partial(class_rng, seed, scene),
            rescore or sigmoid_rescore,
            move_image_boxes=image_boxes == "follow",
        )
        for i, frame in zip(rows, perturbed, strict=True):
            out[i] = frame
    return out


@dataclass(frozen=True, slots=True)
class _Cameras:
    """Every (frame, camera) of a scene stacked, for per-box lookups without a frame loop."""

    offset: IntArray  # (F,) first flat index of each frame's cameras
    count: IntArray  # (F,) cameras per frame
    image_from_world: FloatArray  # (K, 3, 4)
    camera_from_world: FloatArray  # (K, 4, 4)
    size_px: IntArray  # (K, 2) width, height

    @classmethod
    def of(cls, frames: Sequence[Frame]) -> _Cameras:
        count = np.array([len(f.cameras) for f in frames], dtype=np.int64)
        cams = [c for f in frames for c in f.cameras]
        return cls(
            offset=np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64),
            count=count,
            image_from_world=np.array([c.image_from_world for c in cams]).reshape(-1, 3, 4),
            camera_from_world=np.array([c.camera_from_world for c in cams]).reshape(-1, 4, 4),
            size_px=np.array([(c.width_px, c.height_px) for c in cams], np.int64).reshape(-1, 2),
        )

    def flat(self, frame: IntArray, camera: IntArray) -> IntArray:
        """(N,) flat camera index of each (frame, camera index) pair; -1 where there is none."""
        ok = (camera >= 0) & (camera < self.count[frame])
        return np.where(ok, self.offset[frame] + camera, -1)


def _perturb_scene(
    frames: Sequence[Frame],
    spec: PerturbSpec,
    rng_of: Callable[[int], np.random.Generator],
    rescore: Rescore,
    *,
    move_image_boxes: bool,
) -> list[Frame]:
    per_frame = np.array([len(f.boxes) for f in frames], dtype=np.int64)
    frame_of = np.repeat(np.arange(len(frames)), per_frame)
    boxes = Boxes.concat([f.boxes for f in frames])
    cams = _Cameras.of(frames)
    n = len(boxes)
    rngs = {int(c): rng_of(int(c)) for c in np.unique(boxes.category)}
    # Each class's stream, drawn in a fixed order whatever the spec (see the module docstring).
    u_drop, z_xy, z_yaw = np.empty(n), np.empty((n, 2)), np.empty(n)
    for category, rng in rngs.items():
        rows = np.flatnonzero(boxes.category == category)
        u_drop[rows] = rng.random(len(rows))
        z_xy[rows] = rng.standard_normal((len(rows), 2))
        z_yaw[rows] = rng.standard_normal(len(rows))

    xyz = boxes.xyz.copy()
    xyz[:, :2] += spec.centre_sigma_m * z_xy
    yaw = boxes.yaw  # untouched (not even re-wrapped) without yaw noise
    if spec.yaw_sigma_deg > 0:
        yaw = wrap_angle(yaw + np.deg2rad(spec.yaw_sigma_deg) * z_yaw)
    keep = u_drop >= spec.drop_rate
    xyxy = boxes.xyxy_image
    if move_image_boxes and (spec.centre_sigma_m > 0 or spec.yaw_sigma_deg > 0):
        flat_camera = np.where(keep, cams.flat(frame_of, boxes.camera), -1)  # kept boxes only
        xyxy = _moved_image_boxes(boxes, xyz, yaw, flat_camera, cams)
    real = boxes.replace(xyz=xyz, yaw=yaw, xyxy_image=xyxy)[keep]
    fps, fp_frame = _false_positives(boxes, frame_of, spec.fp_rate, cams, rngs)
    out = Boxes.concat([real, fps])
    out_frame = np.concatenate([frame_of[keep], fp_frame])

    if spec.score_sigma > 0:
        if np.isnan(out.score_raw).any():
            raise ValueError("score noise needs the raw detector score (score_raw is NaN)")
        z_score = np.empty(len(out))
        for category, rng in rngs.items():
            rows = np.flatnonzero(out.category == category)
            z_score[rows] = rng.standard_normal(len(rows))
        raw = out.score_raw + spec.score_sigma * z_score
        ego = np.array([np.asarray(f.world_from_ego, np.float64)[:2, 3] for f in frames])
        ego = ego.reshape(-1, 2)[out_frame]
        range_m = np.hypot(out.xyz[:, 0] - ego[:, 0], out.xyz[:, 1] - ego[:, 1])
        out = out.replace(score_raw=raw, score=rescore(out.category, raw, range_m))

    order = np.argsort(out_frame, kind="stable")  # real boxes first within a frame, then FPs
    ends = np.cumsum(np.bincount(out_frame, minlength=len(frames)))
    starts = ends - np.bincount(out_frame, minlength=len(frames))
    return [
        dataclasses.replace(frame, boxes=out[order[a:b]])
        for frame, a, b in zip(frames, starts, ends, strict=True)
    ]


def _moved_image_boxes(
    boxes: Boxes, xyz: FloatArray, yaw: FloatArray, flat_camera: IntArray, cams: _Cameras
) -> FloatArray:
    """Detector 2D boxes shifted by the change of their 3D box's projection (clipped to the
    image); unchanged where either projection is not visible or the box has no camera."""
    out = boxes.xyxy_image.copy()
    rows = np.flatnonzero((flat_camera >= 0) & np.isfinite(out).all(axis=1))
    if not len(rows):
        return out
    m, size = cams.image_from_world[flat_camera[rows]], cams.size_px[flat_camera[rows]]
    _, before, seen_before = project_boxes_batched(
        boxes.xyz[rows], boxes.lwh[rows], boxes.yaw[rows], m, size
    )
    _, after, seen_after = project_boxes_batched(xyz[rows], boxes.lwh[rows], yaw[rows], m, size)
    max_xy = np.tile(size - 1.0, 2)
    moved = np.clip(out[rows] + (after - before), 0.0, max_xy)
    ok = seen_before & seen_after & (moved[:, 2:] > moved[:, :2]).all(axis=1)
    out[rows[ok]] = moved[ok]
    return out


def _false_positives(
    boxes: Boxes,
    frame_of: IntArray,
    fp_rate: float,
    cams: _Cameras,
    rngs: dict[int, np.random.Generator],
) -> tuple[Boxes, IntArray]:
    """The scene's false positives (see the module docstring) and the frame of each; each class
    draws from its own generator in ``rngs``."""
    parts: list[Boxes] = []
    frames: list[IntArray] = []
    if fp_rate <= 0:
        return Boxes.empty(), np.zeros(0, dtype=np.int64)
    num_frames = len(cams.count)
    world_from_camera = np.linalg.inv(cams.camera_from_world)  # (K, 4, 4)
    for category, rng in sorted(rngs.items()):
        of_class = np.flatnonzero(boxes.category == category)
        flat = cams.flat(frame_of[of_class], boxes.camera[of_class])
        donors = of_class[flat >= 0]  # boxes in a camera give size, camera and height
        n_fp = rng.poisson(fp_rate * np.bincount(frame_of[of_class], minlength=num_frames))
        total = int(n_fp.sum())
        if not len(donors) or not total:
            continue
        # Centres of the class in their own camera frame (x right, y down, z forward).
        m = cams.camera_from_world[flat[flat >= 0]]
        centre_cam = np.einsum("nij,nj->ni", m[:, :3, :3], boxes.xyz[donors]) + m[:, :3, 3]
        lo, hi = centre_cam.min(axis=0), centre_cam.max(axis=0)

        fp_frame = np.repeat(np.arange(num_frames), n_fp)  # (T,)
        donor = rng.integers(len(donors), size=(total, _FP_TRIES))  # (T, tries)
        xz = rng.uniform(lo[[0, 2]], hi[[0, 2]], size=(total, _FP_TRIES, 2))
        yaw = rng.uniform(-np.pi, np.pi, size=(total, _FP_TRIES))
        at_frame = np.broadcast_to(fp_frame[:, None], donor.shape)
        cam = cams.flat(at_frame, boxes.camera[donors[donor]])  # (T, tries) flat camera
        centre = np.stack([xz[..., 0], centre_cam[donor, 1], xz[..., 1], np.ones(donor.shape)], -1)
        xyz = np.einsum("tkij,tkj->tki", world_from_camera[cam][..., :3, :], centre)
        lwh = boxes.lwh[donors[donor]]
        ok = cam >= 0
        xyxy = np.full((total, _FP_TRIES, 4), np.nan)
        c = np.flatnonzero(ok.reshape(-1))
        _, xyxy_ok, visible = project_boxes_batched(
            xyz.reshape(-1, 3)[c],
            lwh.reshape(-1, 3)[c],
            yaw.reshape(-1)[c],
            cams.image_from_world[cam.reshape(-1)[c]],
            cams.size_px[cam.reshape(-1)[c]],
        )
        inside = _centre_in_image(xyz.reshape(-1, 3)[c], cam.reshape(-1)[c], cams)
        ok.reshape(-1)[c] = visible & inside
        xyxy.reshape(-1, 4)[c] = xyxy_ok
        first = np.argmax(ok, axis=1)  # the first accepted try of each FP
        placed = ok[np.arange(total), first]
        t, k = np.flatnonzero(placed), first[placed]
        scored = of_class[rng.integers(len(of_class), size=len(t))]  # (score, raw) of a real box
        parts.append(
            Boxes.create(
                xyz=xyz[t, k],
                lwh=lwh[t, k],
                yaw=wrap_angle(yaw[t, k]),
                category=np.full(len(t), category),
                score=boxes.score[scored],
                score_raw=boxes.score_raw[scored],
                xyxy_image=xyxy[t, k],
                camera=boxes.camera[donors[donor[t, k]]],
            )
        )
        frames.append(fp_frame[t])
    if not parts:
        return Boxes.empty(), np.zeros(0, dtype=np.int64)
    return Boxes.concat(parts), np.concatenate(frames)


def _centre_in_image(xyz: FloatArray, flat_camera: IntArray, cams: _Cameras) -> NDArray[np.bool_]:
    """(N,) the box centre is in front of the camera and projects inside the image."""
    m = cams.image_from_world[flat_camera]
    h = np.einsum("nij,nj->ni", m[:, :, :3], xyz) + m[:, :, 3]
    front = h[:, 2] >= NEAR_PLANE_M
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = h[:, :2] / h[:, 2:3]
    size = cams.size_px[flat_camera]
    return front & (uv >= 0).all(axis=1) & (uv <= size - 1).all(axis=1)
