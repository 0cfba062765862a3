"""LiDAR range, image bearing: a detection's 3D centre turned toward its own 2D box's bearing.

A detection that carries a 2D box of its own (an image head's, not its 3D box's projection)
measures the object's bearing twice: by its 3D centre and by the centre of its 2D box. Seen from
the camera, the fused centre keeps the 3D range and takes the bearing

    θ = θ_3D + w (θ_2D − θ_3D),    w = σ²_3D / (σ²_3D + σ²_2D)

the inverse-variance blend of two independent measurements of one angle. θ_2D − θ_3D is the
difference of the horizontal viewing angles of the 2D box's centre and of the 3D box
projection's centre, so a box shape the projection does not share (a tighter image box) moves
nothing. Both variances come from the detections themselves, causally, per category, as
:mod:`tracker.noise` estimates the centre noise (no labels):

- σ²_3D, the lateral noise of the 3D centres: the second difference of three chained centres
  along the middle one's lateral direction, var(Δ²ℓ) = 6 σ²_3D (robust: 1.4826 · median / √6);
- σ²_3D + σ²_2D from the lateral disagreement of the two, δ = range · (θ_2D − θ_3D): its spread
  1.4826 · median|δ| about zero. Unlike a second difference it keeps the part of an image box's
  error that persists over frames (an occluded object's box covers its visible part only), so
  a head whose boxes are biased that way is trusted less.

Hence w = min(1, σ²_3D / var δ), 0 until both estimates have ``MIN_SAMPLES`` samples. A box
counts as its own where its IoU with its 3D box's projection (as KITTI writes one: the box stood
upright in the camera's axes) is below ``OWN_BOX_IOU`` and that projection lies wholly in front
of the camera and inside the image: a box the image edge cuts has a cut centre. A LiDAR
detector's 2D boxes are projections, so its frames pass through unchanged.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from tracker.boxes import Boxes, FloatArray, IntArray
from tracker.camera import (
    NEAR_PLANE_M,
    WORLD_FROM_CAMERA_AXES,
    boxes_world_to_rect,
    upright_in_camera_axes,
)
from tracker.cost import iou_xyxy
from tracker.frame import Camera, Frame
from tracker.geometry import corners_3d
from tracker.noise import (
    EDGES,
    LINK_SIGMAS,
    count_magnitudes,
    even_steps,
    robust_square_scale,
)

#: a centre column within this of the projection's (pixels) is the projection's to rounding: it
#: joins the estimates but moves nothing (a LiDAR detector's small boxes, written to 0.01 px,
#: can fall below OWN_BOX_IOU)
MIN_GAP_PX = 1.0
#: a disagreement beyond this many of its estimated standard deviations is a mismatched box, not
#: noise: it joins the estimates (their medians are robust) but moves nothing
MAX_GAP_SIGMAS = 3.0
#: a detection's 2D box is its own (not its 3D box's projection) when their IoU is below this;
#: a projection written by the detector agrees with ours to rounding (IoU >= 0.99 on the three
#: KITTI detectors of the kit). The KITTI writer's rule too (tracker.io.writers.ImageBoxStats)
OWN_BOX_IOU = 0.95


@dataclasses.dataclass(slots=True)
class _OwnBoxes:
    """One frame's detections with an own 2D box: their rows, world xy, lateral unit vectors
    (world xy), categories, lengths (the least linking radius), bearing gaps θ_2D − θ_3D (rad),
    lateral disagreements δ = range · gap (m) and cameras."""

    rows: IntArray
    xy: FloatArray
    lateral: FloatArray
    category: IntArray
    length: FloatArray
    gap: FloatArray
    disagreement: FloatArray
    camera: IntArray
    moves: np.ndarray  # the centre column is at least MIN_GAP_PX from the projection's


class BearingFusion:
    """Causal per-category bearing weights and the fused detections of one scene.

    Feed the scene's frames in time order to :meth:`apply`; each frame's own boxes join the
    estimates before that frame is fused (its own second differences need the two frames before).
    """

    def __init__(self, n_categories: int) -> None:
        n_bins = len(EDGES) - 1
        self.lateral_counts = np.zeros((n_categories, n_bins), dtype=np.int64)  # |Δ²ℓ|
        self.disagree_counts = np.zeros((n_categories, n_bins), dtype=np.int64)  # |δ|
        self._frames: list[tuple[float, _OwnBoxes, IntArray]] = []  # the last two, with links

    def weight(self) -> FloatArray:
        """(C,) w per category (0 where either estimate lacks samples)."""
        lateral = robust_square_scale(self.lateral_counts) / 6.0
        disagree = robust_square_scale(self.disagree_counts)
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.clip(lateral / disagree, 0.0, 1.0)
        return np.where(np.isfinite(w), w, 0.0)

    def disagreement_sigma(self) -> FloatArray:
        """(C,) the standard deviation of the lateral disagreement δ (m; NaN: no estimate)."""
        return np.sqrt(robust_square_scale(self.disagree_counts))

    def apply(self, frame: Frame, time_secs: float, own: _OwnBoxes | None) -> Frame:
        """``frame`` with its own-box detections (``own``, from :func:`own_boxes`) turned by ``w``
        of their bearing gap (the same frame object when nothing moves)."""
        self._update(time_secs, own)
        if own is None:
            return frame
        spread = self.disagreement_sigma()[own.category]
        with np.errstate(invalid="ignore"):  # (NaN spread: no estimate, and w is 0 anyway)
            plausible = np.abs(own.disagreement) <= MAX_GAP_SIGMAS * spread
        w = np.where(own.moves & plausible, self.weight()[own.category], 0.0)
        if not w.any():
            return frame
        xyz = frame.boxes.xyz.copy()
        for cam in np.unique(own.camera[w > 0]):
            at = (own.camera == cam) & (w > 0)
            xyz[own.rows[at]] = turn_about_camera(
                xyz[own.rows[at]], frame.cameras[cam].camera_from_world, w[at] * own.gap[at]
            )
        return dataclasses.replace(frame, boxes=frame.boxes.replace(xyz=xyz))

    def _update(self, time_secs: float, own: _OwnBoxes | None) -> None:
        if own is None:
            self._frames = []  # a frame without own boxes breaks every chain
            return
        count_magnitudes(self.disagree_counts, own.category, np.abs(own.disagreement))
        link = np.full(len(own.rows), -1, dtype=np.int64)
        if self._frames:
            prev = self._frames[-1][1]
            with np.errstate(over="ignore"):
                d = np.linalg.norm(own.xy[:, None] - prev.xy[None], axis=-1)
            d[own.category[:, None] != prev.category[None]] = np.inf
            nearest = d.argmin(axis=1)
            # within the box's length or LINK_SIGMAS σ_3D, as tracker.noise links
            lateral_sd = np.sqrt(robust_square_scale(self.lateral_counts) / 6.0)
            radius = np.fmax(own.length, LINK_SIGMAS * lateral_sd[own.category])
            ok = d[np.arange(len(d)), nearest] <= radius
            link[ok] = nearest[ok]
            if len(self._frames) == 2 and even_steps(
                self._frames[0][0], self._frames[1][0], time_secs
            ):
                prev_link = self._frames[-1][2]
                cur = np.flatnonzero(ok)
                cur = cur[prev_link[link[cur]] >= 0]  # chained over three frames
                if len(cur):
                    mid = link[cur]
                    first = self._frames[0][1].xy[prev_link[mid]]
                    second = own.xy[cur] - 2.0 * prev.xy[mid] + first
                    ell = np.einsum("ij,ij->i", second, prev.lateral[mid])
                    count_magnitudes(self.lateral_counts, own.category[cur], np.abs(ell))
        self._frames = [*self._frames[-1:], (time_secs, own, link)]


def own_boxes(frames: Sequence[Frame]) -> list[_OwnBoxes | None]:
    """Per frame, its detections whose 2D box is their own (module docstring), or None.

    The projections of the whole scene are computed at once (each box with its frame's camera):
    a LiDAR detector's scene costs one batched projection and nothing after it.
    """
    out: list[_OwnBoxes | None] = [None] * len(frames)
    # every box seen by a camera, with that camera's matrices
    cameras: list[Camera] = []
    at_frame, at_row, at_camera, at_index = [], [], [], []
    for k, frame in enumerate(frames):
        b = frame.boxes
        cam = b.camera
        finite = np.isfinite(b.xyz).all(axis=1) & np.isfinite(b.lwh).all(axis=1)
        seen = np.flatnonzero((cam >= 0) & (cam < len(frame.cameras)) & finite & np.isfinite(b.yaw))
        if not len(seen):
            continue
        used = np.unique(cam[seen])
        index = np.full(len(frame.cameras), -1, dtype=np.int64)
        index[used] = np.arange(len(cameras), len(cameras) + len(used))
        cameras.extend(frame.cameras[c] for c in used)
        at_frame.append(np.full(len(seen), k, dtype=np.int64))
        at_row.append(seen)
        at_camera.append(cam[seen])
        at_index.append(index[cam[seen]])
    if not at_frame:
        return out
    frame_of, row, camera_of, index = (
        np.concatenate(a) for a in (at_frame, at_row, at_camera, at_index)
    )
    cam_m = np.stack([c.camera_from_world for c in cameras])
    cam_k = np.stack([c.image_from_camera for c in cameras])
    usable = _rigid(cam_m, cam_k)[index]
    if not usable.all():
        frame_of, row, camera_of, index = (a[usable] for a in (frame_of, row, camera_of, index))
    boxes = Boxes.concat([frames[k].boxes for k in range(len(frames))])
    start = np.cumsum([0] + [len(f.boxes) for f in frames])
    b = boxes[start[frame_of] + row]
    camera_from_world, image_from_camera = cam_m[index], cam_k[index]  # (N, 4, 4), (N, 3, 4)
    size = np.array([(c.width_px, c.height_px) for c in cameras], dtype=np.float64)[index]
    # the projection a detector writes: the box upright in camera axes (KITTI's convention and
    # the KITTI writer's, tracker.camera.project_boxes_upright), for boxes wholly in front
    location, hwl, rotation_y = boxes_world_to_rect(b.xyz, b.lwh, b.yaw, camera_from_world)
    in_front = location[:, 2] - 0.5 * np.hypot(hwl[:, 1], hwl[:, 2]) > NEAR_PLANE_M
    xyz_up, yaw_up = upright_in_camera_axes(location, hwl, rotation_y)
    corners = corners_3d(xyz_up, b.lwh, yaw_up) @ WORLD_FROM_CAMERA_AXES[:3, :3]  # camera axes
    h = corners @ image_from_camera[:, :, :3].transpose(0, 2, 1) + image_from_camera[:, None, :, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = h[..., :2] / h[..., 2:3]
    proj = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)  # (N, 4), unclipped
    det = b.xyxy_image
    with np.errstate(invalid="ignore"):
        # the whole projection inside the image: a box the image edge cuts has a cut centre
        ok = in_front & np.isfinite(det).all(axis=1) & (det[:, 2:] > det[:, :2]).all(axis=1)
        ok &= image_from_camera[:, 0, 0] > 0  # a focal length to turn pixels into angles
        for box in (proj, det):  # both wholly inside the image
            ok &= (box[:, :2] >= 0).all(axis=1) & (box[:, 2:] <= size - 1).all(axis=1)
    ok[ok] = iou_xyxy(det[ok], proj[ok]) < OWN_BOX_IOU
    own = np.flatnonzero(ok)
    if not len(own):
        return out
    fx, cx = image_from_camera[own, 0, 0], image_from_camera[own, 0, 2]
    u_det = 0.5 * (det[own, 0] + det[own, 2])
    u_proj = 0.5 * (proj[own, 0] + proj[own, 2])
    gap = np.arctan((u_det - cx) / fx) - np.arctan((u_proj - cx) / fx)
    m = camera_from_world[own]
    p = np.einsum("nij,nj->ni", m[:, :3, :3], b.xyz[own]) + m[:, :3, 3]  # camera frame
    phi = np.arctan2(p[:, 0], p[:, 2])  # bearing in the camera's x-z plane
    # the lateral unit (cos φ, 0, -sin φ) in the camera frame, in world xy (Rᵀ v)
    lateral_cam = np.column_stack([np.cos(phi), np.zeros_like(phi), -np.sin(phi)])
    lateral = np.einsum("nji,nj->ni", m[:, :3, :3], lateral_cam)[:, :2]
    columns = (
        row[own], b.xyz[own, :2], lateral, b.category[own], b.lwh[own, 0], gap,
        np.hypot(p[:, 0], p[:, 2]) * gap, camera_of[own], np.abs(u_det - u_proj) >= MIN_GAP_PX,
    )  # fmt: skip
    bounds = np.searchsorted(frame_of[own], np.arange(len(frames) + 1))
    for k in np.flatnonzero(np.diff(bounds)):
        part = slice(bounds[k], bounds[k + 1])
        out[k] = _OwnBoxes(*(c[part] for c in columns))
    return out


def fuse_scene(frames: Sequence[Frame], n_categories: int) -> list[Frame]:
    """A scene's frames, each fused with the weights its past gives (:class:`BearingFusion`);
    the frames themselves where no own box moves (a LiDAR detector's scene)."""
    own = own_boxes(frames)
    if not any(o is not None and o.moves.any() for o in own):
        return list(frames)
    fusion = BearingFusion(n_categories)
    return [fusion.apply(f, f.timestamp_secs, o) for f, o in zip(frames, own, strict=True)]


def turn_about_camera(
    xyz: FloatArray, camera_from_world: FloatArray, angle: FloatArray
) -> FloatArray:
    """(N, 3) world points turned by ``angle`` (N,) rad about the camera's vertical axis through
    its centre (``camera_from_world`` rigid): the bearing atan2(x, z) in the camera frame grows by
    the angle and the world height is kept, so the range in the camera's x-z plane is kept
    exactly for a level camera (to 2 cm at 15 m and 4° of pitch otherwise).

    Row by row in plain arithmetic (no matrix product), so a point's result does not depend on
    the other rows passed with it (a BLAS product's rounding can).
    """
    m = np.asarray(camera_from_world, dtype=np.float64)
    r, t = m[:3, :3], m[:3, 3]
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    px = r[0, 0] * x + r[0, 1] * y + r[0, 2] * z + t[0]
    py = r[1, 0] * x + r[1, 1] * y + r[1, 2] * z + t[1]
    pz = r[2, 0] * x + r[2, 1] * y + r[2, 2] * z + t[2]
    c, s = np.cos(angle), np.sin(angle)
    qx, qz = c * px + s * pz - t[0], -s * px + c * pz - t[2]
    qy = py - t[1]
    out = np.empty_like(xyz)  # world = Rᵀ (p - t)
    out[:, 0] = r[0, 0] * qx + r[1, 0] * qy + r[2, 0] * qz
    out[:, 1] = r[0, 1] * qx + r[1, 1] * qy + r[2, 1] * qz
    out[:, 2] = z
    return out


def _rigid(camera_from_world: FloatArray, image_from_camera: FloatArray) -> np.ndarray:
    """(N,) whether each camera's matrices (N, 4, 4) and (N, 3, 4) are finite and its
    ``camera_from_world`` a rotation and a translation (the turn's way back to the world frame
    is its transpose)."""
    m, k = camera_from_world, image_from_camera
    finite = np.isfinite(m).all(axis=(1, 2)) & np.isfinite(k).all(axis=(1, 2))
    r = np.where(finite[:, None, None], m[:, :3, :3], 0.0)
    with np.errstate(invalid="ignore", over="ignore"):
        orthonormal = np.abs(r.transpose(0, 2, 1) @ r - np.eye(3)).max(axis=(1, 2)) <= 1e-6
    return finite & orthonormal & (np.abs(m[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) <= 1e-12)
