"""The ``rerun`` binary of the rerun-sdk wheel, started with the address it listens on.

Rerun's Python API starts every server on all interfaces (0.0.0.0) and takes no bind address
(0.41: ``rr.serve_grpc``, ``rr.serve_web_viewer``, ``RecordingStream.spawn``,
``ViewerClient.spawn``); the binary takes ``--bind``. So every viewer and server the CLI starts
(``mctrack view --spawn / --serve-web``, ``inspect``, ``shots``, ``report --shots / --serve``)
is this binary, started here, on 127.0.0.1 unless the user asks for another address (``--host``).
"""

from __future__ import annotations

import contextlib
import ctypes
import ipaddress
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

LOOPBACK = "127.0.0.1"
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def rerun_executable() -> str | None:
    """The viewer binary itself (the ``rerun`` console script is a Python shim around it)."""
    with contextlib.suppress(ImportError):
        import rerun_cli

        binary = Path(rerun_cli.__file__).with_name("rerun")
        if binary.is_file():
            return str(binary)
    return None


def free_port(host: str = LOOPBACK) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def is_loopback(host: str) -> bool:
    """``localhost`` or an address in 127.0.0.0/8 or ::1."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def exposure_note(host: str, what: str) -> str | None:
    """The line that says a server on ``host`` is reachable from other machines (None: it
    is not; it listens on loopback only)."""
    if is_loopback(host):
        return None
    return f"note: --host {host} exposes {what} to the network"


def local_address(host: str) -> str:
    """The address a client on this machine uses for a server bound to ``host`` (a wildcard
    address is not one to connect to), bracketed when IPv6 (for a URL)."""
    if host in ("0.0.0.0", ""):  # (the WILDCARDS)
        return LOOPBACK
    if host == "::":
        return "[::1]"
    return f"[{host}]" if ":" in host else host


#: the addresses that listen on all interfaces (not ones to connect to)
WILDCARDS = ("0.0.0.0", "::", "")


def served_at(host: str, url: Callable[[str], str]) -> tuple[str, str | None]:
    """How to print the URL of a server listening on ``host``, ``url(address)``: (the URL, a
    line to print after it or None). On a wildcard address (0.0.0.0, ::) the URL names this
    machine by its host name, for a browser on another machine (127.0.0.1 there is that other
    machine), and the line says the server listens on all interfaces and gives the URL for this
    machine; without a usable host name the URL is this machine's, and the line says to put
    this machine's address in its place from elsewhere."""
    local = url(local_address(host))
    if host not in WILDCARDS:
        return local, None
    name = socket.gethostname()
    if not name or is_loopback(name):
        elsewhere = f"from another machine, this machine's address for {local_address(host)}"
        return local, f"  listening on all interfaces: {elsewhere}"
    return url(name), f"  listening on all interfaces; on this machine: {local}"


def rerun_command(
    args: Sequence[str], *, host: str = LOOPBACK, executable: str | None = None
) -> list[str]:
    """The binary's argv with ``--bind host`` first."""
    exe = executable or rerun_executable()
    if exe is None:
        raise RuntimeError("the rerun binary of rerun-sdk is not installed")
    return [exe, "--bind", host, *args]


def _die_with_parent(parent: int) -> Callable[[], None]:
    """``preexec_fn`` of a child that must not outlive this process: on Linux the kernel sends
    it SIGTERM when the parent dies, however it dies (SIGKILL, a hang-up without a handler)."""

    def arm() -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
        if os.getppid() != parent:  # the parent died before the prctl: no signal will come
            os.kill(os.getpid(), signal.SIGTERM)

    return arm


def start_rerun(
    args: Sequence[str],
    *,
    host: str = LOOPBACK,
    quiet: bool = True,
    env: Mapping[str, str] | None = None,
    detach: bool = False,
) -> subprocess.Popen[bytes]:
    """The binary started with ``args`` on ``host``. ``RERUN_APP_ONLY`` skips its analytics
    banner, as ``ViewerClient.spawn`` does.

    ``detach``: a viewer meant to outlive the command (``view --spawn``, ``inspect``), in a
    session of its own, out of reach of Ctrl-C and the terminal's hang-up. Otherwise (servers,
    the headless viewer of shots) it stays in the caller's process group, so a hang-up or a
    signal to the group reaches it too, and on Linux it gets SIGTERM when this process dies:
    such a server left behind kept its ports, a child of nobody.

    That signal follows the *thread* that starts the child (prctl(2): the parent-death signal
    comes when the creating thread ends), so such a child is started from the main thread only,
    which lives as long as the process: one from a worker thread would be stopped when that
    thread ended, under a command still using it. Every command starts its viewers and servers
    from the main thread; a RuntimeError here is a bug of the caller."""
    linux = sys.platform.startswith("linux")
    if linux and not detach and threading.current_thread() is not threading.main_thread():
        raise RuntimeError(
            f"start_rerun from thread {threading.current_thread().name!r}: a server or headless "
            "viewer is started from the main thread only (its death signal follows the thread "
            "that starts it)"
        )
    return subprocess.Popen(
        rerun_command(args, host=host),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL if quiet else None,
        stderr=subprocess.DEVNULL if quiet else None,
        env={**os.environ, **(env or {}), "RERUN_APP_ONLY": "true"},
        start_new_session=detach,
        preexec_fn=_die_with_parent(os.getpid()) if linux and not detach else None,
    )


