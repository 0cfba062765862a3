"""`mctrack view INPUT`: run the tracker with the Rerun observer (file, native viewer or web).

Every stage of every frame is recorded under the entity paths of :mod:`viz.paths`, plus (with
``--gt``) the ground truth, the ID switches and fragmentations against it and the matched GT's
velocity curves. ``--save`` streams to disk, so memory stays flat on long sequences.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import time
from pathlib import Path

from app.inputs import add_mode_argument, host_address, port_number, refuse_unused_option
from app.track import (
    add_profile_argument,
    calibrate_scenes,
    parse_frame_range,
    require_frames,
    select_scenes,
)
from tracker.config import TrackerConfig
from tracker.errors import InputError, ViewerError
from tracker.frame import Frame
from tracker.io.fileio import (
    check_output_file,
    path_in,
    refuse_case_collisions,
    safe_filename,
)
from viz.rerun_process import LOOPBACK

DEFAULT_WEB_PORT = 9090
DEFAULT_GRPC_PORT = 9876  # (Rerun's own default)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="BaseVersion detections (.json or .json.gz)")
    parser.add_argument("--gt", default=None, help="BaseVersion ground truth of the same scenes")
    parser.add_argument("--config", default="kitti", help="kitti, nuscenes, waymo or a TOML path")
    add_mode_argument(parser)
    add_profile_argument(parser, None)  # (as `track`: a file tracked alike by both)
    parser.add_argument("--scenes", default=None, help="comma-separated scene names (default all)")
    parser.add_argument("--frames", default=None, help="frame index range A:B within each scene")
    parser.add_argument(
        "--labels",
        default=None,
        help="KITTI label_02 folder: ID switches and metrics by TrackEval's KITTI protocol "
        "(default: BEV IoU on --gt)",
    )
    parser.add_argument(
        "--images",
        action="append",
        default=[],
        metavar="[CAMERA=]DIR",
        help="folder of <frame_id:06d>.png images for a camera (default camera: the first); "
        "repeatable. Default: <input folder>/image_02 for the first camera when it exists",
    )
    parser.add_argument("--no-motion", action="store_true", help="skip the motion metrics")
    sink = parser.add_mutually_exclusive_group()
    sink.add_argument(
        "--save",
        default=None,
        metavar="OUT.rrd",
        help="write a recording file, named *.rrd (the default, as ./mctrack_<scene>.rrd)",
    )
    sink.add_argument("--spawn", action="store_true", help="stream to a new native viewer")
    sink.add_argument("--serve-web", action="store_true", help="serve a web viewer (until Ctrl-C)")
    parser.add_argument(
        "--web-port",
        type=port_number,
        default=None,
        help=f"port of --serve-web's web page (default {DEFAULT_WEB_PORT}; only with --serve-web)",
    )
    parser.add_argument(
        "--grpc-port",
        type=port_number,
        default=None,
        help=f"port the viewer connects to (default {DEFAULT_GRPC_PORT}; only with --spawn or "
        "--serve-web)",
    )
    parser.add_argument(
        "--host",
        type=host_address,
        default=None,
        help="IP address the viewer's servers listen on (default 127.0.0.1; only with --spawn "
        "or --serve-web); 0.0.0.0 exposes the recording to the network: do it deliberately",
    )


#: an ``--images`` folder: (its camera, None for each scene's first; the folder; its images)
ImageFolder = tuple[str | None, Path, dict[int, Path]]


def _image_folders(specs: list[str]) -> list[ImageFolder]:
    """``--images [CAMERA=]DIR`` each, its folder checked: it must hold images."""
    from viz.observer import list_images

    folders: list[ImageFolder] = []
    for spec in specs:
        name, sep, folder = spec.partition("=")
        if not sep:
            name, folder = "", spec
        if not Path(folder).is_dir():
            raise InputError(f"--images: {folder} is not a folder")
        images = list_images(Path(folder))
        if not images:  # else the camera view stays dark, unexplained
            raise InputError(
                f"--images: {folder} holds no images (<frame_id:06d>.png, .jpg or .jpeg)"
            )
        folders.append((name if sep else None, Path(folder), images))
    return folders


def _check_images(
    folders: list[ImageFolder], input_path: str, scenes: dict[str, list[Frame]]
) -> dict[str, list[str]]:
    """Each ``--images`` folder's camera must be one of the input's, and the folder must hold
    an image of a recorded frame of it: else the camera view stays dark, without a word.
    Returns, per scene, the folders without an image of its frames (beside scenes with)."""
    _refuse_repeated_cameras(folders, scenes)
    cameras = sorted({c.name for frames in scenes.values() for f in frames for c in f.cameras})
    has = f"its cameras: {', '.join(cameras)}" if cameras else "it has none"
    unmatched: dict[str, list[str]] = {}
    for name, folder, images in folders:
        if name is not None and name not in cameras:
            raise InputError(
                f"--images {name}={folder}: {input_path} has no camera {name!r} ({has})"
            )
        if name is None and not cameras:
            raise InputError(f"--images {folder}: {input_path} has no camera to show it on")
        shown: dict[str, bool] = {}  # scene -> an image of one of its frames
        for scene, frames in scenes.items():
            first = frames[0].cameras[0].name if frames[0].cameras else None
            camera = name if name is not None else first  # as _images picks it
            ids = [f.frame_id for f in frames if camera and f.camera_index(camera) >= 0]
            if ids:
                shown[scene] = any(i in images for i in ids)
        if not any(shown.values()):
            ids = [f.frame_id for frames in scenes.values() for f in frames]
            raise InputError(
                f"--images: {folder} holds no image of a recorded frame (frame_id "
                f"{min(ids)}..{max(ids)}; its images are of frames {min(images)}..{max(images)})"
            )
        for scene, ok in shown.items():
            if not ok:
                unmatched.setdefault(scene, []).append(str(folder))
    return unmatched


def _refuse_repeated_cameras(folders: list[ImageFolder], scenes: dict[str, list[Frame]]) -> None:
    """Two ``--images`` folders for one camera of a scene are a usage error: :func:`_images`
    would keep the last one without a word. A folder without ``CAMERA=`` is for each scene's
    first camera, so it repeats a named one only in the scenes whose first camera that is."""
    for scene, frames in scenes.items():
        first = frames[0].cameras[0].name if frames[0].cameras else None
        given: dict[str, tuple[str | None, Path]] = {}
        for name, folder, _ in folders:
            camera = name if name is not None else first
            if camera is None:
                continue
            if camera in given:
                earlier_name, earlier = given[camera]
                both_named = name is not None and earlier_name is not None
                which = "" if both_named else f" (without CAMERA=: scene {scene}'s first camera)"
                raise InputError(
                    f"--images: camera {camera!r} given twice, {earlier} and {folder}{which}: "
                    "give one folder per camera"
                )
            given[camera] = (name, folder)


def _images(
    folders: list[ImageFolder], input_path: Path, first_camera: str | None
) -> dict[str, Path]:
    """Camera -> image folder of a scene whose first camera is ``first_camera``."""
    images: dict[str, Path] = {}
    for name, folder, _ in folders:
        images[name if name is not None else first_camera or ""] = folder
    if not folders and first_camera and (input_path.parent / "image_02").is_dir():
        images[first_camera] = input_path.parent / "image_02"  # the KITTI layout
    return images


def _refuse_unreadable_images(
    scene_images: dict[str, dict[str, Path]], scenes: dict[str, list[Frame]]
) -> None:
    """An image file of a recorded frame that cannot be read (a broken link, a folder by an
    image's name, no permission) or decoded (a truncated or corrupt PNG or JPEG, which opens
    but has no picture) is an error naming it, before any recording: Rerun only warned, or the
    viewer showed nothing, and the frame went without its image, exit 0. A frame without an
    image file is no error (a folder may hold some frames' images only)."""
    from viz.observer import image_problem, list_images

    listed: dict[Path, dict[int, Path]] = {}
    checked: set[Path] = set()
    for scene, frames in scenes.items():
        for camera, folder in scene_images.get(scene, {}).items():
            if folder not in listed:
                listed[folder] = list_images(folder)
            for frame in frames:
                path = listed[folder].get(frame.frame_id)
                if path is None or frame.camera_index(camera) < 0 or path in checked:
                    continue  # (not recorded: the observer logs a frame's own cameras)
                problem = image_problem(path)
                if problem is not None:
                    raise InputError(
                        f"{path}: image of frame {frame.frame_id} (camera {camera}) {problem}"
                    )
                checked.add(path)


def _check_labels(folder: str, scenes: list[str]) -> set[str]:
    """The ``scenes`` with a label file in ``--labels`` ``folder``, each checked up front (a bad
    one is its file, line and field, not a TrackEval error after the tracking). A missing
    folder, or one without a label file of any scene, is an error: the recording would otherwise
    quietly have no KITTI matching. An empty label file is a scene without labelled objects
    (valid KITTI, as `mctrack eval` scores it): said, and recorded with it."""
    from tracker.eval.kitti import check_kitti_labels

    if not Path(folder).is_dir():
        raise InputError(f"{folder}: --labels folder not found (KITTI label_02)")
    labelled = check_kitti_labels(Path(folder), dict.fromkeys(scenes))  # {scene: frames spanned}
    for scene in scenes:
        if labelled.get(scene) == 0:
            path = path_in(folder, scene, ".txt")
            print(f"scene {scene}: {path} holds no labels (no labelled object to match)")
    if not labelled:
        wanted = ", ".join(path_in(folder, s, ".txt").name for s in scenes[:4])
        more = " ..." if len(scenes) > 4 else ""
        raise InputError(f"{folder}: --labels holds no label file of the scenes ({wanted}{more})")
    return set(labelled)


def _save_path(save: str | None, scene: str, many: bool) -> Path:
    if save is None:
        return Path(f"mctrack_{safe_filename(scene)}.rrd")  # scene names are input data
    path = Path(save)
    return path.with_name(f"{path.stem}_{safe_filename(scene)}{path.suffix}") if many else path


def _save_paths(save: str | None, scenes: dict[str, list[Frame]], source: str) -> dict[str, Path]:
    """Each recorded scene's recording file, checked before any recording (not a folder, its
    folder writable; scenes whose files differ only in case refused, as by the other commands):
    a bad one failed only once every scene was recorded."""
    many = len(scenes) > 1
    paths = {scene: _save_path(save, scene, many) for scene, frames in scenes.items() if frames}
    refuse_case_collisions(paths, source, suffix=".rrd")
    for path in paths.values():
        check_output_file(path, "--save")
    return paths


def _refuse_save_suffix(save: str) -> None:
    """``--save`` names a recording: without the ``.rrd`` suffix (``--save conv``) it was
    written as given (``conv_<scene>`` with several scenes), a file `mctrack inspect --list`
    of its folder does not find; `kitti --record` and the others name theirs ``<seq>.rrd``."""
    path = Path(save)
    if path.suffix == ".rrd":
        return
    upper = path.suffix.lower() == ".rrd"  # (conv.RRD: conv.rrd)
    named = path.with_suffix(".rrd") if upper else path.with_name(f"{path.name}.rrd")
    raise InputError(f"--save {save}: a recording file's name ends in .rrd (e.g. {named})")


def _refuse_unused_options(args: argparse.Namespace) -> None:
    """The viewer's options where they have no effect (each was ignored without a word)."""
    if not (args.spawn or args.serve_web):
        for option, value, what in (
            ("--host", args.host, "address"),
            ("--grpc-port", args.grpc_port, "port"),
        ):
            viewer = f"--spawn or --serve-web (the viewer's {what})"
            refuse_unused_option(option, value, viewer, "without them view records to a file")
    instead = "--spawn's viewer has none" if args.spawn else "without it view records to a file"
    if not args.serve_web:
        refuse_unused_option("--web-port", args.web_port, "--serve-web (its web page)", instead)


def run(args: argparse.Namespace) -> int:
    from app.inspect import missing_display

    _refuse_unused_options(args)
    if args.save is not None:  # (with several scenes, its files would go beside a folder)
        check_output_file(args.save, "--save")
        _refuse_save_suffix(args.save)
    args.host = args.host or LOOPBACK
    args.grpc_port = DEFAULT_GRPC_PORT if args.grpc_port is None else args.grpc_port
    args.web_port = DEFAULT_WEB_PORT if args.web_port is None else args.web_port

    if args.spawn and missing_display(os.environ):  # else the run hangs on a viewer never up
        raise ViewerError(
            "--spawn: no display for the viewer's window (DISPLAY and WAYLAND_DISPLAY are "
            "unset); record to a file (--save OUT.rrd, then mctrack shots OUT.rrd --out shots/) "
            "or serve a web viewer (--serve-web)"
        )

    from tracker.config import load_config
    from tracker.io.baseversion import read_baseversion

    overrides = {"mode": args.mode} if args.mode else None
    config = load_config(args.config, overrides=overrides)
    rate = config.frame_rate_hz
    scenes = read_baseversion(args.input, fallback_frame_rate_hz=rate)
    scenes = select_scenes(scenes, args.scenes, parse_frame_range(args.frames), args.input)
    require_frames(scenes, args.input, "record", args.scenes)  # else nothing is recorded
    # as `track` does (the same option, default and warning): the same file, the same tracks
    scenes, _ = calibrate_scenes(scenes, config, args.profile, args.input)
    live = args.spawn or args.serve_web
    saves = {} if live else _save_paths(args.save, scenes, args.input)
    gt_scenes = read_baseversion(args.gt, fallback_frame_rate_hz=rate) if args.gt else {}
    if args.gt and not any(gt_scenes.values()):  # else every scene "is not in" it
        raise InputError(f"{args.gt}: --gt holds no frames of ground truth")
    labelled = (
        _check_labels(args.labels, [s for s, f in scenes.items() if f]) if args.labels else set()
    )
    folders = _image_folders(args.images)
    unmatched = _check_images(folders, args.input, {s: f for s, f in scenes.items() if f})
    scene_images = {
        scene: _images(folders, Path(args.input), f[0].cameras[0].name if f[0].cameras else None)
        for scene, f in scenes.items()
        if f
    }
    _refuse_unreadable_images(scene_images, scenes)
    from app.serve import stopped_as_by_ctrl_c

    # the server is stopped however the command ends (a spawned viewer stays, with its window)
    with stopped_as_by_ctrl_c() if args.serve_web else contextlib.nullcontext():
        server, url = _start_viewer(args) if live else (None, "")
        try:
            _record(args, config, scenes, gt_scenes, labelled, scene_images, unmatched, saves, url)
            if args.serve_web:
                _serve_until_stopped()
        finally:
            if server is not None and args.serve_web:
                from viz.rerun_process import stop_rerun

                stop_rerun(server)
    return 0


def _start_viewer(args: argparse.Namespace) -> tuple[subprocess.Popen[bytes] | None, str]:
    """The viewer (--spawn) or the gRPC server and web viewer (--serve-web), started as the
    ``rerun`` binary on ``--host``: Rerun's Python API would listen on all interfaces.
    Returns (the process started, None when --spawn found a viewer already listening on the
    port; the gRPC URL the recordings connect to)."""
    from viz.rerun_process import (
        exposure_note,
        local_address,
        port_open,
        served_at,
        start_rerun,
        start_viewer,
        stop_rerun,
        wait_listening,
    )

    host, port = args.host, args.grpc_port
    url = f"rerun+http://{local_address(host)}:{port}/proxy"
    note = exposure_note(host, "the recording")
    if args.spawn:
        if port_open(local_address(host), port):  # a viewer there already: as rr.spawn, use it
            print(f"viewer: {url} (already running)")
            if note:  # (it listens where it was started: this run binds nothing)
                print(f"  --host {host} not applied: that viewer listens where it was started")
            return None, url
        try:
            process, url = start_viewer(headless=False, host=host, port=port, detach=True)
        except (RuntimeError, TimeoutError, OSError) as exc:
            raise ViewerError(f"--spawn: the viewer did not start on {host}: {exc}") from None
        # as --serve-web's: on all interfaces, the URL another machine's viewer or SDK uses
        # (`rerun URL` there), with this machine's after it
        shown, listening = served_at(host, lambda at: f"rerun+http://{at}:{port}/proxy")
        print(f"viewer: {shown}")
        if listening:
            print(listening)
    else:
        for option, taken in (("--grpc-port", port), ("--web-port", args.web_port)):
            if port_open(local_address(host), taken):  # (else that server would answer)
                raise InputError(f"{option} {taken}: in use on {host}; choose another port")
        process = start_rerun(
            ["--serve-web", "--port", str(port), "--web-viewer-port", str(args.web_port)],
            host=host,
            quiet=False,
            env={"RUST_LOG": os.environ.get("RUST_LOG") or "warn"},  # (not its INFO lines)
        )
        try:
            wait_listening(process, host, [port, args.web_port])
        except (RuntimeError, TimeoutError, OSError) as exc:
            stop_rerun(process)
            raise ViewerError(f"--serve-web: the server did not start on {host}: {exc}") from None
        except BaseException:
            stop_rerun(process)
            raise
        # (a browser elsewhere reaches both servers at the address it was given)
        page, listening = served_at(
            host, lambda at: f"http://{at}:{args.web_port}/?url=rerun+http://{at}:{port}/proxy"
        )
        print(f"web viewer: {page}")
        if listening:
            print(listening)
    if note:
        print(note)
    return process, url


def _serve_until_stopped() -> None:
    """Until Ctrl-C, SIGTERM or SIGHUP (which end it as Ctrl-C does: see :func:`run`)."""
    try:  # (the line inside: a signal right after it is a stop too)
        print("serving; press Ctrl-C to stop", flush=True)
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        print("stopped")


def _record(
    args: argparse.Namespace,
    config: TrackerConfig,
    scenes: dict[str, list[Frame]],
    gt_scenes: dict[str, list[Frame]],
    labelled: set[str],
    scene_images: dict[str, dict[str, Path]],
    unmatched: dict[str, list[str]],
    saves: dict[str, Path],
    url: str,
) -> None:
    """Each scene recorded: to its file, or to the viewer at ``url``."""
    from tracker.io.fileio import staged_files
    from viz.layout import debug_blueprint
    from viz.record import new_recording, partial_path, record_scene

    # the recordings are moved into place once every scene is recorded: a run that fails on a
    # later scene (or is stopped) leaves none of its own, and earlier ones at those paths stay
    with staged_files() as staged:
        for scene, frames in scenes.items():
            if not frames:
                print(f"scene {scene}: no frames in range, skipped")
                continue
            cameras = [(c.name, c.width_px, c.height_px) for c in frames[0].cameras]
            images = scene_images[scene]
            for folder in unmatched.get(scene, []):
                print(f"scene {scene}: no image of its frames in {folder}; recording without them")
            gt = None
            if args.gt:
                wanted = {f.frame_id for f in frames}
                gt = [f for f in gt_scenes.get(scene, []) if f.frame_id in wanted]
                if not gt:
                    print(f"scene {scene}: not in {args.gt}; recording without ground truth")
                    gt = None
            if args.labels and scene not in labelled:
                print(
                    f"scene {scene}: no label file in {args.labels}; recording without its labels"
                )
            elif scene in labelled and not cameras:  # the KITTI protocol matches 2D boxes
                print(f"scene {scene}: no camera in {args.input}; recording without its labels")
            path = saves.get(scene)
            partial = None if path is None else partial_path(path)  # renamed at the end
            if partial is not None and path is not None:
                staged.append((partial, path))
            rec = new_recording(scene, path=partial)
            if url:
                rec.connect_grpc(url, default_blueprint=debug_blueprint(cameras))
            first, last = frames[0].frame_id, frames[-1].frame_id
            description = (
                f"- detections: `{args.input}`, scene `{scene}`, frames {first}..{last}"
                f" ({len(frames)} frames)\n- ground truth: `{args.gt or 'none'}`"
                f"\n- labels: `{args.labels or 'none'}`\n- config: `{args.config}`"
                f"\n- score profile: `{args.profile or 'none (detection_score as given)'}`"
            )
            result = record_scene(
                frames,
                config,
                gt,
                rec=rec,
                labels_dir=args.labels if scene in labelled else None,
                images=images,
                input_description=description,
                motion_metrics=not args.no_motion,
                live=bool(url),
            )
            rec.flush()
            rec.disconnect()  # (the server keeps what it got for the viewers)
            _print_result(result)
    for _, saved in staged:
        print(f"wrote {saved}  (open it with: rerun {saved})")


def _print_result(result: object) -> None:
    from viz.record import RecordResult

    assert isinstance(result, RecordResult)
    ev = result.id_evaluation
    line = (
        f"scene {result.scene}: {result.counts.get('frames', 0)} frames, "
        f"{len(result.track_ids)} tracks"
    )
    if ev is not None:
        line += ", " + ", ".join(
            f"{c}: {n['IDSW']} ID switches, {n['Frag']} fragmentations"
            for c, n in ev.counts.items()
        )
    print(line)
