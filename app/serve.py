"""`mctrack report ... --serve`: the report, its runs' recordings and Rerun's web viewer, from
one HTTP server on 127.0.0.1.

* ``/`` the report folder (``index.html``; ``serve.json`` tells the page it is served);
* ``/recordings/<a|b>/<seq>.rrd`` the runs' recordings (only those, looked up by name: no path
  from a request reaches the file system);
* ``/viewer/`` Rerun's web viewer. The rerun-sdk wheel embeds it in its ``rerun`` binary, which
  serves it (``rerun --serve-web --bind 127.0.0.1``) on a private port; this server relays its
  files, so page, recordings and viewer share one origin (no CORS). The viewer page is the
  wheel's own, with the web-font link removed (no network) and a small script that moves the
  time cursor to ``?frame=N`` once the recording is loaded, through the viewer's control API
  (``WebHandle.viewer_control``, the same ``set_time_cursor`` request as
  ``rerun.experimental.ViewerClient.set_time``): a ``#when=`` URL fragment does not move it in
  0.41 (docs/debugger.md).
"""

from __future__ import annotations

import contextlib
import http.server
import json
import mimetypes
import re
import signal
import socket
import sys
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from tracker.errors import ViewerError

VIEWER_PREFIX = "/viewer/"
RECORDINGS_PREFIX = "/recordings/"

# Seek once the recording is loaded; retried, as the viewer loads the file after it starts.
SEEK_SCRIPT = """<script>
(function () {
  const frame = new URLSearchParams(location.search).get("frame");
  if (frame === null || !/^[0-9]+$/.test(frame)) return;
  function varint(n) {  // protobuf base-128 varint of a non-negative integer
    const out = [];
    while (n > 127) { out.push((n % 128) | 128); n = Math.floor(n / 128); }
    out.push(n); return out;
  }
  function field(tag, bytes) { return [tag, ...varint(bytes.length), ...bytes]; }
  // ViewerControlRequest{set_time_cursor(6): {timeline(2): {name(1)}, time(3): {time(1)},
  // play_state(5): PAUSED(1)}}, the messages of rerun/v1alpha1/viewer_control.proto
  const name = Array.from(new TextEncoder().encode("frame"));
  const cursor = [...field(0x12, field(0x0a, name)),
                  ...field(0x1a, [0x08, ...varint(parseInt(frame, 10))]), 0x28, 0x01];
  const request = new Uint8Array(field(0x32, cursor));
  const started = Date.now();
  function attempt() {
    const handle = window._handle;
    if (Date.now() - started > 180000) return;
    if (!handle) { setTimeout(attempt, 500); return; }
    // Before the recording is active the call may never answer: give up on it after 5 s.
    const timeout = new Promise((_, reject) => setTimeout(() => reject("timeout"), 5000));
    Promise.race([handle.viewer_control(request), timeout])
      .then(function (response) {
        // the answer names the timeline it moved ("frame"); anything else: not loaded yet
        const text = new TextDecoder().decode(response);
        if (text.includes("frame")) window.mctrackSeeked = parseInt(frame, 10);
        else setTimeout(attempt, 1000);
      })
      .catch(function () { setTimeout(attempt, 1000); });
  }
  attempt();
})();
</script>"""


