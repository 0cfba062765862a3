"""What a command printed, as tests compare it."""

from __future__ import annotations


def without_kernel_lines(err: str) -> str:
    """``err`` without the one-time lines of the first tracking command on a fresh install
    (``mctrack: compiling the tracker kernels ...`` and ``... kernels compiled in N s``), which
    come before any error of the command itself."""
    return "".join(
        line
        for line in err.splitlines(True)
        if "tracker kernels" not in line and "kernels compiled in" not in line
    )
