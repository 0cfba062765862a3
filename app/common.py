"""Helpers shared by the subcommands (below every app module: no app imports here)."""

from __future__ import annotations

import contextlib
import logging
import os
import resource
import shlex
import signal
import threading
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

from tracker.errors import InputError

if TYPE_CHECKING:
    from tracker.calibration import ScoreProfile
    from tracker.config import TrackerConfig
    from tracker.events import TrackOutput
    from tracker.frame import Frame

LOG = logging.getLogger("mctrack")
SELF_PROFILE = "self"  # --profile self: fitted without labels on the run's detections
NO_PROFILE = "none"  # --profile none: the uncalibrated fallback
#: Exit status when a viewer or its server did not start or answer (no display, the binary
#: exited, no answer): the environment, not the input (app.cli documents every status).
EXIT_VIEWER_FAILED = 4


def peak_rss_mb() -> float:
    """This process's peak resident memory, MB.

    Linux's VmHWM (the high-water mark of this process image); ``ru_maxrss`` would also count
    the parent's memory when this process was started by fork + exec (a benchmark run from a
    script that already holds hundreds of MB would report the script's peak).
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024.0, 1)  # kB
    except OSError:
        pass
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)


def log_self_profile(profile: ScoreProfile, classes: Sequence[str]) -> None:
    """Say, loudly, which classes a label-free profile calibrated, and each class whose boxes all
    score the same (as `mctrack calibrate` does)."""
    from tracker.eval.calibrate import one_score_warning

    parts = []
    for name in classes:
        q = profile.quality.get(name, {})
        parts.append(
            f"{name} {q.get('kept', 'no: no detections')} ({q.get('detections', 0)} boxes)"
        )
    LOG.warning(
        "self-calibration of %r without labels, kept per class: %s",
        profile.detector,
        "; ".join(parts),
    )
    for name in classes:  # (why a class was not kept, or what its map of one knot means)
        one_score = one_score_warning(profile.detector, name, profile.quality.get(name, {}))
        if one_score is not None:
            LOG.warning("%s", one_score)


def score_source(
    config: TrackerConfig, detector: str, profile: Path | str | None
) -> tuple[bool, ScoreProfile | None, str]:
    """Whether to recalibrate the scores, with which profile (None: the fallback, or the
    self-calibration the caller fits, as ``mctrack kitti`` and ``mctrack robustness`` do), and
    a note of what was used. Resolved once by the driver; each scene task applies it to its own
    frames."""
    from tracker.calibration import resolve_profile, warn_other_detector
    from tracker.config import ScoreSource

    if config.scores is ScoreSource.AS_GIVEN:
        return False, None, "none (scores as converted; the config asks for scores = 'as_given')"
    if profile == NO_PROFILE:
        return True, None, "none (--profile none): sigmoid(raw) or raw probability"
    if profile == SELF_PROFILE:
        return True, None, "--profile self"
    found = resolve_profile(detector, profile)
    if found is not None and profile is not None:  # a profile the user chose
        warn_other_detector(found, detector)
    if found is None:
        return True, None, f"none found for {detector!r}: fallback sigmoid(raw) or raw probability"
    return True, found, f"profile {profile or detector + ' (shipped)'}"


def self_calibrated_note(profile: object, detector: str, fitted: ScoreProfile) -> str:
    """The summary's note of a label-free profile fitted on a run's own detections."""
    why = "--profile self" if profile == SELF_PROFILE else f"none for {detector!r}"
    kept = ", ".join(fitted.maps) or "none"
    return (
        f"{why}: self-calibrated without labels (classes {kept}; others sigmoid(raw) or raw "
        "probability)"
    )


def profile_argument(value: str | None) -> Path | str | None:
    """``--profile`` as given: ``self``, ``none`` or absent as they are, else a path (a file,
    or a shipped profile's name, resolved later)."""
    return value if value in (SELF_PROFILE, NO_PROFILE) or not value else Path(value)


def command_line(words: Sequence[object]) -> str:
    """``mctrack WORDS...``, each word quoted for a POSIX shell: the line a record keeps so the
    run can be repeated (paths with spaces included)."""
    return shlex.join(["mctrack", *map(str, words)])


def _own_file(folder: Path, path: Path) -> bool:
    """A file (or a link) inside ``folder`` itself: not reached through a linked sub-folder,
    which may lead anywhere."""
    return (path.is_file() or path.is_symlink()) and not any(
        (folder / Path(*path.relative_to(folder).parts[:i])).is_symlink()
        for i in range(1, len(path.relative_to(folder).parts))
    )


def _outputs(folder: Path, patterns: Sequence[str]) -> set[Path]:
    """The files in ``folder`` matching ``patterns`` (globs relative to it), own files only."""
    return {p for pattern in patterns for p in folder.glob(pattern) if _own_file(folder, p)}


def refuse_inputs_among_outputs(
    folder: Path,
    patterns: Sequence[str],
    inputs: Mapping[str, Path | None],
    written: Sequence[str] | None = None,
) -> None:
    """InputError when an input (``inputs``: option -> path) is, or holds, a file the run writes
    or removes in ``folder`` (``patterns``: globs relative to it, as for
    :func:`remove_earlier_outputs`): `--detections OUT/results.json --out OUT` would be deleted
    or overwritten by the run that reads it. ``written``: the patterns of those the run writes
    (default: all); the others it removes as an earlier run's. Called before any work."""
    root = folder.resolve()
    # the same glob (and the same files) as remove_earlier_outputs, so the two never disagree
    found = sorted({p.resolve() for p in _outputs(folder, patterns)})
    own = {p.resolve() for p in _outputs(folder, patterns if written is None else written)}
    for option, path in inputs.items():
        if path is None:
            continue
        target = Path(path).resolve()
        if not target.is_relative_to(root):  # (outside --out: the run writes nothing there)
            continue
        for file in found:
            if file.is_relative_to(target):
                what = "is" if file == target else f"holds {file.relative_to(root).as_posix()},"
                kind = (
                    f"a file this run writes in {folder}"
                    if file in own
                    else f"an earlier run's output, which this run removes from {folder}"
                )
                raise InputError(f"{path}: {option} {what} {kind}: move it, or give another --out")


def remove_earlier_outputs(folder: Path, patterns: Sequence[str]) -> int:
    """Delete the files of an earlier run in ``folder`` that match ``patterns`` (globs relative
    to it), then the sub-folders that leaves empty; other files stay. A run into the folder of
    an earlier one calls this once its inputs are accepted, so the folder never mixes two runs
    (a level or sequence the new run leaves out would keep its old results). Returns how many
    files went."""
    earlier = sorted(_outputs(folder, patterns))
    for path in earlier:
        path.unlink()
    root = folder.resolve()
    for parent in sorted({p.parent for p in earlier}, key=lambda p: -len(p.parts)):
        while parent.resolve() != root and parent.is_dir() and not any(parent.iterdir()):
            parent.rmdir()
            parent = parent.parent
    if earlier:
        LOG.info("%s: removed %d files of an earlier run", folder, len(earlier))
    return len(earlier)


def folders_to_make(paths: Iterable[Path | str]) -> list[Path]:
    """The folders a run writing ``paths`` (output folders, or output files) may make: each
    path and its parents that do not exist yet, deepest first. Taken before the run, for
    :func:`remove_made_folders`."""
    missing: set[Path] = set()
    for path in paths:
        path = Path(path).absolute()  # (still true if the run changes folder)
        for folder in (path, *path.parents):
            if os.path.lexists(folder):
                break
            missing.add(folder)
    return sorted(missing, key=lambda p: (-len(p.parts), p))


def remove_made_folders(folders: Sequence[Path]) -> None:
    """After a refused or failed run: remove the folders it made (``folders``, from
    :func:`folders_to_make`) that are empty, so it leaves no folder of its own behind. A folder
    that existed before is not among them; one that holds a file (the run's partial output, or
    anyone's) stays, and so do its parents."""
    for folder in folders:
        with contextlib.suppress(OSError):  # not empty, never made (an output file), or gone
            folder.rmdir()


def _pattern_folder(pattern: str) -> str:
    """The fixed folder a glob's files are in (``eval/*.json``: ``eval``; ``*.json``: ``.``)."""
    parts = PurePosixPath(pattern).parent.parts
    fixed = []
    for part in parts:
        if any(c in part for c in "*?["):
            break
        fixed.append(part)
    return "/".join(fixed) or "."


@contextlib.contextmanager
def outputs_removed_on_failure(
    folder: Path, patterns: Sequence[str], folders: Sequence[str] = ()
) -> Iterator[None]:
    """If the block fails (an error, Ctrl-C), delete what it wrote in ``folder``: the files
    matching ``patterns`` (globs relative to it, as for :func:`remove_earlier_outputs`) that
    are new or rewritten since it began, then the folders it made for them (each pattern's
    folder, and ``folders``: ones a library makes, relative to ``folder``) that this leaves
    empty. A failed run so leaves no partial outputs of its own (a results file without the
    summary that marks a run complete); files it did not write stay."""
    before = _stamps(_outputs(folder, patterns))
    made = folders_to_make(
        [folder / _pattern_folder(p) for p in patterns] + [folder / f for f in folders]
    )
    # (the folders a pattern's files are in: one made below a pattern's fixed folder, e.g.
    # results/vehicle/ of results/*/*.npz, goes too when the run's files leave it empty; one
    # on the way that was there, results/ itself, stays even if empty)
    existed = {
        d
        for p in patterns
        for parts in [PurePosixPath(p).parent.parts]
        for i in range(1, len(parts) + 1)
        for d in folder.glob("/".join(parts[:i]))
        if d.is_dir()
    }
    try:
        yield
    except BaseException:
        with ctrl_c_deferred():  # (a second Ctrl-C does not stop the clean-up half done)
            after = _stamps(_outputs(folder, patterns))
            removed = sorted(p for p, stamp in after.items() if before.get(p) != stamp)
            for path in removed:
                path.unlink(missing_ok=True)
            for parent in sorted({p.parent for p in removed}, key=lambda p: -len(p.parts)):
                while parent != folder and parent not in existed:
                    try:
                        parent.rmdir()
                    except OSError:  # (not empty: another file of the run's, or anyone's)
                        break
                    parent = parent.parent
            remove_made_folders(made)
        raise


@contextlib.contextmanager
def ctrl_c_deferred() -> Iterator[None]:
    """Ctrl-C ignored during the block (in the main thread, which alone handles signals): what
    an interrupted run must finish before it ends (stop its workers, remove its outputs) is
    not itself cut short by a second Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)


def _stamps(paths: Iterable[Path]) -> dict[Path, tuple[int, int]]:
    """Each file's inode and modification time: a file replaced or rewritten changes them."""
    stamps = {}
    for path in paths:
        with contextlib.suppress(OSError):  # (gone meanwhile)
            st = path.lstat()
            stamps[path] = (st.st_ino, st.st_mtime_ns)
    return stamps


def warn_undetected_classes(detector: str, classes: Sequence[str]) -> None:
    """Say which tracked classes the detector has not a single box of (their HOTA is 0 for
    that reason, not the tracker's)."""
    if classes:
        LOG.warning(
            "detector %r has no %s detections in these sequences: nothing of that class is "
            "tracked (--classes names the classes to track)",
            detector,
            " or ".join(classes),
        )


#: The columns of the per-class metrics table `mctrack kitti` and `mctrack eval` print.
METRIC_COLUMNS = ("HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW", "FP", "FN", "Frag")
MOTION_COLUMNS = ("vae_deg", "vne_mps", "vir_ratio", "vse_mps", "vde_secs", "n_samples")


def print_metrics(metrics: Mapping[str, Mapping[str, object]], absent: Mapping[str, str]) -> None:
    """The per-class KITTI metrics table, then each class without ground truth and why."""
    print(f"{'class':<12}" + "".join(f"{c:>9}" for c in METRIC_COLUMNS))
    for cls, m in metrics.items():
        print(f"{cls:<12}" + "".join(f"{m[c]!s:>9}" for c in METRIC_COLUMNS))
    for cls, why in absent.items():
        print(f"{cls:<12}  absent: {why}")


def write_motion_metrics(
    detections: Mapping[str, Sequence[Frame]] | None,
    gt: Mapping[str, Sequence[Frame]],
    outputs: Mapping[str, Sequence[TrackOutput]],
    classes: Sequence[str],
    out: Path,
) -> dict[str, Any]:
    """A run's motion metrics, with ``out/motion.md`` and the velocity-curve PNG beside them
    (`mctrack kitti`, `nuscenes` and `waymo` alike)."""
    from tracker.eval.motion_eval import MOTION_PLOT, evaluate_motion, motion_report_lines
    from tracker.io.fileio import write_text_atomic

    motion = evaluate_motion(
        detections, gt, outputs, classes=list(classes), plot_path=out / MOTION_PLOT
    )
    write_text_atomic(
        out / "motion.md", ["\n".join(["# Motion metrics", "", *motion_report_lines(motion)])]
    )
    return motion


def print_motion(motion: object) -> None:
    """The motion metrics over all classes per estimator (or why there are none)."""
    if isinstance(motion, Mapping):
        print(f"{'motion (all)':<14}" + "".join(f"{c:>11}" for c in MOTION_COLUMNS))
        for est, rows in motion["metrics"].items():
            row = rows["all"]
            print(f"{est:<14}" + "".join(_cell(row[c]) for c in MOTION_COLUMNS))
    elif isinstance(motion, str):
        print(f"motion: {motion}")


def _cell(value: object) -> str:
    if value is None:
        return f"{'n/a':>11}"
    return f"{value:>11.3f}" if isinstance(value, float) else f"{value!s:>11}"
