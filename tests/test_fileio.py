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


def test_a_work_folder_of_a_pid_that_no_longer_runs_is_removed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What a run killed outright (SIGKILL) leaves in the temp folder goes with the next work
    folder made; a running process's (however old), a name without a pid (an older version's,
    or anyone's), and a file or a link of such a name stay."""
    dead = 2**22 + 12345  # above the default pid_max: no such process
    stranded = tmp_path / f"mctrack-tune-{dead}-abc_12"
    (stranded / "fold0-trial" / "pointrcnn").mkdir(parents=True)
    (stranded / "fold0-trial" / "pointrcnn" / "0001.txt").write_text("a trial's tracks\n")
    kept = [
        f"mctrack-tune-{os.getpid()}-running",  # this process: alive
        "mctrack-tune-0ux514vm",  # no pid: a folder of an earlier version
        f"mctrack-test-compare-{dead}",  # not a work folder's name
        f"other-tune-{dead}-abc",
    ]
    for name in kept:
        (tmp_path / name).mkdir()
    (tmp_path / f"mctrack-eval-{dead}-afile").write_text("not a folder\n")
    (tmp_path / f"mctrack-eval-{dead}-alink").symlink_to(stranded)
    kept += [f"mctrack-eval-{dead}-afile", f"mctrack-eval-{dead}-alink"]
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # ($TMPDIR)
    with fileio.work_folder("eval") as work:
        assert work.parent == tmp_path and work.name.startswith(f"mctrack-eval-{os.getpid()}-")
        assert _names(tmp_path) == sorted([*kept, work.name])
    assert _names(tmp_path) == sorted(kept)  # its own gone too, at the end of the block
    assert fileio.remove_stale_work_folders(tmp_path) == 0


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
        (tmp_path / f"mctrack-trial-{proc.pid}-abc").mkdir()
        assert fileio.remove_stale_work_folders(tmp_path) == 1 and _names(tmp_path) == []
    finally:
        proc.wait()
