"""Where the KITTI kit is by default, and the up-front checks that turn a wrong path or a missing
folder into one line naming the folder and the flag that fixes it."""

from __future__ import annotations

import argparse
import ipaddress
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from tracker.errors import InputError

if TYPE_CHECKING:
    pass

#: Environment variable naming the KITTI tracking kit (the tests honour it too).
KITTI_ROOT_ENV = "MCTRACK_KITTI_ROOT"
#: The kit next to the project checkout (``<checkout>/../shared/data/kitti/tracking``), so the
#: default does not depend on the working directory.
CHECKOUT_KITTI_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti" / "tracking"


def default_kitti_root() -> Path:
    """``$MCTRACK_KITTI_ROOT``, else the kit next to the checkout."""
    env = os.environ.get(KITTI_ROOT_ENV)
    return Path(env) if env else CHECKOUT_KITTI_ROOT


def kitti_root_help() -> str:
    return (
        "the KITTI tracking folder (holds training/calib, detections/); default: "
        f"${KITTI_ROOT_ENV} if set, else the kit next to the checkout "
        f"(now: {default_kitti_root()})"
    )


def add_kitti_root_argument(parser: argparse.ArgumentParser) -> None:
    """``--kitti-root DIR``; None unless given (:func:`default_kitti_root` is read at run time)."""
    parser.add_argument(
        "--kitti-root", type=Path, default=None, metavar="DIR", help=kitti_root_help()
    )


def add_detector_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--detector",
        default="pointrcnn",
        help="detections folder under <root>/detections/ (pointrcnn, virconv, second_iou, ...)",
    )


IMAGE_DETECTOR_HELP = (
    "2D boxes of an image detector, <root>/detections/NAME/<split>/<Class>/<seq>.txt "
    "(frame,x1,y1,x2,y2,score; e.g. rrc_2d): each detection takes the one overlapping its own 2D "
    "box most (IoU >= 0.5)"
)


def check_image_detector(
    root: Path,
    name: str | None,
    split: str = "training",
    *,
    classes: Sequence[str] = (),
    seqs: Sequence[str] | None = None,
) -> None:
    """InputError unless ``--image-detector NAME`` names a folder of the kit (or is absent)
    holding 2D boxes: a ``<Class>/`` folder of one of ``classes``, whose first file of ``seqs``
    (default: the split's) starts with a line of 6 columns. A 3D detector's folder (one
    ``<seq>.txt`` per sequence, or per-class files of 15 columns) is refused here, once, rather
    than warned about or failed in every sequence after the work."""
    from tracker.io.convert.kitti import CLASS_FOLDERS, IMAGE_DET_COLUMNS

    folder = root / "detections" / str(name) / split
    if name is None:
        return
    if not folder.is_dir():
        found = sorted(p.name for p in (root / "detections").glob("*") if p.is_dir())
        raise InputError(
            f"{folder}: image detections not found; --image-detector names a folder under "
            f"{root / 'detections'} (found: {', '.join(found) or 'none'})"
        )
    layout = f"--image-detector names a folder of <Class>/<seq>.txt ({','.join(IMAGE_DET_COLUMNS)})"
    names = [CLASS_FOLDERS.get(c, c) for c in classes]
    present = [n for n in names if (folder / n).is_dir()]
    if names and not present:
        held = " (it holds <seq>.txt files: a 3D detector's, for --detector?)"
        raise InputError(
            f"{folder}: no {'/, '.join(names)}/ folder of 2D boxes"
            f"{held if any(folder.glob('*.txt')) else ''}; {layout}"
        )
    if seqs is None:
        seqs = sorted(p.stem for p in (root / split / "calib").glob("*.txt"))
    first = next(
        (f for n in present for s in seqs if (f := folder / n / f"{s}.txt").is_file()), None
    )
    if first is None:
        return  # (each sequence says which image boxes it has not)
    try:
        with first.open() as text:
            line_no, line = next(((i, t) for i, t in enumerate(text, 1) if t.strip()), (0, ""))
    except (OSError, UnicodeDecodeError):
        return  # (the sequence's own read reports it)
    row = line.split(",")
    if row[-1].strip() == "":
        row.pop()  # (a trailing separator, as the reader takes it)
    if line_no and len(row) != len(IMAGE_DET_COLUMNS):
        raise InputError(
            f"expected {len(IMAGE_DET_COLUMNS)} comma-separated columns, got {len(row)}: not "
            f"2D boxes (a 3D detector's file?); {layout}",
            path=first,
            line=line_no,
            field="columns",
        )


