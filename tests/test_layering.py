"""Layering: the tracker never imports the viewer; the CLI pays for rerun only when it records."""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

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


def _imports(path: Path) -> set[str]:
    """Absolute module names a source file imports (every ``import``/``from``, lazy ones too)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def _layer(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] in ("app", "viz", "rerun"):
        return parts[0]
    if parts[0] != "tracker":
        return None
    return parts[1] if len(parts) > 1 and parts[1] in ("io", "eval") else "core"


def _layer_of_file(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    return _layer(".".join(p for p in rel.parts if p != "__init__")) or "other"


# who may import whom: the core is the bottom; io and eval sit on it (eval may read files
# through io); viz draws the core's events; app is the top.
ALLOWED = {
    "core": {"core"},
    "io": {"core", "io"},
    "eval": {"core", "io", "eval"},
    "viz": {"core", "io", "eval", "viz", "rerun"},
    "app": {"core", "io", "eval", "viz", "app", "rerun"},
}


@pytest.mark.parametrize("package", ["tracker", "viz", "app"])
def test_import_layers(package: str) -> None:
    files = sorted((ROOT / package).rglob("*.py"))
    assert files
    violations = []
    for path in files:
        layer = _layer_of_file(path)
        for name in sorted(_imports(path)):
            target = _layer(name)
            if target is not None and target not in ALLOWED[layer]:
                violations.append(f"{path.relative_to(ROOT)} ({layer}) imports {name} ({target})")
    assert not violations, "\n".join(violations)


def test_layer_rules_catch_a_violation(tmp_path: Path) -> None:
    """The checker itself: a core module importing the evaluators is reported."""
    fake = tmp_path / "m.py"
    fake.write_text("from tracker.eval.kitti import evaluate\nimport viz.observer\n")
    layers = {_layer(n) for n in _imports(fake)}
    assert {"eval", "viz"} <= layers
    assert not layers <= ALLOWED["core"]


#: The one module that makes temporary files and folders. Its work folders carry the run's pid
#: (``make_work_folder``: ``mctrack-<kind>-<pid>-<random>``), so the next run removes those of a
#: killed one; a bare ``mkdtemp`` or ``TemporaryDirectory`` elsewhere would stay for good.
TEMP_MAKER = "tracker/io/fileio.py"


def _uses_tempfile(path: Path) -> bool:
    return any(n == "tempfile" or n.startswith("tempfile.") for n in _imports(path))


def test_temporary_folders_are_work_folders(tmp_path: Path) -> None:
    offenders = [
        path.relative_to(ROOT).as_posix()
        for package in ("app", "viz", "tracker", "bench")
        for path in sorted((ROOT / package).rglob("*.py"))
        if path.relative_to(ROOT).as_posix() != TEMP_MAKER and _uses_tempfile(path)
    ]
    assert not offenders, f"use tracker.io.fileio.work_folder, not tempfile: {offenders}"
    assert _uses_tempfile(ROOT / TEMP_MAKER)
    for line in ("import tempfile", "from tempfile import mkdtemp", "import tempfile as t"):
        fake = tmp_path / "m.py"
        fake.write_text(f"def f():\n    {line}\n")  # (a lazy import is caught too)
        assert _uses_tempfile(fake), line
