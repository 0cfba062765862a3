"""`mctrack inspect REC [--event K | --frame F | --list]`: the viewer on a recording, at one
moment; or the events it can open.

With ``--event K`` (``#K`` in the recording's summary) the viewer opens in that event's focused
layout (old and new track and the GT object highlighted, everything else dimmed, the 3D eye on
the event, the explanation and cost rows beside it) with the time cursor on the event's frame.

How the cursor gets there (Rerun 0.41, docs/debugger.md "Landing on the moment"): the blueprint's
``TimePanel`` has no cursor field (timeline, play state, speed, loop, selection only), and a
viewer URL's ``#when=frame@N`` fragment is ignored for a file (checked on a headless viewer: the
cursor stays at 0). What works is ``rerun.experimental.ViewerClient.set_time`` on a native viewer
this command spawns: :func:`drive_viewer` opens the recording, applies the focused layout, sets
the cursor and reads the viewer's own cursor back, failing loudly when it is not on the frame.
``--print`` only prints the target (the event, its frame, the recording) without starting
anything (not with ``--list``, which starts nothing either); ``--list`` prints the events
``--event`` can open (of a recording, or of each recording of a ``mctrack kitti --record`` run
folder), one per line, without a viewer or a display.
``--frame F`` must lie within the recording's frames (default: its first frame); a frame
outside them is an error naming the frames it has.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from app.common import EXIT_VIEWER_FAILED
from tracker.errors import InputError

_T = TypeVar("_T")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording",
        help="an .rrd written by mctrack view / demo / kitti --record (with --list also a "
        "mctrack kitti --record --out folder)",
    )
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--event", type=int, default=None, help="event #K of the summary")
    what.add_argument(
        "--frame",
        type=int,
        default=None,
        help="a frame, in the default layout (default: the first)",
    )
    what.add_argument(
        "--list",
        action="store_true",
        help="print the events --event opens, one per line (sequence, #K, frame, kind, "
        "tracks); no viewer, no display needed",
    )
    parser.add_argument(
        "--print",
        action="store_true",
        help="print the URL and the target; start nothing (not with --list)",
    )


@dataclass(frozen=True)
class InspectTarget:
    """Where the viewer goes: a frame, and for an event its focused layout's target."""

    url: str  # the recording (a file URI: a #when fragment does not move the cursor in 0.41)
    frame: int
    event: int | None
    description: str


def read_recording(recording: Path, reader: Callable[[Path], _T]) -> _T:
    """``reader(recording)``, with rerun's error on a file it cannot read as one line."""
    try:
        return reader(recording)
    except RuntimeError as exc:  # rerun's reader: not an .rrd, truncated, or another version
        raise InputError(
            f"{recording}: not a readable Rerun recording ({exc}); pass an .rrd written by "
            "mctrack view, demo or kitti --record"
        ) from None


def checked_frame(recording: Path, frame: int | None) -> int:
    """``frame`` (None: the recording's first), checked against the recording's ``frame``
    timeline: InputError naming the frames it has when outside them (inspect, shots)."""
    from viz.shots import read_frame_range

    frames = read_recording(recording, read_frame_range)
    if frames is None:
        raise InputError(f"{recording}: the recording has no frames")
    first, last = frames
    f = first if frame is None else frame
    if not first <= f <= last:
        raise InputError(f"{recording}: --frame {f}: the recording has frames {first}..{last}")
    return f


def inspect_target(recording: Path, event: int | None, frame: int | None) -> InspectTarget:
    """The frame (the event's own, or ``frame``: by default the recording's first), the
    recording's URI, a description.

    Raises InputError for a frame or event the recording does not have: the viewer would
    otherwise open on an empty scene at that frame, without a word."""
    from viz.shots import read_shot_index

    url = recording.resolve().as_uri()
    if event is None:
        f = checked_frame(recording, frame)
        return InspectTarget(url, f, None, f"frame {f}")
    index = read_recording(recording, read_shot_index)
    n = len(index.event_frames)
    if not 0 <= event < n:
        has = f"events #0..#{n - 1}" if n else "no ID events (ID switches or fragmentations)"
        raise InputError(f"{recording}: --event {event}: the recording has {has}")
    f = index.event_frames[event]
    kind = "fragmentation" if index.event_kinds[event] else "ID switch"
    cause = index.event_causes[event] if event < len(index.event_causes) else "cause unknown"
    text = (
        f"event #{event}: {kind} at frame {f}, GT {index.event_gt_ids[event]}, "
        f"T{index.event_old_track_ids[event]} -> T{index.event_new_track_ids[event]} ({cause})"
    )
    return InspectTarget(url, f, event, text)


