"""Headless screenshots of a recording's key views at its most interesting frames.

Where to look is read from the recording itself (the static ``summary/index`` written by
:func:`viz.record.record_scene`), so this works on any recording made by this project. The
viewer is Rerun's headless native viewer driven by ``rerun.experimental.ViewerClient``; without
a GPU it needs a software Vulkan driver (Mesa lavapipe, Debian/Ubuntu package
``mesa-vulkan-drivers``), without which the viewer cannot start at all.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import glob
import logging
import os
import re
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tracker.io.fileio import work_folder
from viz import layout, paths
from viz.rerun_process import running_viewer_client

if TYPE_CHECKING:
    from rerun.chunk import RrdReader

LOG = logging.getLogger("mctrack.shots")

INSTALL_HINT = "apt-get install -y mesa-vulkan-drivers libvulkan1"
_ICD_GLOBS = (
    "/usr/share/vulkan/icd.d/*.json",
    "/etc/vulkan/icd.d/*.json",
    "/usr/local/share/vulkan/icd.d/*.json",
)


class RendererMissing(RuntimeError):
    """No Vulkan driver: the headless viewer cannot render."""


@dataclass(frozen=True)
class ShotIndex:
    """What ``summary/index`` says about a recording (empty lists when absent).

    ``event_*`` lists are per ID event (both kinds) in the summary's ``#K`` order."""

    id_switch_frames: list[int] = field(default_factory=list)
    id_switch_old_track_ids: list[int] = field(default_factory=list)
    id_switch_new_track_ids: list[int] = field(default_factory=list)
    fragmentation_frames: list[int] = field(default_factory=list)
    lag_frame: int | None = None
    lag_track_id: int | None = None
    event_frames: list[int] = field(default_factory=list)
    event_kinds: list[int] = field(default_factory=list)  # 0 ID switch, 1 fragmentation
    event_gt_ids: list[int] = field(default_factory=list)
    event_old_track_ids: list[int] = field(default_factory=list)
    event_new_track_ids: list[int] = field(default_factory=list)
    event_causes: list[str] = field(default_factory=list)
    event_xyz_m: list[tuple[float, float, float]] = field(default_factory=list)
    event_shot_frames: list[int] = field(default_factory=list)
    image_frames: list[int] = field(default_factory=list)

    def event_reason(self, k: int) -> str:
        return "fragmentation" if self.event_kinds[k] else "id_switch"


@dataclass(frozen=True)
class PlannedShot:
    frame: int
    reason: str  # "id_switch", "fragmentation", "lag" or "frame"
    event: int | None = None  # the event's #K: its focused layout is shown


@dataclass(frozen=True)
class Shot:
    path: Path
    frame: int
    reason: str
    view: str  # view name, or "viewer" for the whole window
    event: int | None = None


def renderer_available() -> tuple[bool, str]:
    """Is a Vulkan loader and a driver (lavapipe or a GPU's) installed? And if not, why."""
    if ctypes.util.find_library("vulkan") is None:
        return False, f"the Vulkan loader (libvulkan) is not installed ({INSTALL_HINT})"
    env = os.environ.get("VK_ICD_FILENAMES") or os.environ.get("VK_DRIVER_FILES")
    if env:  # the loader then looks nowhere else
        icds = [p for p in env.split(os.pathsep) if os.path.isfile(p)]
    else:
        icds = [p for pattern in _ICD_GLOBS for p in glob.glob(pattern)]
    if not icds:
        return False, f"no Vulkan driver (ICD) is installed ({INSTALL_HINT})"
    return True, ", ".join(sorted(os.path.basename(p) for p in icds))


def open_recording(recording: str | Path) -> RrdReader:
    """An ``RrdReader`` of ``recording``. Rerun's RerunWarning on a file without a footer
    (cut short, or by an older Rerun; read by a whole-file scan, or refused next as unreadable)
    goes to the debug log: the user saw a Python warning block before the one-line error."""
    from rerun.chunk import RrdReader
    from rerun.error_utils import RerunWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = RrdReader(str(recording))
    for warning in caught:
        if issubclass(warning.category, RerunWarning):
            LOG.debug("%s: %s", recording, warning.message)
        else:  # (not ours to hide)
            warnings.warn_explicit(
                warning.message, warning.category, warning.filename, warning.lineno
            )
    return reader


