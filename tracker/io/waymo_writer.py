"""Waymo result writer: per-segment ``.npz`` files in the ImmortalTracker / MCTrack convention.

Layout: ``OUT/{vehicle,pedestrian,cyclist}/<segment>.npz``, each with

* ``ids``: per frame, the list of integer track ids;
* ``bboxes``: per frame, the list of ``[x, y, z, heading, l, w, h, score]`` rows in the **world**
  frame (filtered position, size and heading; the score of the track's last detection);
* ``states``: per frame, the list of track states (``"confirmed"`` / ``"coasting"``);
* ``velos``: per frame, the list of filtered world ``[vx, vy]`` (m/s);
* ``timestamps``: (F,) frame timestamps in µs.

Frames without a track keep an empty list, so every segment file has one entry per frame of
``ts_info``. These ragged per-frame lists are pickled object arrays, exactly what the reference's
``pred_bin.py`` (from ImmortalTracker) reads: it turns these files into the ``pred.bin`` protobuf
of the Waymo tracking benchmark (moving each box back to the vehicle frame with ``ego_info``).
That step needs TensorFlow and the ``waymo-open-dataset`` package, which this project does not
depend on (docs/nuscenes_waymo.md).

The same boxes are also stored without pickle, one row per box: ``frame_index`` (N,),
``box_ids`` (N,), ``box_bboxes`` (N, 8), ``box_states`` (N,) and ``box_velos`` (N, 2).
:func:`read_waymo_results` reads only these (``allow_pickle=False``); the pickled members are
for ``pred_bin.py`` and never loaded here.
"""

from __future__ import annotations

import io
import itertools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Final

import numpy as np

from tracker.categories import CATEGORIES
from tracker.errors import InputError
from tracker.events import TrackOutput, TrackStatus
from tracker.frame import Frame
from tracker.io.fileio import load_npz, path_in, write_bytes_atomic

#: Our category → the Waymo result folder (the benchmark's object types).
WAYMO_RESULT_DIRS: Final[dict[str, str]] = {
    "car": "vehicle",
    "pedestrian": "pedestrian",
    "cyclist": "cyclist",
    "bicycle": "cyclist",  # the reference's name for Waymo cyclists
}
RESULT_TYPES: Final[tuple[str, ...]] = ("vehicle", "pedestrian", "cyclist")


def _ragged(items: list[np.ndarray | list[object]]) -> np.ndarray:
    """A 1-D object array whose elements are the per-frame items (never broadcast)."""
    out = np.empty(len(items), dtype=object)
    for i, item in enumerate(items):
        out[i] = item
    return out


def write_waymo_results(
    out_dir: str | Path,
    results: Mapping[str, tuple[Sequence[Frame], Sequence[TrackOutput]]],
) -> dict[str, int]:
    """Write ``OUT/<type>/<segment>.npz`` for every segment; returns boxes written per type."""
    out_dir = Path(out_dir)
    written = dict.fromkeys(RESULT_TYPES, 0)
    for segment, (frames, outputs) in results.items():
        by_frame = {o.frame_id: o for o in outputs}
        timestamps = np.array([round(f.timestamp_secs * 1e6) for f in frames], dtype=np.int64)
        for result_type in RESULT_TYPES:
            ids, bboxes, states, velos = [], [], [], []
            frame_index: list[int] = []
            for f, frame in enumerate(frames):
                output = by_frame.get(frame.frame_id)
                if output is None:
                    ids.append([])
                    bboxes.append(np.zeros((0, 8)))
                    states.append([])
                    velos.append(np.zeros((0, 2)))
                    continue
                b = output.boxes
                rows = np.flatnonzero(
                    [WAYMO_RESULT_DIRS.get(CATEGORIES[c]) == result_type for c in b.category]
                )
                ids.append([int(t) for t in b.track_id[rows]])
                bboxes.append(
                    np.column_stack([b.xyz[rows], b.yaw[rows], b.lwh[rows], b.score[rows]]).reshape(
                        -1, 8
                    )
                )
                states.append(
                    [
                        "coasting" if s == TrackStatus.COASTING else "confirmed"
                        for s in output.status[rows]
                    ]
                )
                velos.append(b.velocity[rows].reshape(-1, 2))
                frame_index += [f] * len(rows)
                written[result_type] += len(rows)
            buffer = io.BytesIO()
            np.savez_compressed(
                buffer,
                ids=_ragged(ids),
                bboxes=_ragged(bboxes),
                states=_ragged(states),
                velos=_ragged(velos),
                timestamps=timestamps,
                frame_index=np.array(frame_index, dtype=np.int64),
                box_ids=np.array([i for row in ids for i in row], dtype=np.int64),
                box_bboxes=np.concatenate(bboxes).reshape(-1, 8),
                box_states=np.array([s for row in states for s in row], dtype="<U9"),
                box_velos=np.concatenate(velos).reshape(-1, 2),
            )
            path = path_in(out_dir / result_type, segment, ".npz")  # names are input data
            write_bytes_atomic(path, buffer.getvalue())
    return written


#: The pickle-free members of a result file (the only ones read back).
FLAT_MEMBERS: Final[tuple[str, ...]] = (
    "timestamps",
    "frame_index",
    "box_ids",
    "box_bboxes",
    "box_states",
    "box_velos",
)


def read_waymo_results(path: str | Path) -> tuple[list[list[int]], list[np.ndarray]]:
    """``(ids, bboxes)`` per frame of one result file (rows ``[x, y, z, o, l, w, h, s]``), from
    its pickle-free members (``allow_pickle=False``; the pickled ones are never touched)."""
    path = Path(path)
    npz = load_npz(path, "Waymo result", members=FLAT_MEMBERS)
    missing = [k for k in ("timestamps", "frame_index", "box_ids", "box_bboxes") if k not in npz]
    if missing:
        raise InputError(f"{path}: not a result file of this writer (no {', '.join(missing)})")
    n_frames, frame = len(npz["timestamps"]), npz["frame_index"]
    box_ids, box_bboxes = npz["box_ids"], npz["box_bboxes"].reshape(-1, 8)
    if not (len(frame) == len(box_ids) == len(box_bboxes)) or (
        len(frame) and (frame.min() < 0 or frame.max() >= n_frames)
    ):
        raise InputError(f"{path}: frame_index, box_ids and box_bboxes do not agree")
    bounds = np.searchsorted(frame, np.arange(n_frames + 1))  # written in frame order
    ids = [box_ids[a:b].astype(int).tolist() for a, b in itertools.pairwise(bounds)]
    bboxes = [box_bboxes[a:b].astype(np.float64) for a, b in itertools.pairwise(bounds)]
    return ids, bboxes
