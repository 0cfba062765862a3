"""The rerun processes the CLI starts end with it, unless meant to outlive it.

A server (``view --serve-web``, ``report --serve``'s web viewer) or the headless viewer of
``shots`` left behind keeps its ports, a child of nobody: they stay in the command's process
group (a hang-up or a signal to the group reaches them) and, on Linux, get SIGTERM when it
dies, however it dies. Only the windowed viewers of ``view --spawn`` and ``inspect`` get a
session of their own. Each test runs real processes and looks at them with psutil."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import psutil
import pytest

from app.cli import main
from tests.test_viz import SAMPLE
from viz import rerun_process

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(
    rerun_process.rerun_executable() is None, reason="the rerun binary is not installed"
)


def _env(home: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1", "HOME": str(home)}


def _rerun_children(pid: int) -> list[psutil.Process]:
    return [
        p
        for p in psutil.Process(pid).children(recursive=True)
        if (p.cmdline() or [""])[0].endswith("rerun")
    ]


def _gone(procs: list[psutil.Process], timeout: float = 5.0) -> list[psutil.Process]:
    """The processes still alive after ``timeout`` seconds (killed, so that nothing is left)."""
    _, alive = psutil.wait_procs(procs, timeout=timeout)
    for p in alive:
        p.kill()
    return alive


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal")
@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGTERM, signal.SIGKILL])
def test_view_serve_web_server_ends_with_the_command(tmp_path: Path, signum: int) -> None:
    """The repro: `view --serve-web` in a session of its own (as under setsid), the signal to
    its pid alone once serving; the `rerun --serve-web` server it started must not remain."""
    grpc, web = rerun_process.free_port(), rerun_process.free_port()
    argv = ["view", str(SAMPLE / "detections.json.gz"), "--frames", "0:5", "--serve-web"]
    argv += ["--grpc-port", str(grpc), "--web-port", str(web)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", *argv],
        cwd=tmp_path,
        env=_env(tmp_path),
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        start_new_session=True,
    )
    servers: list[psutil.Process] = []
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith("serving"):
                break
        else:
            pytest.fail("not served")
        servers = _rerun_children(proc.pid)
        assert len(servers) == 1
        proc.send_signal(signum)
        proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        alive = _gone(servers)  # (killed: a failing test leaves nothing running)
    assert not alive
    if signum != signal.SIGKILL:  # handled as Ctrl-C: the server stopped, the command ends
        assert proc.returncode == 0, proc.returncode
    assert not rerun_process.port_open("127.0.0.1", grpc)


_START = """
import sys, time
from viz import rerun_process
port = rerun_process.free_port()
p = rerun_process.start_rerun(
    ["--serve-web", "--web-viewer-port", str(port), "http://127.0.0.1:9/none.rrd"],
    detach={detach},
)
rerun_process.wait_listening(p, "127.0.0.1", [port])
print(p.pid, flush=True)
time.sleep(600)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal")
@pytest.mark.parametrize("detach", [False, True])
def test_only_a_detached_viewer_outlives_a_killed_parent(tmp_path: Path, detach: bool) -> None:
    """start_rerun as ViewerAssets (report --serve) and the shots viewer use it: SIGKILL of
    the parent (no clean-up runs) ends the child; a detached one (view --spawn, inspect) stays,
    in a session of its own."""
    script = textwrap.dedent(_START.format(detach=detach))
    parent = subprocess.Popen(
        [sys.executable, "-c", script],
        env=_env(tmp_path),
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    child = None
    try:
        assert parent.stdout is not None
        child = psutil.Process(int(parent.stdout.readline()))
        assert (os.getsid(child.pid) == child.pid) == detach
        assert (os.getpgid(child.pid) == os.getpgid(parent.pid)) != detach
        parent.kill()
        parent.wait()
        alive = _gone([child], timeout=5.0 if not detach else 1.0)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        if child is not None and child.is_running():
            child.kill()
    assert bool(alive) == detach


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal")
def test_the_death_signal_follows_the_thread_that_starts_the_child() -> None:
    """Why start_rerun refuses a worker thread: the kernel sends the parent-death signal when
    the *thread* that started the child ends (prctl(2)), here while the process lives on."""
    started: list[subprocess.Popen[bytes]] = []

    def start() -> None:
        die = rerun_process._die_with_parent(os.getpid())
        started.append(subprocess.Popen(["sleep", "60"], preexec_fn=die))

    worker = threading.Thread(target=start)
    worker.start()
    worker.join()
    try:
        assert started[0].wait(timeout=10) == -signal.SIGTERM
    finally:
        started[0].kill()
        started[0].wait()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal")
def test_start_rerun_refuses_a_worker_thread_unless_detached(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A server started from a worker thread would be stopped when that thread ended: refused
    (every command starts its own from the main thread); a detached viewer, which has no death
    signal, may start from any thread."""
    monkeypatch.setattr(rerun_process, "rerun_command", lambda args, host: ["sleep", "60"])
    outcome: dict[bool, object] = {}

    def start(detach: bool) -> None:
        try:
            outcome[detach] = rerun_process.start_rerun([], detach=detach)
        except RuntimeError as exc:
            outcome[detach] = exc

    for detach in (False, True):
        worker = threading.Thread(target=start, args=(detach,), name="worker")
        worker.start()
        worker.join()
    assert isinstance(outcome[False], RuntimeError)
    assert str(outcome[False]) == (
        "start_rerun from thread 'worker': a server or headless viewer is started from the main "
        "thread only (its death signal follows the thread that starts it)"
    )
    detached = outcome[True]
    assert isinstance(detached, subprocess.Popen)
    try:
        assert detached.poll() is None  # (not stopped with the thread that started it)
    finally:
        rerun_process.stop_rerun(detached)


def test_view_serve_web_handles_sigterm_and_sighup_before_the_server_starts(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A signal while the server starts or while the scenes are recorded stops the server as
    Ctrl-C does (the handlers were installed only once recording was done)."""
    seen: list[object] = []

    def start(args: list[str], **kwargs: object) -> object:
        seen.extend(signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP))
        raise KeyboardInterrupt  # (as the handler does)

    monkeypatch.setattr(rerun_process, "start_rerun", start)
    monkeypatch.setattr(rerun_process, "port_open", lambda *a: False)
    argv = ["view", str(SAMPLE / "detections.json.gz"), "--frames", "0:5", "--serve-web"]
    before = [signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)]
    assert main(argv) == 130
    from app.serve import _interrupt

    assert seen == [_interrupt, _interrupt]
    assert [signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)] == before
