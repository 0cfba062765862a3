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
import os
import re
import socket
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from viz import layout, paths

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
    """What ``summary/index`` says about a recording (empty lists when absent)."""

    id_switch_frames: list[int] = field(default_factory=list)
    id_switch_old_track_ids: list[int] = field(default_factory=list)
    id_switch_new_track_ids: list[int] = field(default_factory=list)
    fragmentation_frames: list[int] = field(default_factory=list)
    lag_frame: int | None = None
    lag_track_id: int | None = None


@dataclass(frozen=True)
class Shot:
    path: Path
    frame: int
    reason: str  # "id_switch", "fragmentation" or "lag"
    view: str  # view name, or "viewer" for the whole window


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


def read_shot_index(recording: str | Path) -> ShotIndex:
    """The static ``summary/index`` of a recording."""
    from rerun.chunk import RrdReader

    chunks = (
        RrdReader(str(recording))
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

    lag_frame, lag_track = ints("lag_frame"), ints("lag_track_id")
    return ShotIndex(
        id_switch_frames=ints("id_switch_frames"),
        id_switch_old_track_ids=ints("id_switch_old_track_ids"),
        id_switch_new_track_ids=ints("id_switch_new_track_ids"),
        fragmentation_frames=ints("fragmentation_frames"),
        lag_frame=lag_frame[0] if lag_frame else None,
        lag_track_id=lag_track[0] if lag_track else None,
    )


def plan_shots(index: ShotIndex, *, max_events: int = 3) -> list[tuple[int, str]]:
    """(frame, reason) pairs: the first ID switches (or, when there are none, the first
    fragmentations) and the largest velocity lag."""
    plan: list[tuple[int, str]] = []
    events = index.id_switch_frames or index.fragmentation_frames
    reason = "id_switch" if index.id_switch_frames else "fragmentation"
    for frame in dict.fromkeys(events):  # unique, in order
        if len(plan) >= max_events:
            break
        plan.append((frame, reason))
    if index.lag_frame is not None:
        plan.append((index.lag_frame, "lag"))
    return plan


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
}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _rerun_executable() -> str | None:
    """The viewer binary itself (the ``rerun`` console script is a Python shim around it)."""
    with contextlib.suppress(ImportError):
        import rerun_cli

        binary = Path(rerun_cli.__file__).with_name("rerun")
        if binary.is_file():
            return str(binary)
    return None


@contextlib.contextmanager
def _private_home() -> Iterator[None]:
    """The viewer and Mesa write state under $HOME; keep screenshots reproducible and the
    user's home untouched."""
    keys = (
        "HOME",
        "XDG_DATA_HOME",
        "XDG_CONFIG_HOME",
        "XDG_CACHE_HOME",
        "XDG_RUNTIME_DIR",
        "RERUN_ANALYTICS",
    )
    saved = {k: os.environ.get(k) for k in keys}
    with tempfile.TemporaryDirectory(prefix="mctrack-viewer-") as home:
        os.environ.update(
            HOME=home,
            XDG_DATA_HOME=f"{home}/data",
            XDG_CONFIG_HOME=f"{home}/config",
            XDG_CACHE_HOME=f"{home}/cache",
            XDG_RUNTIME_DIR=home,
            RERUN_ANALYTICS="false",
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
    plan: Sequence[tuple[int, str]] | None = None,
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
    out_dir : created if needed; files are ``<reason>_f<frame>_<view>.png``.
    plan : (frame, reason) pairs; default :func:`plan_shots` of the recording's index.
    settle_secs : wait after moving the time cursor: the viewer loads chunks on demand.
    full_viewer : also capture the whole window at each frame.
    views : view-name prefixes to capture (default: :data:`VIEWS_BY_REASON` of each shot).

    Raises
    ------
    RendererMissing when no Vulkan driver is installed.
    """
    ok, why = renderer_available()
    if not ok:
        raise RendererMissing(why)
    from rerun.experimental import ViewerClient

    recording = Path(recording).resolve()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if plan is None:
        plan = plan_shots(read_shot_index(recording), max_events=max_events)
    shots: list[Shot] = []
    with (
        _private_home(),
        ViewerClient.spawn(
            headless=True,
            port=_free_port(),
            hide_welcome_screen=True,
            executable_path=_rerun_executable(),
        ) as client,
    ):
        client.open(str(recording))
        deadline = time.monotonic() + timeout_secs
        while client.get_state().loading:
            if time.monotonic() > deadline:
                raise TimeoutError(f"the viewer did not load {recording} in {timeout_secs} s")
            time.sleep(0.2)
        viewer_views = client.get_state().views
        for frame, reason in plan:
            client.set_time(paths.FRAME, sequence=int(frame), play_state="paused")
            time.sleep(settle_secs)
            stem = f"{reason}_f{frame:04d}"
            if full_viewer:
                target = out / f"{stem}_viewer.png"
                client.save_screenshot(str(target.resolve()))
                shots.append(Shot(target, frame, reason, "viewer"))
            for prefix in views if views is not None else VIEWS_BY_REASON.get(reason, ()):
                view = next((v for v in viewer_views if v.name.startswith(prefix)), None)
                if view is None:
                    continue
                slug = re.sub(r"[^a-z0-9]+", "_", prefix.lower()).strip("_")
                target = out / f"{stem}_{slug}.png"
                client.save_screenshot(str(target.resolve()), view_id=view.view_id)
                shots.append(Shot(target, frame, reason, view.name))
    return shots


def image_variance(png: str | Path) -> float:
    """Pixel variance of a PNG (0 for a blank image)."""
    from PIL import Image

    with Image.open(png) as im:
        return float(np.asarray(im.convert("L"), dtype=np.float64).var())