class ViewerAssets:
    """Rerun's web viewer files, from the wheel's ``rerun`` binary on a private loopback port."""

    def __init__(self, port: int) -> None:
        from viz.rerun_process import LOOPBACK, start_rerun

        self.base = f"http://{LOOPBACK}:{port}"
        # With a URL to show the binary hosts the web viewer only (no gRPC server). The URL is
        # never fetched by it: the page's own ?url= replaces it.
        self.process = start_rerun(
            ["--serve-web", "--web-viewer-port", str(port), "http://127.0.0.1:9/none.rrd"],
            host=LOOPBACK,
        )
        self._cache: dict[str, tuple[bytes, str]] = {}
        self._lock = threading.Lock()

    def wait(self, timeout: float = 30.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise ViewerError(f"the rerun web viewer exited (status {self.process.returncode})")
            with contextlib.suppress(OSError):
                with urllib.request.urlopen(self.base + "/", timeout=2) as r:
                    if r.status == 200:
                        return
            time.sleep(0.2)
        raise ViewerError(f"the rerun web viewer did not answer in {timeout:.0f} s")

    def get(self, name: str) -> tuple[bytes, str] | None:
        """(bytes, content type) of ``/viewer/<name>`` (``""``: the patched index.html)."""
        if not re.fullmatch(r"[A-Za-z0-9_.-]*", name) or name.startswith("."):
            return None
        with self._lock:
            if name in self._cache:
                return self._cache[name]
        try:
            with urllib.request.urlopen(f"{self.base}/{name}", timeout=60) as r:
                data, ctype = r.read(), r.headers.get("Content-Type", "application/octet-stream")
        except (urllib.error.URLError, OSError):
            return None
        if name in ("", "index.html"):
            text = data.decode("utf-8")
            text = re.sub(r"<link[^>]*fonts\.(googleapis|gstatic)\.com[^>]*>", "", text, flags=re.S)
            text = text.replace("</body>", SEEK_SCRIPT + "\n</body>")
            data, ctype = text.encode("utf-8"), "text/html; charset=utf-8"
        with self._lock:
            self._cache[name] = (data, ctype)
        return data, ctype

    def stop(self) -> None:
        from viz.rerun_process import stop_rerun

        stop_rerun(self.process)


def _handler(root: Path, recordings: Mapping[str, Path], viewer: ViewerAssets | None) -> type:
    root = root.resolve()

    class Handler(http.server.BaseHTTPRequestHandler):
        server_version = "mctrack-report"

        def log_message(self, format: str, *args: Any) -> None:
            pass

        def _send(self, data: bytes, ctype: str, status: int = 200) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(data)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(data)

        def _file(self, path: Path) -> None:
            ctype = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
            size = path.stat().st_size
            self.send_response(200)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(size))
            self.end_headers()
            if self.command == "HEAD":
                return
            with open(path, "rb") as fh:
                while chunk := fh.read(1 << 20):
                    self.wfile.write(chunk)

        def do_HEAD(self) -> None:
            self.do_GET()

        def do_GET(self) -> None:
            path = urllib.parse.unquote(self.path.split("?", 1)[0])
            try:
                if path == "/serve.json":
                    info = {
                        "viewer": VIEWER_PREFIX if viewer else None,
                        "recordings": sorted(recordings),
                    }
                    return self._send(json.dumps(info).encode(), "application/json")
                if path.startswith(RECORDINGS_PREFIX) and path.endswith(".rrd"):
                    rec = recordings.get(path[len(RECORDINGS_PREFIX) : -len(".rrd")])
                    if rec is not None and rec.is_file():
                        return self._file(rec)
                    return self._send(b"no such recording", "text/plain", 404)
                if path.startswith(VIEWER_PREFIX) and viewer is not None:
                    got = viewer.get(path[len(VIEWER_PREFIX) :])
                    if got is None:
                        return self._send(b"not found", "text/plain", 404)
                    return self._send(*got)
                rel = path.lstrip("/") or "index.html"
                target = (root / rel).resolve()
                if target.is_dir():
                    target = target / "index.html"
                if root not in target.parents or not target.is_file():
                    return self._send(b"not found", "text/plain", 404)
                return self._file(target)
            except (BrokenPipeError, ConnectionResetError):
                return None

    return Handler


class _Server6(http.server.ThreadingHTTPServer):
    """The server on an IPv6 address (``--host ::1``; ``::`` takes IPv4 too, as ``0.0.0.0``
    would): the base class binds IPv4 only."""

    address_family = socket.AF_INET6

    def server_bind(self) -> None:
        with contextlib.suppress(OSError, AttributeError):  # (the system's default otherwise)
            self.socket.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 0)
        super().server_bind()


@contextlib.contextmanager
def report_server(
    root: Path,
    recordings: Mapping[str, Path],
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    with_viewer: bool = True,
) -> Iterator[tuple[http.server.ThreadingHTTPServer, str]]:
    """The server running in a thread: (server, base URL); stopped (with the viewer process)
    on exit."""
    from viz.rerun_process import free_port, local_address

    viewer = None
    if with_viewer:
        viewer = ViewerAssets(free_port())
    server = None
    thread = None
    try:
        if viewer is not None:
            viewer.wait()
        server_type = _Server6 if ":" in host else http.server.ThreadingHTTPServer
        server = server_type((host, port), _handler(root, recordings, viewer))
        server.daemon_threads = True
        thread = threading.Thread(target=server.serve_forever, name="mctrack-report", daemon=True)
        thread.start()
        yield server, f"http://{local_address(host)}:{server.server_address[1]}/"
    finally:
        if server is not None:
            server.shutdown()
            server.server_close()
        if thread is not None:
            thread.join(timeout=10)
        if viewer is not None:
            viewer.stop()


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


@contextlib.contextmanager
def stopped_as_by_ctrl_c() -> Iterator[None]:
    """SIGTERM (kill, a CI timeout, docker stop) and SIGHUP (the terminal closed) end the block
    as Ctrl-C does, so that its clean-up stops the servers it started: by default they ended
    the process at once, and a rerun server kept running, holding its ports. Installed before
    the servers start (a signal while they start or while recording is handled too)."""
    signals = [signal.SIGTERM] + ([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])
    previous = {s: signal.signal(s, _interrupt) for s in signals}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def serve_report(root: Path, recordings: Mapping[str, Path], *, host: str, port: int) -> int:
    """Serve until Ctrl-C, SIGTERM or SIGHUP."""
    from viz.rerun_process import exposure_note, served_at

    try:
        with stopped_as_by_ctrl_c(), report_server(root, recordings, host=host, port=port) as run:
            bound = run[0].server_address[1]  # (--port 0: the one it got)
            url, listening = served_at(host, lambda at: f"http://{at}:{bound}/")
            print(f"serving the report at {url} (Ctrl-C to stop)", flush=True)
            if listening:
                print(listening)
            note = exposure_note(host, "the report and recordings")
            if note:
                print(note)
            while True:
                time.sleep(3600)
    except KeyboardInterrupt:
        print("stopped")
        return 0
    except OSError as exc:
        print(f"mctrack report: cannot serve on {host}:{port}: {exc}", file=sys.stderr)
        return 2