def check_kitti_root(
    root: Path,
    *,
    split: str = "training",
    seqs: Sequence[str] | None = None,
    poses: str | None = "orbslam3",
    detector: str | None = "pointrcnn",
    detector_flag: str = "--detector NAME",
) -> None:
    """Raise :class:`InputError` naming the first missing piece of a KITTI layout and the flag
    that fixes it (``detector_flag``: how the calling command names detectors); the converter's
    own checks then only see files that exist."""
    flag = f"--kitti-root (or ${KITTI_ROOT_ENV})"
    seqs = [s.zfill(4) if s.isdigit() else s for s in (str(s).strip() for s in seqs or ())]
    if not root.is_dir():
        raise InputError(f"{root}: KITTI folder not found; pass {flag}")
    calib = root / split / "calib"
    if not calib.is_dir():
        raise InputError(
            f"{calib}: not found; {flag} must be the kitti/tracking folder "
            f"(with {split}/calib, {split}/label_02, detections/)"
        )
    for seq in seqs:
        if not (calib / f"{seq}.txt").is_file():
            here = sorted(p.stem for p in calib.glob("*.txt"))
            span = f"{here[0]}, ..., {here[-1]}" if len(here) > 12 else ", ".join(here) or "none"
            raise InputError(
                f"{calib / f'{seq}.txt'}: no calibration for sequence {seq} (--seqs; this "
                f"{split} split has {len(here)}: {span})"
            )
    if detector is not None:
        det_dir = root / "detections" / detector / split
        if not det_dir.is_dir() and det_dir.parent.is_dir():
            raise InputError(
                f"{det_dir}: not found; a detector's files go in detections/{detector}/{split}/ "
                f"(one <seq>.txt per sequence, or the other layouts of docs/detectors.md)"
            )
        if not det_dir.is_dir():
            found = sorted(p.parent.name for p in (root / "detections").glob(f"*/{split}"))
            raise InputError(
                f"{det_dir}: detections not found; pass {detector_flag} "
                f"(found: {', '.join(found) or 'none'})"
            )
    if poses == "orbslam3":
        pose_dir = root / split / "pose_orbslam3"
        if not pose_dir.is_dir():
            raise InputError(
                f"{pose_dir}: not found (official KITTI downloads have no ORB-SLAM3 poses); "
                "pass --poses none to track in the camera frame, or --poses DIR for pose files"
            )
        missing = [s for s in seqs if not (pose_dir / f"{s}.txt").is_file()]
        if missing:
            raise InputError(
                f"{pose_dir / f'{missing[0]}.txt'}: no poses for sequence {missing[0]}; "
                "pass --poses none or --poses DIR"
            )
    elif poses is not None and not Path(poses).is_dir():
        raise InputError(f"{poses}: --poses folder not found (orbslam3, none or a folder)")


def add_mode_argument(parser: argparse.ArgumentParser, note: str = "") -> None:
    """``--mode online|offline``; default: the config's own mode."""
    parser.add_argument(
        "--mode",
        choices=["online", "offline"],
        default=None,
        help="tracking mode (default: the config's); offline: the config's offline variant, "
        "each built-in in its base chain with one replaced by it (kitti -> kitti_offline); "
        "online: each built-in offline variant in it replaced by its base (kitti_offline -> "
        "kitti)" + note,
    )