def drive_viewer(client: Any, recording: Path, target: InspectTarget, tmp: Path) -> int:
    """Open ``recording`` in the viewer ``client`` drives, apply the event's focused layout, put
    the time cursor on the target frame (paused) and return where the viewer says its cursor is.

    Raises RuntimeError when the viewer's own cursor is not on the frame afterwards."""
    from viz import paths
    from viz.shots import _wait_loaded, focus_layout_json, read_shot_index

    rec = recording.resolve()
    layout = None
    if target.event is not None:
        layout = focus_layout_json(client, rec, read_shot_index(rec), target.event, tmp)
    client.open(str(rec))
    _wait_loaded(client, rec, 120.0)
    store = client.get_state().active_recording
    if layout is not None:
        client.set_blueprint(layout, store_id=store)
    client.set_time(paths.FRAME, sequence=target.frame, play_state="paused")
    state = client.get_state()
    cursor = next(
        (r.current_time for r in state.recordings if r.store_id == store),
        None,
    )
    if cursor != target.frame:
        raise RuntimeError(f"the viewer's time cursor is at {cursor}, not at frame {target.frame}")
    return int(cursor)


def missing_display(environ: Mapping[str, str], platform: str = sys.platform) -> bool:
    """No display server for the viewer's window: on Linux (X11 or Wayland) the viewer would
    start, print winit's error among its logs and leave only "transport error" to say why."""
    if not platform.startswith("linux"):
        return False
    return not any(environ.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"))


def _listed_recordings(given: Path) -> list[Path]:
    """The recordings ``--list`` reads: the file, or a run folder's ``recordings/*.rrd`` (or
    a folder of recordings itself)."""
    if given.is_file():
        return [given]
    if not given.is_dir():
        raise InputError(f"{given}: file or folder not found")
    folder = given / "recordings" if (given / "recordings").is_dir() else given
    found = sorted(p for p in folder.glob("*.rrd") if p.is_file())
    if not found:
        raise InputError(
            f"{given}: no recordings (.rrd) in it or in its recordings/ folder; record with "
            "mctrack kitti --record or mctrack view --save"
        )
    return found


def event_lines(recording: Path) -> tuple[str, list[str]]:
    """(the recording's sequence, one line per ID event): ``#K`` as ``--event K`` takes it,
    sorted by frame then number; sequence, #K, frame, kind, old -> new track, the GT object."""
    from viz.shots import read_scene_name, read_shot_index

    index = read_recording(recording, read_shot_index)
    scene = read_recording(recording, read_scene_name) or recording.stem
    n = len(index.event_frames)
    lines = []
    for k in sorted(range(n), key=lambda k: (index.event_frames[k], k)):
        kind = "fragmentation" if index.event_kinds[k] else "ID switch"
        lines.append(
            f"{scene}  #{k:<3}  frame {index.event_frames[k]:>5}  {kind:<13}  "
            f"T{index.event_old_track_ids[k]} -> T{index.event_new_track_ids[k]}  "
            f"(GT {index.event_gt_ids[k]})"
        )
    return scene, lines


def list_events(given: Path) -> int:
    """``--list``: the events of each recording, by sequence, then frame. Reads the recordings
    only: no viewer, no display."""
    listed = []
    for rec in _listed_recordings(given):
        scene, lines = event_lines(rec)
        listed.append((scene, str(rec), lines))
        if not lines:  # said, so that an empty listing is not taken for a failure
            print(f"{rec}: no ID events (ID switches or fragmentations) recorded", file=sys.stderr)
    for _, _, lines in sorted(listed):
        for line in lines:
            print(line)
    if len(listed) > 1 and any(lines for _, _, lines in listed):
        print(
            f"open one: mctrack inspect RECORDING --event K (the sequence's recording in "
            f"{Path(listed[0][1]).parent})",
            file=sys.stderr,
        )
    return 0


def run(args: argparse.Namespace) -> int:
    recording = Path(args.recording)
    if args.list and args.print:  # (else --print went without a word)
        raise InputError("--print and --list: give one (--list starts no viewer either)")
    if args.list:
        return list_events(recording)
    if not recording.is_file():
        raise InputError(f"{recording}: file not found")
    target = inspect_target(recording, args.event, args.frame)
    print(target.description)
    print(f"recording: {target.url}")
    if args.print:
        return 0
    if missing_display(os.environ):
        where = f"--event {target.event}" if target.event is not None else f"--frame {target.frame}"
        print(
            "mctrack inspect: no display for the viewer's window (DISPLAY and WAYLAND_DISPLAY "
            f"are unset); on a machine without one, picture the moment with: mctrack shots "
            f"{recording} {where} --out shots/",
            file=sys.stderr,
        )
        return EXIT_VIEWER_FAILED
    from tracker.io.fileio import work_folder
    from viz.rerun_process import stop_rerun, viewer_client

    process = None
    try:
        # the viewer listens on 127.0.0.1 (ViewerClient.spawn's would listen on all interfaces)
        # and keeps running after this command, until its window is closed
        client, process = viewer_client(headless=False, detach=True)
        with work_folder("inspect") as tmp:
            frame = drive_viewer(client, recording, target, tmp)
    except (RuntimeError, TimeoutError, OSError, ConnectionError) as exc:
        if process is not None:
            stop_rerun(process)
        print(f"mctrack inspect: could not start or drive the viewer: {exc}", file=sys.stderr)
        return EXIT_VIEWER_FAILED
    print(f"viewer started at frame {frame} (close its window to quit)")
    return 0
