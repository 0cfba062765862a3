"""`mctrack shots RECORDING --out DIR`: headless screenshots of a recording's key views.

What to capture (as listed in the recording's ``summary/index``):

* default: the first 3 ID switches (``--max-events``; the first fragmentations when there are
  none), each in its focused layout, and the largest velocity lag (``--max-events 0``: the
  lag alone);
* ``--event K`` (repeatable) or ``--events all``: those events (``#K`` in the summary), focused;
* ``--frame F``: one frame in the default layout (F within the recording's frames).

Event and frame shots move to a frame with a camera image when one is at most 3 frames away.
Needs a Vulkan driver; on a machine without GPU, Mesa's software one: ``apt-get install -y
mesa-vulkan-drivers libvulkan1``. Without it, this says so and exits with status 3.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from app.common import EXIT_VIEWER_FAILED
from app.inputs import non_negative_int
from tracker.errors import InputError

EXIT_NO_RENDERER = 3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="an .rrd written by mctrack view / demo / kitti --record")
    parser.add_argument("--out", required=True, help="folder for the PNG files")
    what = parser.add_mutually_exclusive_group()
    what.add_argument(
        "--event", type=int, action="append", help="event #K of the summary (repeatable)"
    )
    what.add_argument("--events", choices=["all"], help="every ID switch and fragmentation")
    what.add_argument("--frame", type=int, help="one frame, in the default layout")
    parser.add_argument(
        "--max-events",
        type=non_negative_int,
        default=3,
        help="ID switches captured by default (3; 0: only the largest velocity lag)",
    )
    parser.add_argument("--settle", type=float, default=2.0, help="seconds to wait per frame")
    parser.add_argument("--timeout", type=float, default=120.0, help="seconds to load the file")


def run(args: argparse.Namespace) -> int:
    from app.inspect import checked_frame, read_recording
    from viz.shots import RendererMissing, plan_shots, read_shot_index, take_shots

    recording = Path(args.recording)
    if not recording.is_file():
        raise InputError(f"{recording}: file not found")
    index = read_recording(recording, read_shot_index)
    if args.frame is not None:  # else a shot of an empty scene at that frame, without a word
        checked_frame(recording, args.frame)
    try:
        plan = plan_shots(
            index,
            max_events=args.max_events,
            events=args.event or args.events,
            frame=args.frame,
        )
    except IndexError as exc:
        raise InputError(f"{recording}: --event: {exc}") from None
    if not plan and index.event_frames:  # events there, none asked for (--max-events 0)
        print(f"{recording}: no velocity lag recorded; nothing to capture (--max-events 0)")
        return 0
    if not plan:
        print(
            f"{recording}: no ID switches, fragmentations or velocity lag recorded; nothing "
            "to capture (record with ground truth: mctrack view INPUT --gt GT)"
        )
        return 0
    try:
        shots = take_shots(
            recording, args.out, plan=plan, settle_secs=args.settle, timeout_secs=args.timeout
        )
    except RendererMissing as exc:
        print(
            f"mctrack shots: cannot render: {exc}. The headless viewer needs a Vulkan driver; "
            "without a GPU install Mesa's software renderer (lavapipe).",
            file=sys.stderr,
        )
        return EXIT_NO_RENDERER
    except (RuntimeError, TimeoutError, OSError) as exc:  # the viewer died or never answered
        print(f"mctrack shots: the headless viewer failed: {exc}", file=sys.stderr)
        return EXIT_VIEWER_FAILED
    for shot in shots:
        print(f"{shot.path}  ({shot_caption(shot.reason, shot.frame, shot.event)}: {shot.view})")
    return 0


#: How each kind of shot is named on screen (``id_switch`` and "frame at frame 15" read badly).
_REASON_WORDS = {
    "id_switch": "ID switch",
    "fragmentation": "fragmentation",
    "lag": "largest velocity lag",
}


def shot_caption(reason: str, frame: int, event: int | None) -> str:
    """``event #3 ID switch at frame 80``, ``largest velocity lag at frame 410``, ``frame 15``."""
    what = _REASON_WORDS.get(reason)
    text = f"{what} at frame {frame}" if what else f"frame {frame}"
    return f"event #{event} {text}" if event is not None else text
