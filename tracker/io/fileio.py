"""File I/O at the trust boundary.

Output: every file is written completely or not at all (a temporary file in the same folder,
fsynced, then renamed); temporary files stranded by a killed run are removed by the next write
to that folder, and its work folders in the system's temp folder by the next work folder made
(:func:`make_work_folder`). Input: ``.npz`` files are read without pickle and with a size cap
(:func:`load_npz`).
"""

from __future__ import annotations

import contextlib
import errno
import gzip
import hashlib
import io
import json
import math
import os
import re
import shutil
import stat
import tempfile
import time
import zipfile
import zlib
from collections.abc import Collection, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tracker.errors import InputError

TEMP_SUFFIX = ".tmp"
# Temp names are ``.<name>.<pid>.<random>.tmp``: a temp of a process that no longer runs is
# stranded (killed run) and removed by the next write to the folder; one of a live process
# (another run writing there now, or holding finished files until its set is complete, see
# :func:`staged_files`) is kept however old. Only a temp without a readable pid is removed by
# age, once older than this.
STALE_TEMP_SECS = 3600.0


def temp_name(path: Path) -> str:
    """The prefix of a temporary file for ``path`` (same folder, hidden, with our pid)."""
    return f".{path.name}.{os.getpid()}."


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # exists (another user's) or unparseable: keep it
    return not _zombie(pid)


