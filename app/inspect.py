"""`mctrack inspect REC [--event K | --frame F]`: the viewer on a recording, at one moment.

With ``--event K`` (``#K`` in the recording's summary) the viewer opens in that event's focused
layout (old and new track and the GT object highlighted, everything else dimmed, the 3D eye on
the event, the explanation and cost rows beside it) with the time cursor on the event's frame.
Rerun 0.41 has no blueprint field for the time cursor, and the ``#when=frame@N`` fragment of a
viewer URL did not move it in our tests, so the cursor and the layout are set through
``rerun.experimental.ViewerClient`` on a native viewer this command spawns. ``--print`` only
prints what it would do (the URL, the frame, the event) without starting anything.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from tracker.errors import InputError

EXIT_VIEWER_FAILED = 4


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="an .rrd written by mctrack view / demo / kitti --record")
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--event", type=int, default=None, help="event #K of the summary")
    what.add_argument("--frame", type=int, default=None, help="a frame, in the default layout")
    parser.add_argument(
        "--print", action="store_true", help="print the URL and the target; start nothing"
    )


@dataclass(frozen=True)
class InspectTarget:
    """Where the viewer goes: a frame, and for an event its focused layout's target."""

    url: str
    frame: int
    event: int | None
    description: str


def inspect_target(recording: Path, event: int | None, frame: int | None) -> InspectTarget:
    """The frame (the event's own), the viewer URL with its ``#when`` fragment, a description."""
    from viz.shots import read_shot_index

    url = recording.resolve().as_uri()
    if event is None:
        f = frame if frame is not None else 0
        return InspectTarget(f"{url}#when=frame@{f}", f, None, f"frame {f}")
    index = read_shot_index(recording)
    n = len(index.event_frames)
    if not 0 <= event < n:
        raise InputError(f"{recording}: --event {event}: the recording has events #0..#{n - 1}")
    f = index.event_frames[event]
    kind = "fragmentation" if index.event_kinds[event] else "ID switch"
    cause = index.event_causes[event] if event < len(index.event_causes) else "cause unknown"
    text = (
        f"event #{event}: {kind} at frame {f}, GT {index.event_gt_ids[event]}, "
        f"T{index.event_old_track_ids[event]} -> T{index.event_new_track_ids[event]} ({cause})"
    )
    return InspectTarget(f"{url}#when=frame@{f}", f, event, text)


def run(args: argparse.Namespace) -> int:
    recording = Path(args.recording)
    if not recording.is_file():
        raise InputError(f"{recording}: file not found")
    target = inspect_target(recording, args.event, args.frame)
    print(target.description)
    print(f"viewer URL: {target.url}")
    if args.print:
        return 0
    import tempfile

    from rerun.experimental import ViewerClient

    from viz import paths
    from viz.shots import _free_port, _rerun_executable, focus_layout_json, read_shot_index

    try:
        client = ViewerClient.spawn(
            headless=False,
            port=_free_port(),
            hide_welcome_screen=True,
            detach_process=True,
            executable_path=_rerun_executable(),
        )
        with tempfile.TemporaryDirectory(prefix="mctrack-inspect-") as tmp:
            layout = None
            if target.event is not None:
                index = read_shot_index(recording)
                rec = recording.resolve()
                layout = focus_layout_json(client, rec, index, target.event, Path(tmp))
            client.open(str(recording.resolve()))
            while client.get_state().loading:
                time.sleep(0.1)
            store = client.get_state().active_recording
            if layout is not None:
                client.set_blueprint(layout, store_id=store)
            client.set_time(paths.FRAME, sequence=target.frame, play_state="paused")
    except (RuntimeError, TimeoutError, OSError) as exc:
        print(f"mctrack inspect: could not start or drive the viewer: {exc}", file=sys.stderr)
        return EXIT_VIEWER_FAILED
    print("viewer started (close its window to quit)")
    return 0
