"""Per-frame rows buffered per entity and sent with ``send_columns``: the observer's fast path.

Measured on this project's 2-core machine (rerun-sdk 0.41): one ``rec.log`` of a 20-box
Boxes3D costs ~0.6-0.8 ms, a tiny Points3D ~0.2 ms, almost all of it per call; the same boxes
sent as 64 frames in one ``send_columns`` cost ~0.07 ms per frame. A debug recording logs ~25
entities per frame, so per-frame logging would be ~15 ms per frame and buffering is ~1-2 ms.

Rows are flushed after ``max_rows`` frames or ``max_secs`` seconds (whichever comes first), so
memory stays flat and a live viewer lags by at most a fraction of a second.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr

from viz import paths

#: What a deferred builder returns for a list of row payloads: per-instance fields (already
#: concatenated over the rows), the number of instances of each row, and one-per-row fields.
Built = tuple[dict[str, Any], Any, dict[str, list[Any]]]


@dataclass
class _Rows:
    archetype: Any
    build: Callable[[list[Any]], Built] | None = None
    frames: list[int] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    fields: dict[str, list[Any]] = field(default_factory=dict)  # per-instance values
    mono: dict[str, list[Any]] = field(default_factory=dict)  # one value per row
    payloads: list[Any] = field(default_factory=list)  # deferred rows


class ColumnBuffer:
    """Collects rows ``(entity, archetype) -> [(frame, time, instances)]`` and sends columns.

    Rows are either eager (:meth:`add`: the fields are ready) or deferred (:meth:`add_deferred`:
    a payload of references, turned into fields for all buffered rows at once at flush time,
    which vectorises the per-frame numpy work across frames). Every row of one (entity,
    archetype) is of one kind and carries the same field names.
    """

    def __init__(
        self,
        rec: rr.RecordingStream,
        *,
        max_rows: int = 256,
        max_secs: float = 2.0,
        before_flush: Callable[[], None] | None = None,
    ) -> None:
        self.rec = rec
        #: called first by every flush (the owner adds rows it builds per buffer)
        self.before_flush = before_flush
        self.max_rows = max_rows
        self.max_secs = max_secs
        self._rows: dict[tuple[str, str], _Rows] = {}
        self._count = 0
        self._last_flush = time.perf_counter()
        self._last_index: tuple[Any, list[rr.TimeColumn]] | None = None

    def _entity(self, path: str, archetype: Any, build: Any = None) -> _Rows:
        key = (path, archetype.__name__)
        rows = self._rows.get(key)
        if rows is None:
            rows = self._rows[key] = _Rows(archetype, build)
        return rows

    def add(
        self,
        path: str,
        archetype: Any,
        frame_id: int,
        time_secs: float,
        n: int,
        mono: dict[str, Any] | None = None,
        **instances: Any,
    ) -> None:
        """One row: ``n`` instances (each field has ``n`` entries along axis 0), plus ``mono``
        components that have exactly one value per row (``show_labels``, an image, a Clear)."""
        rows = self._entity(path, archetype)
        rows.frames.append(frame_id)
        rows.times.append(time_secs)
        rows.lengths.append(n)
        for name, value in instances.items():
            rows.fields.setdefault(name, []).append(value)
        for name, value in (mono or {}).items():
            rows.mono.setdefault(name, []).append(value)

    def add_deferred(
        self,
        path: str,
        archetype: Any,
        frame_id: int,
        time_secs: float,
        payload: Any,
        build: Callable[[list[Any]], Built],
    ) -> None:
        """One row described by ``payload``; ``build(payloads)`` makes the fields at flush."""
        rows = self._entity(path, archetype, build)
        rows.frames.append(frame_id)
        rows.times.append(time_secs)
        rows.payloads.append(payload)

    def end_frame(self) -> None:
        """Call once per frame: flushes when enough rows or time accumulated."""
        self._count += 1
        now = time.perf_counter()
        if self._count >= self.max_rows or now - self._last_flush >= self.max_secs:
            self.flush()

    def flush(self) -> None:
        if self.before_flush is not None:
            self.before_flush()
        for (path, _), rows in self._rows.items():
            if not rows.frames:
                continue
            if rows.build is not None:
                fields, lengths, mono = rows.build(rows.payloads)
            else:
                fields = {name: _concat(values) for name, values in rows.fields.items()}
                lengths, mono = rows.lengths, rows.mono
            self._send(path, rows.archetype, rows.frames, rows.times, fields, lengths, mono)
        self._rows.clear()
        self._count = 0
        self._last_flush = time.perf_counter()

    def _send(
        self,
        path: str,
        archetype: Any,
        frames: list[int],
        times: list[float],
        fields: dict[str, Any],
        lengths: Any,
        mono: dict[str, list[Any]],
    ) -> None:
        # most entities have a row every frame: the same index columns
        if self._last_index is not None and self._last_index[0] == (frames, times):
            indexes = self._last_index[1]
        else:
            indexes = time_columns(np.asarray(frames), np.asarray(times, dtype=np.float64))
            self._last_index = ((frames, times), indexes)
        lengths = np.asarray(lengths, dtype=np.int64)
        columns: list[Any] = []
        fields = dict(fields)
        strips = fields.pop("strips", None)
        if strips is not None:
            # line strips by hand: Rerun's converter loops in Python over every strip
            desc = archetype.descriptor_strips()
            batch = _ArrowBatch(_strips_array(strips), desc)
            columns.append(rr.ComponentColumn(desc, batch, lengths=lengths))
        if fields:
            columns += list(archetype.columns(**fields).partition(lengths))
        if mono and archetype is rr.Image:
            columns += _image_columns(mono)
        elif mono:
            columns += list(archetype.columns(**mono))
        self.rec.send_columns(path, indexes=indexes, columns=columns)


class _ArrowBatch:
    """A ready arrow array posing as a component batch (for ``rr.ComponentColumn``)."""

    def __init__(self, array: pa.Array, descriptor: Any) -> None:
        self.array, self.descriptor = array, descriptor

    def as_arrow_array(self) -> pa.Array:
        return self.array

    def component_descriptor(self) -> Any:
        return self.descriptor


def arrow_column(descriptor: Any, array: pa.Array) -> rr.ComponentColumn:
    """A ready arrow array (one instance per row) as a ``send_columns`` column."""
    return rr.ComponentColumn(descriptor, _ArrowBatch(array, descriptor))


_IMAGE_TEMPLATE: list[pa.Array] = []


def _rgb8_template() -> tuple[pa.Array, pa.Array]:
    """Rerun's own arrow of one RGB/U8 image buffer and format (types and enum codes)."""
    if not _IMAGE_TEMPLATE:
        fmt = rr.components.ImageFormat(width=1, height=1, color_model="RGB", channel_datatype="U8")
        _IMAGE_TEMPLATE[:] = [
            rr.components.ImageBufferBatch(b"abc").as_arrow_array(),
            rr.components.ImageFormatBatch(fmt).as_arrow_array(),
        ]
    return _IMAGE_TEMPLATE[0], _IMAGE_TEMPLATE[1]


