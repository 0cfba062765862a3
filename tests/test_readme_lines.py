"""The README's two lines, as .ci/readme_lines.sh (CI) and .ci/fresh_clone.sh read them."""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_lines_are_self_contained_in_a_new_shell() -> None:
    printed = subprocess.run(
        [str(ROOT / ".ci" / "readme_lines.sh"), "--print", str(ROOT)],
        capture_output=True,
        text=True,
        check=True,
        timeout=30,
    ).stdout.splitlines()
    assert len(printed) == 2
    install, tests = printed
    assert install.startswith("python3 -m venv .venv && ") and install.endswith("mctrack demo")
    assert tests.startswith(".venv/bin/python -m pytest")
    for line in printed:  # nothing that only works in the shell that activated the venv
        assert "activate" not in line
        commands = [c.strip().split()[0] for c in line.split("&&")]
        assert all(c in ("python3", ".venv/bin/python", ".venv/bin/mctrack") for c in commands)
