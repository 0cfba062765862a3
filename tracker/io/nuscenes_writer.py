"""The nuScenes tracking submission writer (``results.json``).

Format (nuScenes tracking benchmark; loaded by the devkit's ``load_prediction``)::

    {"meta": {"use_camera": false, "use_lidar": true, ...},
     "results": {sample_token: [{"sample_token", "translation", "size", "rotation",
                                 "velocity", "tracking_id", "tracking_name",
                                 "tracking_score"}, ...]}}

* ``translation`` = the tracked box centre (world), ``size`` = (w, l, h) in nuScenes order,
  ``rotation`` = the quaternion (w, x, y, z) of the **filtered** heading (the reference wrote the
  raw detection yaw), ``velocity`` = the filtered (vx, vy) in m/s.
* ``tracking_id`` = ``"<scene>_<track id>"`` (unique over the file; our ids restart per scene).
* ``tracking_score`` = the track's last detection score; a coasting box (a track output while
  missed, ``lifecycle.max_misses_output``) gets ``coasting_score`` (0, as the reference).
* Every sample of every written frame gets an entry (possibly empty): the devkit requires all
  samples of the split. At most ``max_boxes_per_sample`` boxes per sample (500), best first.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from tracker.categories import CATEGORIES
from tracker.errors import InputError
from tracker.events import TrackOutput, TrackStatus
from tracker.frame import Frame
from tracker.io.baseversion import yaw_to_quaternion_wxyz
from tracker.io.fileio import compact_json, write_bytes_atomic, write_json_atomic

TRACKING_NAMES: Final[frozenset[str]] = frozenset(
    ("bicycle", "bus", "car", "motorcycle", "pedestrian", "trailer", "truck")
)
MAX_BOXES_PER_SAMPLE: Final = 500
#: The submission's modality flags when the detection file gave none (a LiDAR detector).
DEFAULT_META: Final[dict[str, bool]] = {
    "use_camera": False,
    "use_lidar": True,
    "use_radar": False,
    "use_map": False,
    "use_external": False,
}


def nuscenes_results(
    results: Mapping[str, tuple[Sequence[Frame], Sequence[TrackOutput]]],
    *,
    coasting_score: float | None = 0.0,
    max_boxes_per_sample: int = MAX_BOXES_PER_SAMPLE,
) -> dict[str, list[dict[str, Any]]]:
    """``{sample_token: [box, ...]}`` of tracker output (see the module docstring).

    Parameters
    ----------
    results : per scene, the frames (for their sample tokens) and the tracker output.
    coasting_score : score of coasting boxes (status COASTING without a detection); None keeps
        the track's score (offline mode, whose interpolated boxes carry the track score).
    max_boxes_per_sample : keep the best-scoring boxes per sample.

    Raises
    ------
    InputError when a frame has no sample token (not a nuScenes conversion).
    """
    out: dict[str, list[dict[str, Any]]] = {}
    for scene, (frames, outputs) in results.items():
        token_of = {f.frame_id: f.sample_token for f in frames}
        for output in outputs:
            token = token_of.get(output.frame_id)
            if token is None:
                raise InputError(
                    f"scene {scene!r} frame {output.frame_id}: no nuScenes sample token "
                    "(convert the input with `mctrack convert nuscenes`)"
                )
            out[token] = _sample_boxes(scene, token, output, coasting_score, max_boxes_per_sample)
    return out


def _sample_boxes(
    scene: str,
    token: str,
    output: TrackOutput,
    coasting_score: float | None,
    max_boxes: int,
) -> list[dict[str, Any]]:
    b = output.boxes
    names = [CATEGORIES[c] for c in b.category]
    keep = np.array([n in TRACKING_NAMES for n in names], dtype=bool)
    score = b.score.copy()
    if coasting_score is not None:
        coasting = (output.status == TrackStatus.COASTING) & (output.det_row < 0)
        score[coasting] = coasting_score
    rows = np.flatnonzero(keep & np.isfinite(score))
    rows = rows[np.argsort(-score[rows], kind="stable")][:max_boxes]
    quats = yaw_to_quaternion_wxyz(b.yaw[rows])
    boxes = []
    for k, i in enumerate(rows):
        length, width, height = (float(v) for v in b.lwh[i])
        boxes.append(
            {
                "sample_token": token,
                "translation": [float(v) for v in b.xyz[i]],
                "size": [width, length, height],
                "rotation": [float(v) for v in quats[k]],
                "velocity": [float(v) if np.isfinite(v) else 0.0 for v in b.velocity[i]],
                "tracking_id": f"{scene}_{int(b.track_id[i])}",
                "tracking_name": names[i],
                "tracking_score": float(score[i]),
            }
        )
    return boxes


def write_nuscenes_results(
    path: str | Path,
    results: Mapping[str, tuple[Sequence[Frame], Sequence[TrackOutput]]],
    *,
    meta: Mapping[str, Any] | None = None,
    coasting_score: float | None = 0.0,
    max_boxes_per_sample: int = MAX_BOXES_PER_SAMPLE,
) -> int:
    """Write the tracking submission atomically; returns the number of boxes written.

    ``meta`` are the modality flags (the detection file's ``meta``; :data:`DEFAULT_META` when
    None or incomplete).
    """
    per_sample = nuscenes_results(
        results, coasting_score=coasting_score, max_boxes_per_sample=max_boxes_per_sample
    )
    write_json_atomic(Path(path), {"meta": _meta_flags(meta), "results": per_sample})
    return sum(len(v) for v in per_sample.values())


def _meta_flags(meta: Mapping[str, Any] | None) -> dict[str, bool]:
    return {**DEFAULT_META, **{k: bool(v) for k, v in (meta or {}).items() if k in DEFAULT_META}}


def write_nuscenes_parts(
    path: str | Path, parts: Iterable[Path], *, meta: Mapping[str, Any] | None = None
) -> None:
    """Assemble the submission from per-scene parts, in order (a scene-parallel run).

    Each part is one scene's compact ``{sample_token: [box, ...]}`` object
    (:func:`nuscenes_results` of that scene); the bytes equal :func:`write_nuscenes_results`'s
    for the same scenes, since sample tokens are unique across scenes.
    """

    def chunks() -> Iterator[bytes]:
        yield b'{"meta":' + compact_json(_meta_flags(meta)) + b',"results":{'
        first = True
        for part in parts:
            body = part.read_bytes()[1:-1]  # the object's members, without its braces
            if body:
                yield body if first else b"," + body
                first = False
        yield b"}}"

    write_bytes_atomic(Path(path), chunks())
