"""The viewers and servers the CLI starts listen on 127.0.0.1 unless told otherwise (--host).

Rerun's Python API (0.41) listens on all interfaces and has no bind address; each test looks
at the sockets the started processes really listen on (psutil), so that a viewer started the
old way (0.0.0.0) fails it."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest

from app.cli import main
from tests.test_report import stopped_by_sigterm
from tests.test_viz import SAMPLE, recording
from viz import rerun_process
from viz.shots import renderer_available

ROOT = Path(__file__).resolve().parents[1]


def listening(pid: int) -> list[tuple[str, int]]:
    """(address, port) of every listening TCP socket of the process and its children."""
    proc = psutil.Process(pid)
    found = []
    for p in [proc, *proc.children(recursive=True)]:
        with_sockets = p.net_connections(kind="inet")
        found += [(c.laddr.ip, c.laddr.port) for c in with_sockets if c.status == "LISTEN"]
    return sorted(found)


def _needs_renderer() -> None:
    ok, why = renderer_available()
    if not ok:
        pytest.skip(f"no software renderer: {why}")
    if rerun_process.rerun_executable() is None:
        pytest.skip("the rerun binary of rerun-sdk is not installed")


@pytest.fixture
def started(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[list]:
    """The rerun processes a command starts, headless instead of windowed (no display here),
    stopped at the end (inspect and view --spawn leave theirs running, as for a person)."""
    _needs_renderer()
    procs: list[subprocess.Popen[bytes]] = []
    real_start, real_args = rerun_process.start_rerun, rerun_process.viewer_args

    def spy(args: list[str], **kwargs: object) -> subprocess.Popen[bytes]:
        proc = real_start(args, **kwargs)  # type: ignore[arg-type]
        procs.append(proc)
        return proc

    monkeypatch.setattr(rerun_process, "start_rerun", spy)
    monkeypatch.setattr(
        rerun_process, "viewer_args", lambda port, headless: real_args(port, headless=True)
    )
    monkeypatch.setenv("HOME", str(tmp_path))  # the viewer's state, not the user's
    monkeypatch.setenv("DISPLAY", ":mctrack-test")  # (inspect and --spawn check for one)
    yield procs
    for proc in procs:
        rerun_process.stop_rerun(proc)


def test_loopback_and_exposure_note() -> None:
    assert rerun_process.is_loopback("127.0.0.1") and rerun_process.is_loopback("127.0.0.2")
    assert rerun_process.is_loopback("::1")
    assert not rerun_process.is_loopback("0.0.0.0") and not rerun_process.is_loopback("::")
    assert not rerun_process.is_loopback("192.168.1.5")
    assert rerun_process.exposure_note("127.0.0.1", "it") is None
    assert rerun_process.exposure_note("0.0.0.0", "it") == (
        "note: --host 0.0.0.0 exposes it to the network"
    )
    assert rerun_process.local_address("0.0.0.0") == "127.0.0.1"
    assert rerun_process.local_address("::") == "[::1]"


def test_shots_viewer_listens_on_loopback_only() -> None:
    """`mctrack shots` and `report --shots`: the headless viewer (ViewerClient.spawn's
    listened on 0.0.0.0)."""
    _needs_renderer()
    from viz.shots import headless_viewer

    with headless_viewer() as client:
        pids = [p.pid for p in psutil.process_iter(["cmdline"]) if _ours(p, client.url)]
        assert len(pids) == 1
        sockets = listening(pids[0])
        assert sockets and all(ip == "127.0.0.1" for ip, _ in sockets), sockets


def _ours(proc: psutil.Process, url: str) -> bool:
    """Is ``proc`` the viewer behind ``url`` (its --port)?"""
    port = url.rsplit(":", 1)[1].split("/")[0]
    cmd = proc.info.get("cmdline") or []
    return bool(cmd) and cmd[0].endswith("rerun") and f"--port={port}" in cmd


def test_inspect_viewer_listens_on_loopback_only(
    started: list, capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = recording()
    assert main(["inspect", str(path), "--frame", "12"]) == 0
    assert "viewer started at frame 12" in capsys.readouterr().out
    assert len(started) == 1 and started[0].poll() is None  # left running for the person
    sockets = listening(started[0].pid)
    assert sockets and all(ip == "127.0.0.1" for ip, _ in sockets), sockets


def test_view_spawn_viewer_listens_on_loopback_and_gets_the_recording(
    started: list, capsys: pytest.CaptureFixture[str]
) -> None:
    from rerun.experimental import ViewerClient

    port = rerun_process.free_port()
    det = SAMPLE / "detections.json.gz"
    argv = ["view", str(det), "--frames", "0:5", "--spawn", "--grpc-port", str(port)]
    assert main(argv) == 0
    assert "scene 0001: 5 frames" in capsys.readouterr().out
    assert len(started) == 1 and started[0].poll() is None
    sockets = listening(started[0].pid)
    assert sockets == [("127.0.0.1", port)]
    client = ViewerClient.connect(f"rerun+http://127.0.0.1:{port}/proxy")
    deadline = time.monotonic() + 30
    while not client.get_state().recordings and time.monotonic() < deadline:
        time.sleep(0.2)
    assert client.get_state().recordings  # the scene reached the viewer


def test_view_serve_web_listens_on_loopback_and_stops_on_sigterm(tmp_path: Path) -> None:
    """`mctrack view --serve-web`: the gRPC server and the web viewer (rr.serve_grpc and
    rr.serve_web_viewer listened on 0.0.0.0), stopped with the command."""
    if rerun_process.rerun_executable() is None:
        pytest.skip("the rerun binary of rerun-sdk is not installed")
    grpc, web = rerun_process.free_port(), rerun_process.free_port()
    det = SAMPLE / "detections.json.gz"
    argv = ["view", str(det), "--frames", "0:5", "--serve-web"]
    argv += ["--grpc-port", str(grpc), "--web-port", str(web)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", *argv],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1", "HOME": str(tmp_path)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        lines = []
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("serving"):
                break
        else:
            pytest.fail(f"not served: {lines} {proc.stderr.read() if proc.stderr else ''}")
        sockets = listening(proc.pid)
        assert sorted(port for _, port in sockets) == sorted([grpc, web])
        assert all(ip == "127.0.0.1" for ip, _ in sockets), sockets
        assert lines[0] == (
            f"web viewer: http://127.0.0.1:{web}/?url=rerun+http://127.0.0.1:{grpc}/proxy\n"
        )
        servers = psutil.Process(proc.pid).children(recursive=True)
    finally:
        out = stopped_by_sigterm(proc)
    assert proc.returncode == 0 and out.strip().endswith("stopped")
    _, alive = psutil.wait_procs(servers, timeout=10)
    for p in alive:
        p.kill()
    assert not alive
    assert not rerun_process.port_open("127.0.0.1", grpc)


def _fake_start(monkeypatch: pytest.MonkeyPatch) -> list[list[str]]:
    """The argv of each rerun binary view would start; none is started, nothing recorded."""
    seen: list[list[str]] = []

    class Fake:
        pid = -1
        returncode = 0

        def poll(self) -> int:
            return 0

    def start(args: list[str], *, host: str, **kwargs: object) -> Fake:
        seen.append(rerun_process.rerun_command(args, host=host, executable="rerun"))
        return Fake()

    monkeypatch.setattr(rerun_process, "start_rerun", start)
    monkeypatch.setattr(rerun_process, "wait_listening", lambda *a, **k: None)
    monkeypatch.setattr(rerun_process, "stop_rerun", lambda p: None)
    monkeypatch.setattr("app.view._record", lambda *a, **k: None)
    monkeypatch.setattr("app.view._serve_until_stopped", lambda: None)
    return seen


def test_view_serve_web_host_is_passed_to_the_binary_with_a_note(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """--host 0.0.0.0 (exposing it, deliberately) reaches the binary's --bind, with a note;
    nothing is bound here (the binary is not started). The URL printed is one a browser on
    another machine can use (it named 127.0.0.1, there the other machine itself), with the one
    for this machine after it."""
    seen = _fake_start(monkeypatch)
    monkeypatch.setattr(rerun_process.socket, "gethostname", lambda: "studio-box")
    det = SAMPLE / "detections.json.gz"
    argv = ["view", str(det), "--frames", "0:5", "--serve-web", "--host", "0.0.0.0"]
    assert main([*argv, "--grpc-port", "9001", "--web-port", "9002"]) == 0
    assert seen == [
        ["rerun", "--bind", "0.0.0.0", "--serve-web", "--port", "9001", "--web-viewer-port", "9002"]
    ]
    out = capsys.readouterr().out
    assert out.splitlines()[:3] == [
        "web viewer: http://studio-box:9002/?url=rerun+http://studio-box:9001/proxy",
        "  listening on all interfaces; on this machine: "
        "http://127.0.0.1:9002/?url=rerun+http://127.0.0.1:9001/proxy",
        "note: --host 0.0.0.0 exposes the recording to the network",
    ]


@pytest.mark.parametrize("host", ["0.0.0.0", "127.0.0.1"])
def test_view_spawn_prints_the_url_another_machine_uses(
    host: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """--spawn --host 0.0.0.0 exposes the viewer's gRPC server (recordings from elsewhere,
    `rerun URL` on another machine) but printed no URL at all, only the note: now the one
    another machine uses and this machine's after it, as --serve-web prints them; on loopback
    the URL alone (nothing is started here)."""
    seen = _fake_start(monkeypatch)
    monkeypatch.setattr(rerun_process, "port_open", lambda *a: False)
    monkeypatch.setattr(rerun_process.socket, "gethostname", lambda: "studio-box")
    monkeypatch.setenv("DISPLAY", ":mctrack-test")
    det = SAMPLE / "detections.json.gz"
    argv = ["view", str(det), "--frames", "0:5", "--spawn", "--host", host, "--grpc-port", "9001"]
    assert main(argv) == 0
    assert seen == [["rerun", "--bind", host, *rerun_process.viewer_args(9001, headless=False)]]
    expected = {
        "0.0.0.0": [
            "viewer: rerun+http://studio-box:9001/proxy",
            "  listening on all interfaces; on this machine: rerun+http://127.0.0.1:9001/proxy",
            "note: --host 0.0.0.0 exposes the recording to the network",
        ],
        "127.0.0.1": ["viewer: rerun+http://127.0.0.1:9001/proxy"],
    }
    assert capsys.readouterr().out.splitlines() == expected[host]


def test_view_spawn_to_a_running_viewer_says_host_is_not_applied(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A viewer already on the port is used as it is: --host 0.0.0.0 binds nothing then, and
    no note says the recording is exposed."""
    seen = _fake_start(monkeypatch)
    monkeypatch.setattr(rerun_process, "port_open", lambda *a: True)
    monkeypatch.setenv("DISPLAY", ":mctrack-test")
    det = SAMPLE / "detections.json.gz"
    argv = ["view", str(det), "--frames", "0:5", "--spawn", "--host", "0.0.0.0"]
    assert main([*argv, "--grpc-port", "9001"]) == 0
    assert seen == []
    assert capsys.readouterr().out.splitlines() == [
        "viewer: rerun+http://127.0.0.1:9001/proxy (already running)",
        "  --host 0.0.0.0 not applied: that viewer listens where it was started",
    ]