def read_shot_index(recording: str | Path) -> ShotIndex:
    """The static ``summary/index`` of a recording."""
    chunks = (
        open_recording(recording)
        .stream()
        .filter(content=paths.entity(paths.SHOT_INDEX), is_static=True)
        .to_chunks()
    )
    values: dict[str, list[Any]] = {}
    for chunk in chunks:
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            column = batch.column(name).to_pylist()
            if column and isinstance(column[-1], list):
                values[name.split(":")[-1]] = column[-1]

    def ints(key: str) -> list[int]:
        return [int(v) for v in values.get(key, [])]

    from tracker.eval.id_causes import Cause

    causes = list(Cause)
    lag_frame, lag_track = ints("lag_frame"), ints("lag_track_id")
    xyz = [float(v) for v in values.get("event_xyz_m", [])]
    return ShotIndex(
        id_switch_frames=ints("id_switch_frames"),
        id_switch_old_track_ids=ints("id_switch_old_track_ids"),
        id_switch_new_track_ids=ints("id_switch_new_track_ids"),
        fragmentation_frames=ints("fragmentation_frames"),
        lag_frame=lag_frame[0] if lag_frame else None,
        lag_track_id=lag_track[0] if lag_track else None,
        event_frames=ints("event_frames"),
        event_kinds=ints("event_kinds"),
        event_gt_ids=ints("event_gt_ids"),
        event_old_track_ids=ints("event_old_track_ids"),
        event_new_track_ids=ints("event_new_track_ids"),
        event_causes=[causes[c].value for c in ints("event_causes")],
        event_xyz_m=[(xyz[i], xyz[i + 1], xyz[i + 2]) for i in range(0, len(xyz) - 2, 3)],
        event_shot_frames=ints("event_shot_frames"),
        image_frames=ints("image_frames"),
    )


#: The recording's name as :func:`viz.record.new_recording` sends it: this + the scene.
RECORDING_NAME_PREFIX = "MCTrack "


def read_scene_name(recording: str | Path) -> str | None:
    """The scene (sequence) a recording is of, from its recording name (None: no name)."""
    chunks = (
        open_recording(recording)
        .stream()
        .filter(content="/__properties/**", is_static=True)
        .to_chunks()
    )
    for chunk in chunks:
        batch = chunk.to_record_batch()
        if "RecordingInfo:name" in batch.schema.names:
            names = [v for row in batch.column("RecordingInfo:name").to_pylist() for v in row or []]
            if names:
                return str(names[-1]).removeprefix(RECORDING_NAME_PREFIX)
    return None


def read_frame_range(recording: str | Path) -> tuple[int, int] | None:
    """The first and last frame id on the recording's ``frame`` timeline (None: no frames).

    Read from the temporal chunks' time columns (~0.1 s for the whole 447-frame sample)."""
    chunks = (
        open_recording(recording)
        .stream()
        .filter(is_static=False, has_timeline=paths.FRAME)
        .to_chunks()
    )
    ids = [
        v
        for chunk in chunks
        for v in chunk.to_record_batch().column(paths.FRAME).to_pylist()
        if v is not None
    ]
    return (int(min(ids)), int(max(ids))) if ids else None


#: ``--frame F`` moves to a frame with a camera image at most this many frames away.
IMAGE_SEARCH_FRAMES = 3


def plan_shots(
    index: ShotIndex,
    *,
    max_events: int = 3,
    events: Sequence[int] | str | None = None,
    frame: int | None = None,
) -> list[PlannedShot]:
    """What to capture.

    * ``frame``: that frame (or the nearest one with a camera image within
      :data:`IMAGE_SEARCH_FRAMES`), in the default layout.
    * ``events``: the given event numbers (``#K`` of the summary), or ``"all"``; each in its
      focused layout at its picture frame (the event's own, or a nearby one with an image).
    * neither: the first ``max_events`` ID switches (the first fragmentations when there are
      none), focused, and the largest velocity lag.
    """
    if frame is not None:
        return [PlannedShot(_near_image(frame, index.image_frames), "frame")]
    n = len(index.event_frames)
    if events == "all":
        chosen = list(range(n))
    elif events is not None:
        chosen = [int(k) for k in events]  # type: ignore[union-attr]
        bad = [k for k in chosen if not 0 <= k < n]
        if bad:
            raise IndexError(f"no event {bad[0]}: the recording has events #0..#{n - 1}")
    else:
        switches = [k for k in range(n) if index.event_kinds[k] == 0]
        frags = [k for k in range(n) if index.event_kinds[k] == 1]
        chosen = (switches or frags)[:max_events]
    shot_frames = index.event_shot_frames or index.event_frames
    plan = [PlannedShot(shot_frames[k], index.event_reason(k), k) for k in chosen]
    if events is None and index.lag_frame is not None:
        plan.append(PlannedShot(index.lag_frame, "lag"))
    return plan


