"""tracker.io.fileio.staged_files: a set of files renamed into place together, or none of it;
work folders: a killed run's are removed by the next run."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tracker.io import fileio
from tracker.io.fileio import staged_files, temp_name


def _stage(staged: list[tuple[Path, Path]], path: Path, data: bytes) -> Path:
    """Stream ``data`` to a temporary name for ``path``, as mctrack view does a recording."""
    tmp = path.parent / f"{temp_name(path)}abc{len(staged)}.tmp"
    tmp.write_bytes(data)
    staged.append((tmp, path))
    return tmp


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_staged_files_are_renamed_into_place_together_at_the_end(tmp_path: Path) -> None:
    (tmp_path / "b.rrd").write_bytes(b"earlier b")
    with staged_files() as staged:
        _stage(staged, tmp_path / "a.rrd", b"new a")
        _stage(staged, tmp_path / "b.rrd", b"new b")
        assert _names(tmp_path) == sorted([t.name for t, _ in staged] + ["b.rrd"])
        assert (tmp_path / "b.rrd").read_bytes() == b"earlier b"  # nothing placed yet
    assert _names(tmp_path) == ["a.rrd", "b.rrd"]
    assert (tmp_path / "a.rrd").read_bytes() == b"new a"
    assert (tmp_path / "b.rrd").read_bytes() == b"new b"


def test_a_failing_block_leaves_none_of_the_set_and_earlier_files_stay(tmp_path: Path) -> None:
    (tmp_path / "a.rrd").write_bytes(b"earlier a")
    with pytest.raises(KeyboardInterrupt), staged_files() as staged:  # (a run stopped)
        _stage(staged, tmp_path / "a.rrd", b"new a")
        _stage(staged, tmp_path / "b.rrd", b"new b")
        raise KeyboardInterrupt
    assert _names(tmp_path) == ["a.rrd"]
    assert (tmp_path / "a.rrd").read_bytes() == b"earlier a"


def test_a_folder_at_a_path_fails_before_any_rename(tmp_path: Path) -> None:
    (tmp_path / "a.rrd").write_bytes(b"earlier a")
    (tmp_path / "b.rrd").mkdir()
    with pytest.raises(IsADirectoryError, match=r"b\.rrd"), staged_files() as staged:
        _stage(staged, tmp_path / "a.rrd", b"new a")
        _stage(staged, tmp_path / "b.rrd", b"new b")
    assert _names(tmp_path) == ["a.rrd", "b.rrd"]
    assert (tmp_path / "a.rrd").read_bytes() == b"earlier a"  # not replaced, then deleted


def test_a_failed_rename_removes_the_files_already_placed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The second of three renames fails (e.g. the disk is full): the first file, already in
    place, goes too, and the earlier file at the third path, not yet reached, stays."""
    (tmp_path / "c.rrd").write_bytes(b"earlier c")
    replace = os.replace

    def failing_replace(src: str | Path, dst: str | Path) -> None:
        if Path(dst).name == "b.rrd":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(dst))
        replace(src, dst)

    monkeypatch.setattr(fileio.os, "replace", failing_replace)
    with pytest.raises(OSError, match=r"b\.rrd"), staged_files() as staged:
        for name in ("a.rrd", "b.rrd", "c.rrd"):
            _stage(staged, tmp_path / name, f"new {name}".encode())
    assert _names(tmp_path) == ["c.rrd"]  # no temporary file, no a.rrd
    assert (tmp_path / "c.rrd").read_bytes() == b"earlier c"


# ---------------------------------------------------------------------------------------------
# work folders: a killed run's are removed by the next run that makes one


def _work(root: Path, name: str, pid: int, marker: str | None = None) -> Path:
    """A folder ``name`` in ``root`` as make_work_folder makes one for ``pid`` (its marker:
    ``marker`` when given)."""
    folder = root / name
    folder.mkdir()
    text = fileio._work_marker(pid) if marker is None else marker
    (folder / fileio.WORK_MARKER).write_text(text)
    return folder


DEAD = 2**22 + 12345  # above the default pid_max: no such process


def test_a_work_folder_of_a_pid_that_no_longer_runs_is_removed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What a run killed outright (SIGKILL) leaves in the temp folder goes with the next work
    folder made; a running process's (however old), a name without a pid (an older version's,
    or anyone's), and a file or a link of such a name stay."""
    stranded = _work(tmp_path, f"mctrack-tune-{DEAD}-abc_1234", DEAD)
    (stranded / "fold0-trial" / "pointrcnn").mkdir(parents=True)
    (stranded / "fold0-trial" / "pointrcnn" / "0001.txt").write_text("a trial's tracks\n")
    _work(tmp_path, f"mctrack-tune-{os.getpid()}-running1", os.getpid())  # this process: alive
    kept = [f"mctrack-tune-{os.getpid()}-running1"]
    kept += [
        "mctrack-tune-0ux514vm",  # no pid: a folder of an earlier version
        f"mctrack-test-compare-{DEAD}",  # not a work folder's name
        f"other-tune-{DEAD}-abc",
    ]
    for name in kept[1:]:
        (tmp_path / name).mkdir()
    (tmp_path / f"mctrack-eval-{DEAD}-afile123").write_text("not a folder\n")
    (tmp_path / f"mctrack-eval-{DEAD}-alink123").symlink_to(stranded)
    kept += [f"mctrack-eval-{DEAD}-afile123", f"mctrack-eval-{DEAD}-alink123"]
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # ($TMPDIR)
    with fileio.work_folder("eval") as work:
        assert work.parent == tmp_path and work.name.startswith(f"mctrack-eval-{os.getpid()}-")
        assert _names(tmp_path) == sorted([*kept, work.name])
        assert (work / fileio.WORK_MARKER).read_text().startswith(f"pid {os.getpid()}\n")
    assert _names(tmp_path) == sorted(kept)  # its own gone too, at the end of the block
    assert fileio.remove_stale_work_folders(tmp_path) == 0