def port_open(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
        s.settimeout(1.0)
        return s.connect_ex((host.strip("[]"), port)) == 0


def wait_listening(
    process: subprocess.Popen[bytes], host: str, ports: Sequence[int], timeout: float = 30.0
) -> None:
    """Until each of ``ports`` accepts a connection on ``host``; RuntimeError when the process
    exits first (a port taken, a bad option), TimeoutError after ``timeout`` seconds."""
    address = local_address(host)
    deadline = time.monotonic() + timeout
    waiting = list(ports)
    while waiting:
        if process.poll() is not None:
            taken = [p for p in ports if port_open(address, p)]  # (by another process)
            why = f"; port {taken[0]} is in use" if taken else ""
            raise RuntimeError(f"the rerun viewer exited (status {process.returncode}){why}")
        if port_open(address, waiting[0]):
            waiting.pop(0)
            continue
        if time.monotonic() > deadline:
            raise TimeoutError(f"the rerun viewer did not listen on port {waiting[0]}")
        time.sleep(0.1)


def stop_rerun(process: subprocess.Popen[bytes], timeout: float = 10.0) -> None:
    """End the process and wait for it: its whole group when it leads one of its own (a
    detached viewer may have started helpers), else the process alone (the group is ours)."""
    if process.poll() is None:
        _signal(process, signal.SIGTERM)
        try:
            process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            _signal(process, signal.SIGKILL)
            process.wait(timeout=timeout)


def _signal(process: subprocess.Popen[bytes], signum: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        if os.getpgid(process.pid) == process.pid:
            os.killpg(process.pid, signum)
        else:
            process.send_signal(signum)


def viewer_args(port: int, *, headless: bool) -> list[str]:
    """A native viewer's options, as ``ViewerClient.spawn`` gives them (plus no welcome
    screen)."""
    args = [
        f"--port={port}",
        "--memory-limit=75%",
        "--server-memory-limit=1GiB",
        "--expect-data-soon",
        "--hide-welcome-screen",
    ]
    return [*args, "--headless"] if headless else args


def start_viewer(
    *,
    headless: bool,
    host: str = LOOPBACK,
    port: int | None = None,
    timeout: float = 30.0,
    detach: bool = False,
) -> tuple[subprocess.Popen[bytes], str]:
    """A native viewer on ``host``, listening: (its process, its ``rerun+http`` URL);
    ``detach`` as for :func:`start_rerun`."""
    port = free_port(host) if port is None else port
    args = viewer_args(port, headless=headless)
    process = start_rerun(args, host=host, quiet=headless, detach=detach)
    try:
        wait_listening(process, host, [port], timeout)
    except BaseException:
        stop_rerun(process)
        raise
    return process, f"rerun+http://{local_address(host)}:{port}/proxy"


def viewer_client(
    *, headless: bool, host: str = LOOPBACK, detach: bool = False
) -> tuple[Any, subprocess.Popen[bytes]]:
    """A native viewer started on ``host`` and a ``ViewerClient`` connected to it:
    (client, process). The viewer keeps running until :func:`stop_rerun` of the process (or,
    unless ``detach``, until this process ends)."""
    from rerun.experimental import ViewerClient

    process, url = start_viewer(headless=headless, host=host, detach=detach)
    try:
        return ViewerClient.connect(url), process
    except BaseException:
        stop_rerun(process)
        raise


@contextlib.contextmanager
def running_viewer_client(*, headless: bool, host: str = LOOPBACK) -> Iterator[Any]:
    """:func:`viewer_client`, stopped on exit."""
    client, process = viewer_client(headless=headless, host=host)
    try:
        yield client
    finally:
        stop_rerun(process)
