"""tracker.io.fileio.staged_files: a set of files renamed into place together, or none of it."""

from __future__ import annotations

import errno
import os
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