def test_served_at_names_an_address_a_browser_can_use(monkeypatch: pytest.MonkeyPatch) -> None:
    def url(at: str) -> str:
        return f"http://{at}:80/"

    monkeypatch.setattr(rerun_process.socket, "gethostname", lambda: "studio-box")
    assert rerun_process.served_at("127.0.0.1", url) == ("http://127.0.0.1:80/", None)
    assert rerun_process.served_at("192.168.1.5", url) == ("http://192.168.1.5:80/", None)
    assert rerun_process.served_at("::1", url) == ("http://[::1]:80/", None)
    assert rerun_process.served_at("::", url) == (
        "http://studio-box:80/",
        "  listening on all interfaces; on this machine: http://[::1]:80/",
    )
    monkeypatch.setattr(rerun_process.socket, "gethostname", lambda: "localhost")  # (no use)
    assert rerun_process.served_at("0.0.0.0", url) == (
        "http://127.0.0.1:80/",
        "  listening on all interfaces: from another machine, this machine's address for 127.0.0.1",
    )


def test_report_serve_on_all_interfaces_prints_a_url_for_other_machines(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """report --serve --host 0.0.0.0 printed http://127.0.0.1:PORT/ (nothing is bound here: the
    server is a stand-in, stopped as by Ctrl-C once it has printed)."""
    import contextlib

    from app import serve

    class Server:
        server_address = ("0.0.0.0", 8765)

    @contextlib.contextmanager
    def server(*args: object, **kwargs: object) -> Iterator[tuple[Server, str]]:
        yield Server(), "http://127.0.0.1:8765/"

    def ctrl_c(seconds: float) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(serve, "report_server", server)
    monkeypatch.setattr(serve.time, "sleep", ctrl_c)
    monkeypatch.setattr(rerun_process.socket, "gethostname", lambda: "studio-box")
    assert serve.serve_report(tmp_path, {}, host="0.0.0.0", port=8765) == 0
    assert capsys.readouterr().out.splitlines() == [
        "serving the report at http://studio-box:8765/ (Ctrl-C to stop)",
        "  listening on all interfaces; on this machine: http://127.0.0.1:8765/",
        "note: --host 0.0.0.0 exposes the report and recordings to the network",
        "stopped",
    ]


def test_view_serve_web_refuses_a_port_in_use(capsys: pytest.CaptureFixture[str]) -> None:
    """A --grpc-port or --web-port another server holds: one line, before any recording (the
    other server would have answered the viewer instead)."""
    import socket

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        taken = held.getsockname()[1]
        det = SAMPLE / "detections.json.gz"
        argv = ["view", str(det), "--frames", "0:5", "--serve-web", "--web-port", str(taken)]
        assert main([*argv, "--grpc-port", str(rerun_process.free_port())]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"mctrack view: error: --web-port {taken}: in use on 127.0.0.1; choose another port\n"
    )


def test_view_host_localhost_is_bound_as_127_0_0_1(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The binary's --bind takes no host name (`invalid value 'localhost'`, status 2): --host
    localhost is given to it as 127.0.0.1, on loopback (no note)."""
    seen = _fake_start(monkeypatch)
    det = SAMPLE / "detections.json.gz"
    argv = ["view", str(det), "--frames", "0:5", "--serve-web", "--host", "localhost"]
    assert main([*argv, "--grpc-port", "9001", "--web-port", "9002"]) == 0
    assert [a[:3] for a in seen] == [["rerun", "--bind", "127.0.0.1"]]
    assert "note:" not in capsys.readouterr().out


def test_rerun_binary_refuses_a_host_name() -> None:
    """Why --host must be an IP address: the binary itself (0.41) refuses a name."""
    if rerun_process.rerun_executable() is None:
        pytest.skip("the rerun binary of rerun-sdk is not installed")
    proc = rerun_process.start_rerun(["--serve-web"], host="localhost")
    assert proc.wait(timeout=30) == 2


@pytest.mark.parametrize("command", ["view", "report"])
@pytest.mark.parametrize("host", ["myhost", "example.org", "127.0.0.300", ""])
def test_host_not_an_ip_address_is_a_usage_error(
    command: str, host: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """view and report --serve take the same --host, checked by one function (report took a
    host name, which view refuses, and failed on a bad one only once the report was made)."""
    if command == "view":
        argv = ["view", str(SAMPLE / "detections.json.gz"), "--serve-web"]
    else:
        argv = ["report", str(tmp_path / "run"), "--out", str(tmp_path / "r"), "--serve"]
    with pytest.raises(SystemExit) as exit:
        main([*argv, "--host", host])
    assert exit.value.code == 2
    err = capsys.readouterr().err
    assert err == (
        f"mctrack {command}: error: argument --host: expected an IP address (127.0.0.1, "
        f"0.0.0.0, ::1) or localhost, got {host!r} (see mctrack {command} --help)\n"
    )
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    ("command", "option", "port", "lowest"),
    [
        ("view", "--web-port", "70000", 1),
        ("view", "--grpc-port", "0", 1),  # (rerun would pick one the command does not know)
        ("view", "--grpc-port", "-1", 1),
        ("report", "--port", "65536", 0),
        ("report", "--port", "x", 0),
    ],
)
def test_port_out_of_range_is_a_usage_error(
    command: str,
    option: str,
    port: str,
    lowest: int,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A port past 65535 ended view and report with socket's OverflowError, reported as a bug
    (exit 1; report once the report was made)."""
    if command == "view":
        argv = ["view", str(SAMPLE / "detections.json.gz"), "--serve-web"]
    else:
        argv = ["report", str(tmp_path / "run"), "--out", str(tmp_path / "r"), "--serve"]
    with pytest.raises(SystemExit) as exit:
        main([*argv, option, port])
    assert exit.value.code == 2
    assert capsys.readouterr().err == (
        f"mctrack {command}: error: argument {option}: expected a port {lowest}..65535, got "
        f"{port!r} (see mctrack {command} --help)\n"
    )


@pytest.mark.parametrize("given", [["--host", "0.0.0.0"], ["--port", "0"]])
def test_report_host_and_port_without_serve_are_refused(
    given: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--host and --port without --serve were ignored without a word: refused before any work,
    as view refuses --host without a viewer."""
    from tests.report_fixtures import make_runs

    run, _, _ = make_runs(tmp_path)
    out = tmp_path / "r"
    assert main(["report", str(run), "--out", str(out), *given]) == 2
    option, value = given
    assert capsys.readouterr().err == (
        f"mctrack report: error: {option} {value}: only with --serve; without it report writes "
        "the folder\n"
    )
    assert not out.exists()


def test_report_serves_on_an_ipv6_address(tmp_path: Path) -> None:
    """--host ::1, an IP address --host takes, was refused by the server ("Address family for
    hostname not supported"): it bound IPv4 only."""
    import socket
    import urllib.request

    from app.serve import report_server

    with socket.socket(socket.AF_INET6) as probe:
        try:
            probe.bind(("::1", 0))
        except OSError:
            pytest.skip("no IPv6 loopback here")
    (tmp_path / "index.html").write_text("<p>report</p>")
    with report_server(tmp_path, {}, host="::1", with_viewer=False) as (_, url):
        assert url.startswith("http://[::1]:")
        with urllib.request.urlopen(url, timeout=30) as answer:
            assert answer.read() == b"<p>report</p>"


def test_viewer_exit_names_a_port_in_use_only_when_it_is() -> None:
    """The viewer's exit was put down to "is port N in use?" whatever its cause (a host name
    it refused, a bad option); now said only when the port is taken."""
    import socket

    if rerun_process.rerun_executable() is None:
        pytest.skip("the rerun binary of rerun-sdk is not installed")
    free = rerun_process.free_port()
    bad = rerun_process.start_rerun(["--no-such-option"])
    with pytest.raises(RuntimeError) as refused:
        rerun_process.wait_listening(bad, "127.0.0.1", [free])
    assert str(refused.value) == "the rerun viewer exited (status 2)"
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        taken = held.getsockname()[1]
        web = rerun_process.free_port()
        args = ["--serve-web", "--port", str(taken), "--web-viewer-port", str(web)]
        proc = rerun_process.start_rerun(args)  # (its gRPC server cannot listen: it exits)
        try:
            with pytest.raises(RuntimeError) as in_use:
                rerun_process.wait_listening(proc, "127.0.0.1", [taken, web])
        finally:
            rerun_process.stop_rerun(proc)
    assert str(in_use.value).endswith(f"; port {taken} is in use")
