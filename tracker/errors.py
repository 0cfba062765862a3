"""Project error types."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input data: the message names the file, the line (1-based) and the field."""

    def __init__(
        self,
        message: str,
        *,
        path: str | Path | None = None,
        line: int | None = None,
        field: str | None = None,
    ) -> None:
        self.path = None if path is None else str(path)
        self.line = line
        self.field = field
        if path is None and line is None and field is None:
            super().__init__(message)  # the message already names file and field
            return
        where = self.path or "<input>"
        if line is not None:
            where += f":{line}"
        what = f" field '{field}':" if field is not None else ""
        super().__init__(f"{where}:{what} {message}")


class ViewerError(RuntimeError):
    """A viewer or its server did not start or answer (no display, the binary exited): the
    machine's environment, not bad input. The CLI exits with status 4 (``EXIT_VIEWER_FAILED``)."""