def _near_image(frame: int, image_frames: Sequence[int]) -> int:
    near = [f for f in image_frames if abs(f - frame) <= IMAGE_SEARCH_FRAMES]
    return min(near, key=lambda f: (abs(f - frame), f)) if near else frame


#: Views captured per kind of shot (by name prefix, see :mod:`viz.layout`).
VIEWS_BY_REASON: dict[str, tuple[str, ...]] = {
    "id_switch": (layout.VIEW_BEV, layout.VIEW_CAMERA, layout.VIEW_COST_BEV, layout.VIEW_ID_EVENTS),
    "fragmentation": (
        layout.VIEW_BEV,
        layout.VIEW_CAMERA,
        layout.VIEW_COST_BEV,
        layout.VIEW_ID_EVENTS,
    ),
    "lag": (layout.VIEW_SPEED_LAG, layout.VIEW_BEV),
    "frame": (layout.VIEW_BEV, layout.VIEW_CAMERA, layout.VIEW_COST_BEV),
}
#: Views captured of an event in its focused layout.
FOCUS_VIEWS = (layout.VIEW_FOCUS, layout.VIEW_EXPLAIN, layout.VIEW_CAMERA, layout.VIEW_COST_BEV)


@contextlib.contextmanager
def headless_viewer() -> Iterator[Any]:
    """A headless native Rerun viewer (``ViewerClient``) on a free port of 127.0.0.1, with a
    private $HOME; closed on exit."""
    with _private_home(), running_viewer_client(headless=True) as client:
        yield client


@contextlib.contextmanager
def _private_home() -> Iterator[None]:
    """The viewer and Mesa write state under $HOME; keep screenshots reproducible and the
    user's home untouched. The viewer logs at warning level unless $RUST_LOG says otherwise:
    its INFO lines (gRPC address, "Connect by running rerun --connect ...", every temporary
    file it loads) are noise under mctrack shots' own output."""
    keys = (
        "HOME",
        "XDG_DATA_HOME",
        "XDG_CONFIG_HOME",
        "XDG_CACHE_HOME",
        "XDG_RUNTIME_DIR",
        "RERUN_ANALYTICS",
        "RUST_LOG",
    )
    saved = {k: os.environ.get(k) for k in keys}
    with work_folder("viewer") as home:
        os.environ.update(
            HOME=str(home),
            XDG_DATA_HOME=f"{home}/data",
            XDG_CONFIG_HOME=f"{home}/config",
            XDG_CACHE_HOME=f"{home}/cache",
            XDG_RUNTIME_DIR=str(home),
            RERUN_ANALYTICS="false",
            RUST_LOG=saved["RUST_LOG"] or "warn",
        )
        try:
            yield
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


def take_shots(
    recording: str | Path,
    out_dir: str | Path,
    *,
    plan: Sequence[PlannedShot | tuple[int, str]] | None = None,
    max_events: int = 3,
    settle_secs: float = 2.0,
    full_viewer: bool = True,
    views: Sequence[str] | None = None,
    timeout_secs: float = 120.0,
) -> list[Shot]:
    """Screenshots (PNG) of the key views at the planned frames.

    Parameters
    ----------
    recording : an ``.rrd`` written by :func:`viz.record.record_scene`.
    out_dir : created if needed; files are ``<reason>_f<frame>_<view>.png``, and
        ``event<K>_f<frame>_<view>.png`` for an event in its focused layout.
    plan : what to capture; default :func:`plan_shots` of the recording's index.
    settle_secs : wait after moving the time cursor: the viewer loads chunks on demand.
    full_viewer : also capture the whole window at each frame.
    views : view-name prefixes to capture (default: :data:`VIEWS_BY_REASON`, or
        :data:`FOCUS_VIEWS` for an event).

    Raises
    ------
    RendererMissing when no Vulkan driver is installed.
    """
    ok, why = renderer_available()
    if not ok:
        raise RendererMissing(why)

    recording = Path(recording).resolve()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    index = read_shot_index(recording)
    if plan is None:
        plan = plan_shots(index, max_events=max_events)
    planned = [p if isinstance(p, PlannedShot) else PlannedShot(*p) for p in plan]
    shots: list[Shot] = []
    with (
        work_folder("shots") as tmp,
        headless_viewer() as client,
    ):
        client.open(str(recording))
        _wait_loaded(client, recording, timeout_secs)
        store = client.get_state().active_recording
        location = client.get_location()
        # default-layout shots first (a focused layout set on the recording stays)
        for shot in sorted(planned, key=lambda p: p.event is not None):
            if shot.event is not None:
                focus = focus_layout_json(client, recording, index, shot.event, tmp, timeout_secs)
                client.set_location(location)
                client.set_blueprint(focus, store_id=store)
                stem = f"event{shot.event}_f{shot.frame:04d}"
                wanted = views if views is not None else FOCUS_VIEWS
            else:
                stem = f"{shot.reason}_f{shot.frame:04d}"
                wanted = views if views is not None else VIEWS_BY_REASON.get(shot.reason, ())
            client.set_time(paths.FRAME, sequence=int(shot.frame), play_state="paused")
            time.sleep(settle_secs)
            viewer_views = client.get_state().views
            if full_viewer:
                target = out / f"{stem}_viewer.png"
                _screenshot(client, target)
                shots.append(Shot(target, shot.frame, shot.reason, "viewer", shot.event))
            for prefix in wanted:
                view = next((v for v in viewer_views if v.name.startswith(prefix)), None)
                if view is None:
                    continue
                slug = re.sub(r"[^a-z0-9]+", "_", prefix.lower()).strip("_")
                target = out / f"{stem}_{slug}.png"
                _screenshot(client, target, view.view_id)
                shots.append(Shot(target, shot.frame, shot.reason, view.name, shot.event))
    return shots