def _image_columns(mono: dict[str, list[Any]]) -> list[rr.ComponentColumn]:
    """RGB8 image rows by hand, one buffer and format per row: ``Image.columns`` cannot batch
    buffers of different sizes (0.41), and Rerun's converters cost ~0.1 ms per image.
    ``mono["buffer"]``: one (bytes of all rows, end offset of each row) pair;
    ``mono["format"]``: (width, height) per row."""
    buffer_tmpl, format_tmpl = _rgb8_template()
    (data, ends) = mono["buffer"][0]
    offsets = np.concatenate([[0], np.asarray(ends, dtype=np.int64)]).astype(np.int32)
    buffers = pa.ListArray.from_arrays(
        pa.array(offsets, pa.int32()), pa.array(data, pa.uint8()), type=buffer_tmpl.type
    )
    size = np.array(mono["format"], dtype=np.uint32).reshape(-1, 2)
    rows = len(size)
    codes = [format_tmpl.field(i)[0] for i in range(2, 5)]  # pixel format, colour model, type
    formats = pa.StructArray.from_arrays(
        [pa.array(size[:, 0], pa.uint32()), pa.array(size[:, 1], pa.uint32())]
        + [pa.array([c.as_py()] * rows, c.type) for c in codes],
        fields=list(format_tmpl.type),
    )
    return [
        rr.ComponentColumn(desc, _ArrowBatch(array, desc))
        for desc, array in (
            (rr.Image.descriptor_buffer(), buffers),
            (rr.Image.descriptor_format(), formats),
        )
    ]