def sequence_list(text: str) -> list[str]:
    """argparse type of ``--seqs``: comma-separated sequence names, digits zero-padded to four
    ("1" -> "0001"). An empty list or a sequence named twice is a usage error (one line, exit 2)
    rather than a run that tracks nothing or a sequence twice."""
    from tracker.io.fileio import case_collision

    names = [s.zfill(4) if s.isdigit() else s for s in (p.strip() for p in text.split(",")) if s]
    unique_names(names, text, "sequences")
    found = case_collision(names)  # (a file per sequence: data/<seq>.txt)
    if found is not None:
        raise argparse.ArgumentTypeError(
            f"sequences {found[0]!r} and {found[1]!r} differ only in case: their files would be "
            "one on a case-insensitive filesystem (macOS, Windows)"
        )
    return names


def unique_names(names: list[str], text: str, what: str) -> list[str]:
    """``names`` as read from ``text`` by an argparse type: at least one, each once (else a
    usage error naming ``what`` was expected, or the names given twice)."""
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated {what}, got {text!r}")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise argparse.ArgumentTypeError(f"{', '.join(twice)} given more than once in {text!r}")
    return names


def class_list(text: str) -> list[str]:
    """argparse type of ``--classes``: comma-separated class names (case and known spellings
    as :func:`tracker.categories.category_index` reads them), each once, as the canonical
    names; an unknown name is a usage error listing the known ones."""
    from tracker.categories import CATEGORIES, category_index

    known = [c for c in CATEGORIES if c != "dontcare"]  # (an ignore region, not a class)
    names = [p.strip() for p in text.split(",") if p.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"expected comma-separated classes, got {text!r}")
    unknown = [
        n for n in names if category_index(n) < 0 or CATEGORIES[category_index(n)] not in known
    ]
    if unknown:
        raise argparse.ArgumentTypeError(
            f"unknown class {unknown[0]!r} (known: {', '.join(known)})"
        )
    canonical = list(dict.fromkeys(CATEGORIES[category_index(n)] for n in names))
    if len(canonical) < len(names):
        raise argparse.ArgumentTypeError(f"a class is given more than once in {text!r}")
    return canonical


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (argparse prints the message as a usage error, exit 2)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0 (argparse prints the message as a usage error, exit 2)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def unit_interval(text: str) -> float:
    """argparse type: a number in [0, 1], a score threshold (NaN, which filters nothing, and a
    value above 1, which filters everything, are usage errors, exit 2)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return value


def _port(text: str, lowest: int) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not lowest <= value <= 65535:  # (else socket's OverflowError, reported as a bug)
        raise argparse.ArgumentTypeError(f"expected a port {lowest}..65535, got {text!r}")
    return value


def port_number(text: str) -> int:
    """argparse type of a server's port: 1..65535."""
    return _port(text, 1)


def port_or_any(text: str) -> int:
    """argparse type of a server's port, 0 for any free one: 0..65535."""
    return _port(text, 0)


def host_address(text: str) -> str:
    """argparse type of ``--host`` (view's viewers, report --serve): an IP address
    (``localhost``: 127.0.0.1). The rerun binary's ``--bind`` takes no host name: it exited
    with status 2, unexplained; report --serve, which took one, takes the same addresses."""
    if text.strip().lower() == "localhost":
        return "127.0.0.1"
    try:
        return str(ipaddress.ip_address(text.strip()))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an IP address (127.0.0.1, 0.0.0.0, ::1) or localhost, got {text!r}"
        ) from None


def refuse_unused_option(option: str, value: object, needs: str, instead: str) -> None:
    """A usage error for ``option`` given (``value`` is not None: the parser's default is None)
    where it has no effect, before any work: it was ignored without a word. ``needs`` names the
    options it goes with (and what it is), ``instead`` what the command does without them."""
    if value is not None:
        raise InputError(f"{option} {value}: only with {needs}; {instead}")


#: Printed once when a run has no ego poses.
NO_POSES_NOTE = (
    "note: --poses none: no ego motion, so positions and velocities are relative to the moving "
    "ego vehicle (not the ground), and motion metrics compare against ego-relative ground truth"
)
