"""mctrack: 3D multi-object tracking (MCTrack) for KITTI, nuScenes and Waymo, with motion
metrics and a Rerun visual debugger.

Start with `mctrack demo` (tracks a bundled KITTI sequence and writes demo.rrd); then
`mctrack COMMAND --help` for any command below."""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import logging
import os
import re
import select
import sys
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from app.common import (
    EXIT_VIEWER_FAILED,
    ctrl_c_deferred,
    folders_to_make,
    remove_made_folders,
)
from tracker.errors import InputError, ViewerError

# subcommand -> (module, help). Each module has add_arguments(parser) and run(args) -> int,
# imported only when used so `mctrack validate` never pays for rerun or trackeval.
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("app.demo", "track the bundled sample sequence, write a recording, print a summary"),
    "validate": ("app.validate", "check a BaseVersion file and print a summary"),
    "convert": ("app.convert", "convert a dataset's detections and labels to BaseVersion"),
    "track": ("app.track", "run the tracker on a BaseVersion file"),
    "kitti": ("app.kitti", "convert, track and evaluate KITTI tracking sequences"),
    "nuscenes": ("app.nuscenes", "convert, track and evaluate nuScenes (official devkit metrics)"),
    "waymo": ("app.waymo", "convert and track Waymo segments, write the per-segment result npz"),
    "calibrate": (
        "app.calibrate",
        "fit a detector's score calibration profile (raw score -> P(true positive)) on labels",
    ),
    "tune": (
        "app.tune",
        "cross-validated search of one class's settings over detectors (Optuna)",
    ),
    "robustness": (
        "app.robustness",
        "HOTA per class under seeded detection noise (drops, jitter, false positives)",
    ),
    "bench": ("app.bench", "tracker speed benchmark (frames/s, ms/frame, peak memory)"),
    "eval": ("app.eval", "evaluate a tracks file: KITTI static metrics and motion metrics"),
    "view": ("app.view", "run the tracker with the Rerun visual debugger (file, viewer or web)"),
    "shots": ("app.shots", "headless screenshots of a recording at its ID switches and lag"),
    "inspect": ("app.inspect", "open a recording in the viewer at one ID event, focused"),
    "compare": ("app.compare", "A/B diff of two runs: ID events fixed / introduced / kept"),
    "report": ("app.report", "a static HTML report of a run (optionally vs another; --serve)"),
}

EPILOG = """examples:
  mctrack demo                                   track the bundled sample, write ./demo.rrd
  mctrack kitti --out runs/kitti                 the 11 KITTI validation sequences, evaluated
  mctrack track detections.json --out runs/t     any BaseVersion detections file
  mctrack view detections.json --gt gt.json      the same, recorded for the Rerun viewer

exit status: 0 success, 2 bad input or usage (one line on stderr: the file and what to do),
1 an unexpected error (a bug: re-run with --debug for the traceback and report it), 3 no
renderer for `shots` (a Vulkan driver), 4 a viewer or its server did not start or answer (view
--spawn / --serve-web, inspect, shots, report --serve), 141 the reader of the output closed it
early (`| head`)."""

#: Exit status for bad input (a wrong path, a missing or malformed file, a wrong flag), as
#: argparse uses for usage errors.
EXIT_INPUT = 2
#: Exit status for an unexpected error (a bug).
EXIT_BUG = 1
#: Exit status when the reader of stdout closed it early (a shell's for SIGPIPE).
EXIT_PIPE = 141


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Shows every option's default (unless the help already says it or there is none)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or "default" in text.lower()
            or any(default is d for d in (None, False, argparse.SUPPRESS))  # (not 0: 0 == False)
            or not action.option_strings
            or (isinstance(default, list | tuple) and not default)
        ):
            return text
        if isinstance(default, list | tuple):
            return f"{text} (default: {','.join(map(str, default))})"
        return f"{text} (default: %(default)s)"


