"""Which mechanisms move a Rerun 0.41 viewer's time cursor (docs/debugger.md, "Landing on the
moment"): spawns the headless native viewer (needs a Vulkan driver, e.g. Mesa lavapipe), tries
each mechanism on a recording and prints where the viewer says its cursor is.

Usage: ``python bench/probe_time_cursor.py REC.rrd`` (a recording with a ``frame`` timeline of
at least 60 frames, e.g. ``mctrack demo``'s).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from viz.shots import _free_port, _private_home, _rerun_executable, _wait_loaded


def cursor(client: object) -> list[tuple[str | None, int | None]]:
    state = client.get_state()  # type: ignore[attr-defined]
    return [(r.current_timeline, r.current_time) for r in state.recordings]


def main() -> int:
    from rerun.experimental import ViewerClient

    rec = Path(sys.argv[1]).resolve()
    with (
        _private_home(),
        ViewerClient.spawn(
            headless=True,
            port=_free_port(),
            hide_welcome_screen=True,
            executable_path=_rerun_executable(),
        ) as client,
    ):
        print("viewer", client.get_state().viewer_version)
        client.open(rec.as_uri() + "#when=frame@25")
        _wait_loaded(client, rec, 60.0)
        time.sleep(1.0)
        print("open(file URI #when=frame@25):", cursor(client))
        location = client.get_location()
        for how, url in (
            ("open", location + "#when=frame@55"),
            ("set_location", location + "#when=frame@60"),
        ):
            try:
                getattr(client, how)(url)
                time.sleep(1.0)
                print(f"{how}({url}):", cursor(client))
            except Exception as exc:  # the viewer refuses: report it, it is the finding
                print(f"{how}({url}): refused: {type(exc).__name__}: {str(exc).splitlines()[0]}")
        client.set_time("frame", sequence=40, play_state="paused")
        time.sleep(0.5)
        print("set_time(frame, 40):", cursor(client))
    return 0


if __name__ == "__main__":
    sys.exit(main())