def _zombie(pid: int) -> bool:
    """True when ``pid`` has exited and waits to be reaped (it writes nothing more; an orphan
    of a killed run can stay so a while). Linux's /proc; elsewhere False."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (OSError, UnicodeDecodeError):
        return False
    fields = text.rsplit(")", 1)[-1].split()  # (the command name may hold spaces or parens)
    return bool(fields) and fields[0] == "Z"


def remove_stale_temps(folder: str | Path, *, older_than_secs: float = STALE_TEMP_SECS) -> int:
    """Delete temporary files a killed run left in ``folder``; returns how many.

    A temp whose pid (in its name) is alive here is never deleted, however old: a long run may
    hold a finished file under its temporary name until the rest of its set is done. A temp
    without a readable pid goes once older than ``older_than_secs``."""
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    now = time.time()
    removed = 0
    for p in folder.glob(f".*{TEMP_SUFFIX}"):
        parts = p.name.rsplit(".", 3)  # ['.<name>', '<pid>', '<random>', 'tmp']
        ours = len(parts) == 4 and len(parts[0]) > 1 and parts[1].isdigit()  # (".1.x.tmp": no)
        pid = int(parts[1]) if ours else None
        try:
            if not p.is_file():
                continue
            if pid is not None:
                stale = not _pid_alive(pid)
            else:
                stale = now - p.stat().st_mtime > older_than_secs
            if stale:
                p.unlink()
                removed += 1
        except OSError:
            continue  # another process took it: not ours to report
    return removed


#: Work folders are ``mctrack-<kind>-<pid>-<random>`` in the system's temp folder ($TMPDIR):
#: intermediate files of a run (a tune's trial results, TrackEval's copies), removed when it
#: ends. A killed run cannot remove its own: the next work folder made removes it, but only a
#: folder that holds the marker a work folder is made with (:data:`WORK_MARKER`): a folder of
#: anyone else's named alike (``mctrack-kitti-20240101-baseline``) is never touched.
WORK_FOLDER_PREFIX = "mctrack-"
#: The kinds of work folder (make_work_folder refuses others): only these names are removed.
WORK_FOLDER_KINDS = frozenset(
    {
        "benchrecord", "bevids", "eval", "fnanatomy", "folds", "fpanatomy", "fptrim",
        "hotaceiling", "idsw", "inspect", "kill", "noise", "parallel", "profile", "record",
        "results", "shots", "speed", "trial", "tune", "viewer",
    }
)  # fmt: skip
# (mkdtemp's random part: 8 of tempfile's lower-case letters, digits and "_")
_WORK_FOLDER = re.compile(
    rf"mctrack-({'|'.join(sorted(WORK_FOLDER_KINDS))})-([1-9][0-9]*)-[a-z0-9_]{{8}}"
)
#: The file inside each work folder that says it is one, and whose: ``pid <pid>``, ``boot
#: <boot id>`` and ``pidns <pid namespace>`` lines (the last two where Linux's /proc has them).
WORK_MARKER = ".mctrack-work"
#: A work folder made under another boot or pid namespace (a temp folder shared with a
#: container), or where either is unknown: its pid says nothing here, so it goes only once
#: unchanged this long.
STALE_WORK_SECS = 86400.0


def _host_ids() -> dict[str, str]:
    """This boot's id and this process's pid namespace (Linux's /proc; elsewhere none): a pid
    is only meaningful within both."""
    ids = {}
    with contextlib.suppress(OSError):
        ids["boot"] = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    with contextlib.suppress(OSError):
        ids["pidns"] = os.readlink("/proc/self/ns/pid")
    return ids


def _work_marker(pid: int) -> str:
    return "".join(f"{k} {v}\n" for k, v in {"pid": str(pid), **_host_ids()}.items())


def make_work_folder(kind: str) -> Path:
    """A new private folder ``mctrack-<kind>-<pid>-<random>`` in the system's temp folder, for
    the caller to remove when done (``kind``: one of :data:`WORK_FOLDER_KINDS`). It holds its
    marker (:data:`WORK_MARKER`). The work folders of runs that no longer run (killed before
    they removed theirs) go first (:func:`remove_stale_work_folders`)."""
    if kind not in WORK_FOLDER_KINDS:
        raise ValueError(f"work folder kind {kind!r}: not one of WORK_FOLDER_KINDS")
    remove_stale_work_folders()
    folder = Path(tempfile.mkdtemp(prefix=f"{WORK_FOLDER_PREFIX}{kind}-{os.getpid()}-"))
    try:
        (folder / WORK_MARKER).write_text(_work_marker(os.getpid()))
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    return folder


@contextlib.contextmanager
def work_folder(kind: str) -> Iterator[Path]:
    """:func:`make_work_folder`, removed with its contents when the block ends (as
    ``tempfile.TemporaryDirectory``, whose names carry no pid: a killed run's would stay)."""
    folder = make_work_folder(kind)
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _stale_work_folder(path: Path, pid: int, now: float) -> bool:
    """Whether ``path`` (named with ``pid``) is a work folder whose run no longer runs: a
    folder of ours (not a link) holding a marker of that pid, whose pid is dead here (same
    boot and pid namespace) or, made elsewhere, unchanged for :data:`STALE_WORK_SECS`."""
    try:
        st = path.lstat()
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid():
            return False  # (a link, a file, another user's: not made by make_work_folder)
        marker = path / WORK_MARKER
        mst = marker.lstat()
        if not stat.S_ISREG(mst.st_mode) or mst.st_size > 4096:
            return False
        fields = dict(line.split(" ", 1) for line in marker.read_text().splitlines() if " " in line)
    except (OSError, UnicodeDecodeError, ValueError):
        return False  # (no marker: anyone's folder named alike; or gone meanwhile)
    if fields.get("pid") != str(pid):
        return False
    here = _host_ids()
    if any(k not in here or fields.get(k) != here[k] for k in ("boot", "pidns")):
        return now - max(st.st_mtime, mst.st_mtime) > STALE_WORK_SECS
    return not _pid_alive(pid)


def remove_stale_work_folders(root: str | Path | None = None) -> int:
    """Delete the work folders (:func:`make_work_folder`) in ``root`` (default: the system's
    temp folder) of runs that no longer run; returns how many. Only a folder of a work
    folder's name (a known kind, a pid, mkdtemp's random part) that holds its marker naming
    that pid goes, once the pid no longer runs (:func:`_stale_work_folder`); as for temporary
    files, one of a live pid is never deleted, nor one of another user's."""
    root = Path(root if root is not None else tempfile.gettempdir())
    removed = 0
    try:
        candidates = list(root.glob(f"{WORK_FOLDER_PREFIX}*"))
    except OSError:
        return 0
    now = time.time()
    for path in candidates:
        match = _WORK_FOLDER.fullmatch(path.name)
        if match is None or not _stale_work_folder(path, int(match.group(2)), now):
            continue
        shutil.rmtree(path, ignore_errors=True)  # (another run may be removing it too)
        removed += not os.path.lexists(path)
    return removed


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return  # some filesystems do not open directories; the rename is still atomic
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_bytes_atomic(path: str | Path, data: bytes | Iterable[bytes]) -> None:
    """Write to a temporary file in the same folder, fsync it, then rename it into place.

    ``data`` may be an iterable of chunks, so a large file assembled from parts is streamed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(path.parent)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temp_name(path), suffix=TEMP_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in [data] if isinstance(data, bytes) else data:
                fh.write(chunk)
            fh.flush()
            os.fsync(fh.fileno())  # the data is on disk before the name points at it
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; use the user's normal mode
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def compact_json(payload: Any) -> bytes:
    """The encoding of every JSON output file: compact, no NaN."""
    return json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()


def write_json_atomic(path: str | Path, payload: Any) -> None:
    """Compact JSON; gzip-compressed (reproducibly, mtime 0) when the name ends in .gz."""
    text = compact_json(payload)
    write_bytes_atomic(path, gzip.compress(text, mtime=0) if str(path).endswith(".gz") else text)


def write_text_atomic(path: str | Path, lines: list[str]) -> None:
    write_bytes_atomic(path, "".join(lines).encode())


def read_text(path: str | Path) -> str:
    """``path``'s text, read as UTF-8 (as Path.read_text in a UTF-8 locale). A file that is not
    UTF-8 is an :class:`InputError` naming it, the line and the byte offset: the decoder's own
    error ("invalid start byte") names no file."""
    data = Path(path).read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(
            f"not a UTF-8 text file (byte {exc.start}: {exc.reason})", path=path, line=line
        ) from None


# ---------------------------------------------------------------------------------------------
# input size cap

# Input larger than this (decompressed) is refused before parsing: a 1 MB .json.gz or .npz can
# expand to gigabytes. Generous for real files (a full nuScenes val split is ~0.5 GB); override
# per call or with the MCTRACK_MAX_INPUT_BYTES environment variable.
DEFAULT_MAX_INPUT_BYTES = 4 * 1024**3
MAX_INPUT_BYTES_ENV = "MCTRACK_MAX_INPUT_BYTES"


def max_input_bytes() -> int:
    """The decompressed-size cap: ``MCTRACK_MAX_INPUT_BYTES`` if set, else the default."""
    value = os.environ.get(MAX_INPUT_BYTES_ENV)
    if not value:
        return DEFAULT_MAX_INPUT_BYTES
    try:
        cap = int(value)
    except ValueError:
        raise InputError(f"{MAX_INPUT_BYTES_ENV}={value!r}: must be a number of bytes") from None
    if cap <= 0:
        raise InputError(f"{MAX_INPUT_BYTES_ENV}={value!r}: must be positive")
    return cap


# ---------------------------------------------------------------------------------------------
# npz input: no pickle, sizes checked before anything is decompressed

#: What to tell the owner of a pickled (object-array) npz: how to convert their own files.
OBJECT_ARRAY_HINT = (
    "pickled object arrays are not read (loading one can run code); convert your own, trusted "
    "files with: python bench/waymo_flatten_npz.py IN_FOLDER OUT_FOLDER (docs/nuscenes_waymo.md)"
)


class SafeNpz:
    """The arrays of an ``.npz`` file, read eagerly; mapping-like (``files``, ``[key]``, ``in``)."""

    def __init__(self, arrays: dict[str, np.ndarray]) -> None:
        self._arrays = arrays
        self.files = list(arrays)

    def __getitem__(self, key: str) -> np.ndarray:
        return self._arrays[key]

    def __contains__(self, key: object) -> bool:
        return key in self._arrays

    def __iter__(self) -> Iterator[str]:
        return iter(self._arrays)

    def __enter__(self) -> SafeNpz:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def _npy_header(fh: Any) -> tuple[tuple[int, ...], np.dtype, int]:
    """Shape, dtype and header length of the ``.npy`` stream ``fh`` (read from its start)."""
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, _fortran, dtype = np.lib.format.read_array_header_1_0(fh)
    elif version in ((2, 0), (3, 0)):
        shape, _fortran, dtype = np.lib.format.read_array_header_2_0(fh)
    else:
        raise ValueError(f"unsupported .npy version {version}")
    return shape, dtype, fh.tell()


def check_npz(
    path: Path, fh: Any, what: str, cap: int, members: Collection[str] | None = None
) -> None:
    """Refuse an npz before decompressing it: members' declared sizes (the zip directory) and
    the arrays' declared sizes (each ``.npy`` header) over ``cap`` in total, a header that
    disagrees with its member's size (a lie either way), or an object (pickled) array.
    ``members``: check only these (the others are never read)."""
    hint = f"(the cap; raise it with {MAX_INPUT_BYTES_ENV})"
    with zipfile.ZipFile(fh) as zf:
        infos = [
            i
            for i in zf.infolist()
            if members is None or i.filename.removesuffix(".npy") in members
        ]
        declared = sum(i.file_size for i in infos)
        if declared > cap:
            raise InputError(f"{path}: {what} members declare {declared} bytes, over {cap} {hint}")
        for info in infos:
            key = info.filename.removesuffix(".npy")
            with zf.open(info) as member:
                # only the header is decompressed here (a few hundred bytes)
                shape, dtype, header_len = _npy_header(io.BufferedReader(member, 1024))
            if dtype.hasobject:
                raise InputError(f"{path}: member '{key}' of the {what} file: {OBJECT_ARRAY_HINT}")
            data_bytes = math.prod(shape) * dtype.itemsize  # Python ints: no overflow
            if data_bytes > cap:
                raise InputError(
                    f"{path}: member '{key}' declares {data_bytes} bytes, over {cap} {hint}"
                )
            if header_len + data_bytes != info.file_size:
                raise InputError(
                    f"{path}: member '{key}': its header says {shape} {dtype} "
                    f"({header_len + data_bytes} bytes), the zip says {info.file_size} bytes"
                )


def load_npz(
    path: str | Path,
    what: str = "npz",
    *,
    max_bytes: int | None = None,
    members: Collection[str] | None = None,
) -> SafeNpz:
    """Read an ``.npz`` file of plain arrays: no pickle (``allow_pickle=False``), sizes checked
    against ``max_bytes`` (default :func:`max_input_bytes`) before decompressing
    (:func:`check_npz`).
    ``members``: read only these arrays (when present); the others are not even decompressed.

    Raises InputError (naming the file, and the member where it applies) when the file is
    missing, not an npz, too large, lies about its sizes, or holds an object array.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} file not found")
    cap = max_input_bytes() if max_bytes is None else max_bytes
    try:
        with open(path, "rb") as fh:
            check_npz(path, fh, what, cap, members)
            fh.seek(0)
            with np.load(fh, allow_pickle=False) as npz:
                keys = [k for k in npz.files if members is None or k in members]
                arrays = {key: npz[key] for key in keys}
    except InputError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise InputError(f"{path}: unreadable {what} file ({exc})") from None
    return SafeNpz(arrays)


# ---------------------------------------------------------------------------------------------
# file names from input data

_SAFE_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_.")
_MAX_NAME_BYTES = 200  # below the usual 255-byte file-name limit, room for a suffix


def safe_filename(name: str) -> str:
    """A file name (one path component) for an input-data name, e.g. a scene.

    Injective and reversible: characters outside ``[A-Za-z0-9._-]`` (and ``%``) become ``%XX``
    of their UTF-8 bytes, as does a leading dot, so ``..``, ``/abs``, ``a/b``, NUL and hidden
    names cannot leave or hide in the folder. Lone surrogates are escaped too. Overlong
    results are cut and suffixed with a hash of the name. Safe names (``0001``, ``scene-0103``,
    Waymo segment stems) are unchanged.
    """
    data = name.encode("utf-8", "surrogatepass")
    out: list[str] = []
    for i, byte in enumerate(data):
        char = chr(byte)
        if char in _SAFE_CHARS and not (i == 0 and char == "."):
            out.append(char)
        else:
            out.append(f"%{byte:02X}")
    text = "".join(out) or "%"  # the empty name: a bare % is never the escape of another
    if len(text) > _MAX_NAME_BYTES:
        text = text[:150] + "~" + hashlib.sha256(data).hexdigest()[:16]
    return text


def case_collision(names: Iterable[str]) -> tuple[str, str] | None:
    """The first two of ``names`` whose files (:func:`safe_filename`) differ only in case
    (``A`` and ``a``), or None: on a case-insensitive filesystem (macOS's and Windows' by
    default) they are one file, the second run's over the first's."""
    seen: dict[str, str] = {}
    for name in names:
        first = seen.setdefault(safe_filename(name).casefold(), name)
        if first != name:
            return first, name
    return None


def refuse_case_collisions(
    names: Iterable[str], source: str | Path, what: str = "scenes", suffix: str = ""
) -> None:
    """InputError naming two ``what`` (of ``source``) whose files (name + ``suffix``) would
    differ only in case (:func:`case_collision`). Called before a run writes a file per name,
    on every filesystem: outputs written here must stay whole where they are copied to."""
    found = case_collision(names)
    if found is not None:
        a, b = found
        raise InputError(
            f"{source}: {what} {a!r} and {b!r} differ only in case: their files "
            f"({safe_filename(a)}{suffix}, {safe_filename(b)}{suffix}) would be one on a "
            "case-insensitive filesystem (macOS, Windows); rename one"
        )


def name_is_escaped(name: str) -> bool:
    """True when :func:`safe_filename` changes the name (``mctrack validate`` reports these)."""
    return safe_filename(name) != name


def path_in(folder: str | Path, name: str, suffix: str = "") -> Path:
    """``folder / (safe_filename(name) + suffix)``, checked to stay inside ``folder``. The
    file itself may be a symbolic link (a kit of linked label files): the name is checked, not
    where a link points."""
    folder = Path(folder)
    path = folder / (safe_filename(name) + suffix)
    inside = folder.resolve() / path.name
    if path.name in ("", ".", "..") or inside.parent != folder.resolve():  # a guard
        raise InputError(f"name {name!r}: would leave the folder {folder}")
    return path


def check_output_folder(folder: str | Path, option: str = "--out") -> Path:
    """Create ``folder`` if needed and prove it writable, before any work (InputError if not)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{option} {folder}: exists and is not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".mctrack-probe.", suffix=TEMP_SUFFIX)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(f"{option} {folder}: not writable ({exc.strerror or exc})") from None
    return folder


def check_output_file(path: str | Path, option: str = "--out") -> Path:
    """An output *file* path: not a folder, and its folder writable (checked before any work)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: is a folder, expected a file name")
    check_output_folder(path.parent, option)
    return path


def finish_temp(tmp: Path, path: Path) -> None:
    """Rename a completed temporary file (streamed by someone else, e.g. a recording) into
    place, after an fsync; the name appears only when the file is complete."""
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


@contextlib.contextmanager
def staged_files() -> Iterator[list[tuple[Path, Path]]]:
    """Files written as one set: the block appends ``(tmp, path)`` for each file it streams to
    a temporary name (complete by the end of the block), and they are renamed into place
    (:func:`finish_temp`) together once it ends. If the block fails, or a rename does, the
    temporary files go and so do the files already renamed: none of the set is left (an
    earlier file at a path not yet reached stays)."""
    staged: list[tuple[Path, Path]] = []
    placed: list[Path] = []
    try:
        yield staged
        for _, path in staged:  # (the one rename that fails for certain, before any is done)
            if path.is_dir() and not path.is_symlink():
                raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
        for tmp, path in staged:
            finish_temp(tmp, path)
            placed.append(path)
    except BaseException:
        for tmp, _ in staged:
            tmp.unlink(missing_ok=True)
        for path in placed:
            path.unlink(missing_ok=True)
        raise


def output_manifest(folder: str | Path, paths: list[Path]) -> list[dict[str, Any]]:
    """``[{"path": relative path, "bytes": size}]`` of written outputs, for a summary written
    last: a run cut short has no summary, and a file not matching its listed size is stale."""
    folder = Path(folder)
    return [
        {"path": p.relative_to(folder).as_posix(), "bytes": p.stat().st_size} for p in sorted(paths)
    ]