def _add_formatter(parser: argparse.ArgumentParser) -> None:
    """The same help formatter on a subcommand's own sub-subcommands (``convert kitti``)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                child.formatter_class = HelpFormatter
                _add_formatter(child)


def _plain(doc: str) -> str:
    """A module docstring as help text: without reST roles and backquotes."""
    return re.sub(r":\w+:`([^`]*)`", r"\1", doc).replace("`", "").strip()


class Parser(argparse.ArgumentParser):
    """A usage error is one line, as every other error (argparse prints the usage first)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _command_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> Parser:
    """The (sub-)subcommand's parser that ``args`` were parsed by (``convert kitti``)."""
    while True:
        chosen = None
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                chosen = action.choices.get(getattr(args, action.dest or "", None) or "")
        if chosen is None:
            return parser  # type: ignore[return-value]
        parser = chosen


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="mctrack", description=__doc__, epilog=EPILOG, formatter_class=HelpFormatter
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument(
        "--debug",
        action="store_true",
        help="on an error, also show the Python traceback (the exit status stays the same)",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue  # a subcommand not built yet is absent, not stubbed
        sub_parser = sub.add_parser(
            name,
            help=help_text,
            description=_plain(module.__doc__ or help_text),
            formatter_class=HelpFormatter,
        )
        module.add_arguments(sub_parser)
        sub_parser.add_argument(  # also accepted after the subcommand
            "--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS
        )
        _add_formatter(sub_parser)
        sub_parser.set_defaults(_run=module.run)
    return parser


def error_message(exc: BaseException) -> tuple[str, int] | None:
    """One line for an error a user can cause (bad path, missing or malformed file, bad flag
    value), with its exit status; None for anything else (a bug)."""
    if isinstance(exc, InputError):
        return str(exc), EXIT_INPUT
    if isinstance(exc, ViewerError):
        return str(exc), EXIT_VIEWER_FAILED
    if isinstance(exc, FileNotFoundError):
        if exc.filename is None:  # raised with a message of our own
            return str(exc), EXIT_INPUT
        return f"{exc.filename}: not found (check the path)", EXIT_INPUT
    if isinstance(exc, FileExistsError):
        return f"{exc.filename}: exists and is not a folder; pass another --out", EXIT_INPUT
    if isinstance(exc, IsADirectoryError):
        return f"{exc.filename}: is a folder, expected a file", EXIT_INPUT
    if isinstance(exc, NotADirectoryError):
        return f"{exc.filename}: expected a folder", EXIT_INPUT
    if isinstance(exc, PermissionError):
        return f"{exc.filename}: permission denied", EXIT_INPUT
    if isinstance(exc, ModuleNotFoundError) and exc.name:
        return (
            f"needs the Python package {exc.name!r}, which is not installed: run the README's "
            "install line (python -m pip install -e '.[dev,nuscenes]')",
            EXIT_INPUT,
        )
    if isinstance(exc, json.JSONDecodeError):
        return f"malformed JSON ({exc})", EXIT_INPUT
    if isinstance(exc, UnicodeDecodeError):
        return f"not a text file ({exc.reason})", EXIT_INPUT
    if type(exc).__name__ == "TrackEvalException":  # (not imported: trackeval is heavy)
        # TrackEval refuses a file it cannot score; its messages span lines
        return f"TrackEval: {' '.join(str(exc).split())}", EXIT_INPUT
    if isinstance(exc, OSError) and exc.filename:
        return f"{exc.filename}: {exc.strerror or exc}", EXIT_INPUT
    return None


def _kernel_stamp() -> tuple[Path, str] | None:
    """Where the warm-up stamp lives (numba's cache folder of ``tracker/kernels``) and what it
    must hold: a hash of every source with a compiled kernel. None when nothing compiles."""
    import hashlib
    import os

    if os.environ.get("MCTRACK_NUMBA", "1") == "0" or importlib.util.find_spec("numba") is None:
        return None
    package = Path(importlib.import_module("tracker").__file__ or "").parent
    digest = hashlib.sha256()
    for source in sorted(package.rglob("*.py")):
        text = source.read_bytes()
        if b"numba.njit" in text:
            digest.update(source.relative_to(package).as_posix().encode() + b"\0" + text)
    kernels = package / "kernels"
    cache_root = os.environ.get("NUMBA_CACHE_DIR")
    # numba's user-provided location mirrors the source folder
    folder = (
        Path(cache_root) / str(kernels.resolve()).lstrip(os.sep)
        if cache_root
        else kernels / "__pycache__"
    )
    return folder / "mctrack_kernels.stamp", digest.hexdigest()


def kernels_cold() -> bool:
    """True when the tracker's compiled kernels have not been warmed up since their sources last
    changed (the first run of a checkout or install: numba caches them next to the source, or
    after an edit): loading them then compiles for ~20 s.
    A stamp holding the sources' hash is written after each warm-up; comparing file times
    instead missed an edited helper whose own cache index numba never rewrites."""
    stamp = _kernel_stamp()
    if stamp is None:
        return False
    path, digest = stamp
    try:
        return path.read_text(encoding="utf-8").strip() != digest
    except (OSError, UnicodeDecodeError):
        return True


def _mark_kernels_warm() -> None:
    stamp = _kernel_stamp()
    if stamp is None:
        return
    path, digest = stamp
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(digest + "\n", encoding="utf-8")
    except OSError:  # a read-only install: numba cannot cache there either; warn each run
        pass


def _kernel_cache_note(folder: Path | None) -> str:
    """Where the compiled kernels are kept, and so when they compile again: the cache sits
    with the source (or under $NUMBA_CACHE_DIR, by the source's path), so each checkout or
    install compiles once, not each machine."""
    if folder is None:
        return "not cached"
    existing = next((p for p in (folder, *folder.parents) if p.exists()), folder)
    if not os.access(existing, os.W_OK):
        # (numba then caches in its user-wide folder: later runs load them, but this note,
        # whose stamp cannot be kept here, comes back)
        return (
            f"cached in numba's user-wide folder: {folder} is not writable (NUMBA_CACHE_DIR "
            "chooses the folder)"
        )
    return (
        f"cached in {folder}: later runs of this copy of the source load them, until a "
        "kernel's source changes"
    )


#: Subcommands that run the tracker (and so load its compiled kernels).
TRACKING_COMMANDS = frozenset(
    {"demo", "track", "kitti", "nuscenes", "waymo", "view", "bench", "tune", "robustness"}
)


def _warm_kernels() -> None:
    """Compile the kernels up front, saying so, instead of a silent pause in the first frame."""
    if not kernels_cold():
        return
    stamp = _kernel_stamp()
    folder = stamp[0].parent if stamp is not None else None
    print(
        f"mctrack: compiling the tracker kernels, 20-60 s ({_kernel_cache_note(folder)})...",
        file=sys.stderr,
        flush=True,
    )
    from tracker.geometry import prepare_kernels
    from tracker.kernels import load

    start = time.perf_counter()
    load()
    prepare_kernels()
    _mark_kernels_warm()
    print(f"mctrack: kernels compiled in {time.perf_counter() - start:.0f} s", file=sys.stderr)


#: The options that name what a command writes: an output folder, or a file (whose folder it
#: makes). A run that ends in an error leaves no folder it made for them (only empty ones go).
OUTPUT_OPTIONS = ("--out", "--gt-out", "--json", "--save")


def _output_paths(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[str]:
    """The paths the command's output options were given (or default to)."""
    paths = []
    for action in _command_parser(parser, args)._actions:
        if set(action.option_strings) & set(OUTPUT_OPTIONS) and action.nargs != 0:  # (a flag)
            value = getattr(args, action.dest, None)
            if isinstance(value, str | os.PathLike) and str(value):
                paths.append(str(value))
    return paths


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # named by the command they were given to, not by `mctrack`
        _command_parser(parser, args).error(f"unrecognized arguments: {' '.join(unknown)}")
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s %(name)s: %(message)s",
    )
    # commands make --out before they have read all their inputs (a bad --out fails in a
    # second, not after the work), and some inputs are refused only once read: a run that
    # ends in an error removes the empty folders it made, never one that was there before
    made = folders_to_make(_output_paths(parser, args))
    status = EXIT_BUG  # (if an error escapes, as with --debug)
    try:
        status = _run_command(args)
    finally:
        if status != 0:
            with ctrl_c_deferred():
                remove_made_folders(made)
    return status


def _run_command(args: argparse.Namespace) -> int:
    """Run the parsed command; an error is one line on stderr and its exit status."""
    try:
        if args.command in TRACKING_COMMANDS:
            _warm_kernels()
        status = int(args._run(args))
        sys.stdout.flush()  # (a reader that went away shows here, not at the interpreter's exit)
        return status
    except KeyboardInterrupt:
        print(f"mctrack {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if isinstance(exc, BrokenPipeError) and _stdout_reader_gone():
            # the reader of the output went away (`mctrack validate F | head -2`): stop
            # quietly, as a Unix tool killed by SIGPIPE does, with its status (128 + 13)
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return EXIT_PIPE
        known = error_message(exc)
        if args.debug:
            if known is None:
                raise  # a bug: its traceback, exit 1 (and a debugger's post-mortem)
            # the traceback too, but the exit status of the error (2 for input and usage), so
            # a script that checks it behaves the same with --debug
            traceback.print_exc()
        if known is not None:
            message, status = known
            print(f"mctrack {args.command}: error: {message}", file=sys.stderr)
            return status
        print(
            f"mctrack {args.command}: unexpected error: {type(exc).__name__}: {exc} "
            "(a bug: re-run with --debug for the traceback and report it)",
            file=sys.stderr,
        )
        return EXIT_BUG


def _stdout_reader_gone() -> bool:
    """Whether stdout is a pipe whose reader closed it (poll says POLLERR), as opposed to another
    pipe of the command's breaking (a worker's, the viewer's): that one is a bug to report."""
    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(event & select.POLLERR for _, event in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # (no poll on this platform, no stdout fd)
        return False


if __name__ == "__main__":
    sys.exit(main())
