"""Atomic file output: every output file is written completely or not at all."""

from __future__ import annotations

import gzip
import json
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any


def write_bytes_atomic(path: str | Path, data: bytes | Iterable[bytes]) -> None:
    """Write to a temporary file in the same folder, then rename it into place.

    ``data`` may be an iterable of chunks, so a large file assembled from parts is streamed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in [data] if isinstance(data, bytes) else data:
                fh.write(chunk)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; use the user's normal mode
        os.replace(tmp, path)
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