def _strips_array(strips: Any) -> pa.Array:
    """``list<fixed_size_list<float32, D>>`` from an (S, P, D) array (S strips of P points), a
    list of (P_i, D) arrays, or a tuple (points (N, D), points per strip (S,))."""
    if isinstance(strips, tuple):
        flat, counts = np.asarray(strips[0], np.float32), np.asarray(strips[1], np.int64)
        dim = flat.shape[-1]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    elif isinstance(strips, np.ndarray):
        s, p, dim = strips.shape
        flat = strips.reshape(-1, dim).astype(np.float32)
        offsets = np.arange(0, s * p + 1, p, dtype=np.int32) if p else np.zeros(s + 1, np.int32)
    else:
        dim = next((q.shape[-1] for q in strips if len(q)), 3)
        counts = np.array([len(q) for q in strips], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        flat = (
            np.concatenate([np.asarray(q, np.float32).reshape(-1, dim) for q in strips])
            if len(strips)
            else np.zeros((0, dim), np.float32)
        )
    # Rerun only visualises the exact physical type: non-nullable items at both levels
    point_type = pa.list_(pa.field("item", pa.float32(), nullable=False), dim)
    values = pa.FixedSizeListArray.from_arrays(
        pa.array(flat.ravel(), type=pa.float32()), type=point_type
    )
    strip_type = pa.list_(pa.field("item", point_type, nullable=False))
    return pa.ListArray.from_arrays(pa.array(offsets, type=pa.int32()), values, type=strip_type)


def _concat(values: list[Any]) -> Any:
    if isinstance(values[0], np.ndarray):
        return np.concatenate(values)
    out: list[Any] = []
    for v in values:
        out.extend(v)
    return out


def pair_key(a: Any, b: Any) -> Any:
    """One int64 per pair of int32 values, ordered as the pairs are (``a`` first)."""
    return (np.asarray(a, dtype=np.int64) << 32) + (np.asarray(b, dtype=np.int64) + 2**31)


def time_columns(frame_ids: np.ndarray, times_secs: np.ndarray) -> list[rr.TimeColumn]:
    """The ``frame`` and ``time`` index columns (``time`` as in :func:`time_kind`)."""
    frame_col = rr.TimeColumn(paths.FRAME, sequence=np.asarray(frame_ids, dtype=np.int64))
    finite = np.isfinite(times_secs)
    if not finite.all():
        return [frame_col]
    if time_kind(times_secs) == "timestamp":
        return [frame_col, rr.TimeColumn(paths.TIME, timestamp=times_secs)]
    return [frame_col, rr.TimeColumn(paths.TIME, duration=times_secs)]


def time_kind(times_secs: Any) -> str:
    """Small times are durations since the scene start (KITTI: frame / 10 Hz); epoch-sized ones
    (nuScenes, Waymo) are timestamps, which the viewer shows as dates."""
    t = np.asarray(times_secs, dtype=np.float64)
    return "timestamp" if t.size and np.nanmax(t) > 1e8 else "duration"


def set_frame_time(rec: rr.RecordingStream, frame_id: int, time_secs: float) -> None:
    """Both timelines for the following ``rec.log`` calls."""
    rec.set_time(paths.FRAME, sequence=int(frame_id))
    if np.isfinite(time_secs):
        if time_kind(time_secs) == "timestamp":
            rec.set_time(paths.TIME, timestamp=float(time_secs))
        else:
            rec.set_time(paths.TIME, duration=float(time_secs))


class SeriesColumns:
    """Scalar series of many entities, sent as one record batch per group of entities.

    The rows of all groups are given together, grouped (``starts`` / ``counts``: the rows of each
    group, e.g. a track); every arrow array is built once over all rows, and each group's
    entities (e.g. the track's speed, velocity and heading curves, which share its rows) go
    into one record batch of zero-copy slices, which Rerun splits into one chunk per entity.
    One ``send_columns`` per curve cost ~0.2-0.3 ms each (~1,100 curves on a KITTI sequence
    with GT), almost all of it per call.
    """

    def __init__(self, frame_ids: Any, times_secs: Any, starts: Any, counts: Any) -> None:
        frames = np.asarray(frame_ids, dtype=np.int64)
        times = np.asarray(times_secs, dtype=np.float64)
        self.starts = np.asarray(starts, dtype=np.int64)
        self.counts = np.asarray(counts, dtype=np.int64)
        self._frame = pa.array(frames, pa.int64())
        # a group gets the time timeline when all its times are finite (as time_columns)
        finite = np.isfinite(times)
        bad = np.r_[0, np.cumsum(~finite)]
        self._timed = bad[self.starts + self.counts] == bad[self.starts]
        self._time: pa.Array | None = None
        if self._timed.any():
            t = np.where(finite, times, 0.0)
            if time_kind(times[finite]) == "timestamp":
                self._time = rr.TimeColumn(paths.TIME, timestamp=t).times
            else:
                self._time = rr.TimeColumn(paths.TIME, duration=t).times
        self._chunks: list[Any] = []

    def add_group(self, k: int, entities: list[tuple[str, list[tuple[Any, pa.Array]]]]) -> None:
        """Group ``k``'s entities: (path, [(descriptor, one-list-per-row array over all rows)])
        (see :func:`unit_lists`)."""
        from rerun.chunk import Chunk

        a, n = int(self.starts[k]), int(self.counts[k])
        fields = [pa.field(paths.FRAME, pa.int64())]
        arrays = [self._frame.slice(a, n)]
        index = [paths.FRAME]
        if self._timed[k] and self._time is not None:
            fields.append(pa.field(paths.TIME, self._time.type))
            arrays.append(self._time.slice(a, n))
            index.append(paths.TIME)
        for path, columns in entities:
            entity = paths.entity(path)
            for desc, array in columns:
                meta = {
                    b"rerun:entity_path": entity.encode(),
                    b"rerun:archetype": (desc.archetype or "").encode(),
                    b"rerun:component": desc.component.encode(),
                    b"rerun:component_type": (desc.component_type or "").encode(),
                }
                fields.append(pa.field(f"{entity}:{desc.component}", array.type, metadata=meta))
                arrays.append(array.slice(a, n))
        batch = pa.RecordBatch.from_arrays(arrays, schema=pa.schema(fields))
        self._chunks += Chunk.from_record_batch(batch, index=index)

    def send(self, rec: rr.RecordingStream) -> None:
        """Send every group added so far (one call)."""
        if self._chunks:
            rr.send_chunks(self._chunks, recording=rec)
        self._chunks = []


def unit_lists(values: Any, type_: pa.DataType | None = None) -> pa.Array:
    """``values`` (numpy, list or arrow) as one single-value list per row."""
    array = values if isinstance(values, pa.Array) else pa.array(values, type=type_)
    offsets = pa.array(np.arange(len(array) + 1, dtype=np.int32))
    return pa.ListArray.from_arrays(offsets, array)


class StaticEntities:
    """Static archetypes of many entities, sent as one record batch in one call.

    ``rec.log(..., static=True)`` costs ~1-2 ms per call on a recording with a file sink, most
    of it per call (a KITTI sequence's ID events log three static entities each). Here each
    archetype's component batches become one-row columns of one batch, which Rerun splits into
    one static chunk per entity, the chunks ``rec.log`` would have made."""

    def __init__(self) -> None:
        self._fields: list[pa.Field] = []
        self._arrays: list[pa.Array] = []

    def add(self, path: str, archetype: Any) -> None:
        entity = paths.entity(path)
        for batch in archetype.as_component_batches():
            desc, array = batch.component_descriptor(), batch.as_arrow_array()
            row = pa.ListArray.from_arrays(pa.array([0, len(array)], pa.int32()), array)
            meta = {
                b"rerun:entity_path": entity.encode(),
                b"rerun:archetype": (desc.archetype or "").encode(),
                b"rerun:component": desc.component.encode(),
                b"rerun:component_type": (desc.component_type or "").encode(),
            }
            self._fields.append(pa.field(f"{entity}:{desc.component}", row.type, metadata=meta))
            self._arrays.append(row)

    def send(self, rec: rr.RecordingStream) -> None:
        from rerun.chunk import Chunk

        if self._arrays:
            batch = pa.RecordBatch.from_arrays(self._arrays, schema=pa.schema(self._fields))
            rr.send_chunks(Chunk.from_record_batch(batch, index=None), recording=rec)
        self._fields, self._arrays = [], []