def test_a_folder_named_like_a_work_folder_without_its_marker_stays(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Only a folder make_work_folder made goes: `mctrack-kitti-20240101-baseline` (anyone's
    results, a date read as a dead pid) was removed with its contents. A work folder's name
    needs a known kind and mkdtemp's random part, and the folder its marker naming that pid,
    a file (not a link)."""
    baseline = tmp_path / "mctrack-kitti-20240101-baseline"
    baseline.mkdir()
    (baseline / "results.txt").write_text("x\n")
    (tmp_path / f"mctrack-tune-{DEAD}-abcd1234").mkdir()  # a work folder's name, no marker
    _work(tmp_path, f"mctrack-kitti-{DEAD}-abcd1234", DEAD)  # not a kind of work folder
    _work(tmp_path, f"mctrack-tune-{DEAD}-baseline_x", DEAD)  # not mkdtemp's 8 characters
    _work(tmp_path, f"mctrack-eval-{DEAD}-abcd1234", DEAD + 1)  # the marker: another pid
    linked = tmp_path / f"mctrack-trial-{DEAD}-abcd1234"
    linked.mkdir()
    (tmp_path / "marker").write_text(fileio._work_marker(DEAD))
    (linked / fileio.WORK_MARKER).symlink_to(tmp_path / "marker")  # the marker: a link
    before = _names(tmp_path)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)  # (read $TMPDIR again, as a new process)
    assert fileio.remove_stale_work_folders() == 0
    assert _names(tmp_path) == before
    assert (baseline / "results.txt").read_text() == "x\n"
    _work(tmp_path, f"mctrack-eval-{DEAD}-abcd5678", DEAD)  # a stranded work folder: goes
    assert fileio.remove_stale_work_folders() == 1 and _names(tmp_path) == before
    with pytest.raises(ValueError, match="kitti"):
        fileio.make_work_folder("kitti")  # (a kind the removal would not know)


def test_a_work_folder_of_another_pid_namespace_goes_only_once_old(tmp_path: Path) -> None:
    """A temp folder shared with a container: a pid of another pid namespace (or boot) says
    nothing here, so its work folder goes only once unchanged for STALE_WORK_SECS."""
    ids = fileio._host_ids()
    if "pidns" not in ids:
        pytest.skip("no /proc/self/ns/pid: pid namespaces are not told apart here")
    other = "".join(f"{k} {v}\n" for k, v in {"pid": DEAD, **ids, "pidns": "pid:[1]"}.items())
    folder = _work(tmp_path, f"mctrack-tune-{DEAD}-abcd1234", DEAD, other)
    assert fileio.remove_stale_work_folders(tmp_path) == 0 and folder.is_dir()
    old = time.time() - fileio.STALE_WORK_SECS - 60
    for path in (folder, folder / fileio.WORK_MARKER):
        os.utime(path, (old, old))
    assert fileio.remove_stale_work_folders(tmp_path) == 1 and not folder.exists()


def test_a_work_folder_of_an_exited_process_not_yet_reaped_is_removed(tmp_path: Path) -> None:
    """A process killed with its parent waits to be reaped a while (a zombie): its pid still
    answers, but it writes nothing more."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    try:
        stat = Path(f"/proc/{proc.pid}/stat")
        if not stat.exists():
            pytest.skip("no /proc: zombies are not told from running processes here")
        deadline = time.monotonic() + 60
        while stat.read_text().rsplit(")", 1)[1].split()[0] != "Z":  # exited, not reaped
            assert time.monotonic() < deadline
            time.sleep(0.01)
        _work(tmp_path, f"mctrack-trial-{proc.pid}-abcd1234", proc.pid)
        assert fileio.remove_stale_work_folders(tmp_path) == 1 and _names(tmp_path) == []
    finally:
        proc.wait()


def test_read_text_names_the_file_line_and_byte_that_are_not_utf8(tmp_path: Path) -> None:
    """The decoder's own error names no file: read_text names it, the line and the byte."""
    path = tmp_path / "t.txt"
    path.write_bytes("ok é\r\nsecond \xff line\n".encode("latin-1").replace(b"\xe9", "é".encode()))
    with pytest.raises(fileio.InputError) as excinfo:
        fileio.read_text(path)
    assert str(excinfo.value) == (f"{path}:2: not a UTF-8 text file (byte 14: invalid start byte)")
    path.write_bytes("ok é\r\nsecond\n".encode())
    assert fileio.read_text(path).splitlines() == ["ok é", "second"]