def _wait_loaded(client: Any, what: Path, timeout_secs: float) -> None:
    deadline = time.monotonic() + timeout_secs
    while client.get_state().loading:
        if time.monotonic() > deadline:
            raise TimeoutError(f"the viewer did not load {what} in {timeout_secs} s")
        time.sleep(0.1)


def _screenshot(client: Any, target: Path, view_id: Any = None, attempts: int = 3) -> None:
    """Save a screenshot; lavapipe on a busy machine sometimes misses the viewer's deadline."""
    for attempt in range(attempts):
        try:
            client.save_screenshot(str(target.resolve()), view_id=view_id)
            return
        except TimeoutError:
            if attempt == attempts - 1:
                raise
            time.sleep(2.0)


def recording_cameras(recording: str | Path) -> list[tuple[str, int, int]]:
    """(name, width, height) of each camera of a recording (from its static Pinholes)."""
    chunks = open_recording(recording).stream().filter(is_static=True).to_chunks()
    cams: list[tuple[str, int, int]] = []
    prefix = paths.entity(paths.CAMERAS) + "/"
    for chunk in chunks:
        entity = str(chunk.entity_path)
        if not entity.startswith(prefix) or entity.count("/") != 2:
            continue
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name.endswith("Pinhole:resolution"):
                w, h = batch.column(name).to_pylist()[-1][0]
                cams.append((entity[len(prefix) :], int(w), int(h)))
    return sorted(set(cams))


def focus_blueprint_for(recording: str | Path, index: ShotIndex, event: int) -> Any:
    """The focused blueprint (:func:`viz.layout.focus_blueprint`) of event ``#event``."""
    return layout.focus_blueprint(
        recording_cameras(recording),
        event_index=event,
        target_xyz=index.event_xyz_m[event],
        track_ids=(index.event_old_track_ids[event], index.event_new_track_ids[event]),
        gt_id=index.event_gt_ids[event] if event < len(index.event_gt_ids) else None,
    )


def focus_layout_json(
    client: Any,
    recording: Path,
    index: ShotIndex,
    event: int,
    tmp: Path,
    timeout_secs: float = 60.0,
) -> dict[str, Any]:
    """The focused blueprint in the viewer's JSON form, for ``ViewerClient.set_blueprint``.

    A running viewer takes a blueprint only as JSON, and a blueprint's JSON is only written by
    the viewer: so a tiny recording carrying the blueprint is opened, read back and closed (an
    ``.rbl`` opened next to a recording with its own embedded blueprint does not win)."""
    import rerun as rr

    path = tmp / f"focus_e{event}.rrd"
    # an application id of its own per event: the viewer keeps one active blueprint per
    # application, so a shared one would return the previous event's layout (and the
    # recording's own layout must stay untouched)
    rec = rr.RecordingStream(
        f"{paths.APPLICATION_ID}_focus_e{event}", recording_id=f"focus-e{event}"
    )
    rec.save(path, default_blueprint=focus_blueprint_for(recording, index, event))
    rec.log("focus_layout", rr.AnyValues(event=[event]), static=True)
    rec.flush()
    rec.disconnect()
    client.open(str(path))
    _wait_loaded(client, path, timeout_secs)
    store = client.get_state().active_recording
    layout_json = client.get_blueprint(store_id=store).blueprint
    client.close(store_ids=[store])
    return layout_json


def image_variance(png: str | Path) -> float:
    """Pixel variance of a PNG (0 for a blank image)."""
    from PIL import Image

    with Image.open(png) as im:
        return float(np.asarray(im.convert("L"), dtype=np.float64).var())
