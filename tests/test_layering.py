"""Layering: the tracker never imports the viewer; the CLI pays for rerun only when it records."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )


def test_importing_tracker_does_not_import_rerun() -> None:
    result = _run(
        """
        import importlib, pkgutil, sys
        import tracker
        names = [m.name for m in pkgutil.walk_packages(tracker.__path__, "tracker.")]
        for name in names:
            importlib.import_module(name)
        assert len(names) > 10, names
        bad = sorted(m for m in sys.modules if m.split(".")[0] in ("rerun", "viz", "app", "ray"))
        assert not bad, bad
        print(len(names))
        """
    )
    assert result.returncode == 0, result.stderr


def test_cli_parser_does_not_import_rerun() -> None:
    """`mctrack --help` (and every non-recording command) stays free of the 0.8 s import."""
    result = _run(
        """
        import sys
        from app.cli import build_parser
        parser = build_parser()
        commands = parser._subparsers._group_actions[0].choices
        assert {"view", "demo", "shots"} <= set(commands), sorted(commands)
        assert "rerun" not in sys.modules
        """
    )
    assert result.returncode == 0, result.stderr
