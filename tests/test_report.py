"""`mctrack report`: the static page, in a real browser (headless Chromium driven by
Playwright), and `--serve` (page, recordings and Rerun's web viewer on loopback).

The browser tests skip with the reason where Chromium or Playwright is absent (`.ci/run`
installs Debian's chromium; Playwright comes with the `dev` extra and drives the system
browser, it downloads none). Set MCTRACK_REPORT_SCREENSHOT=DIR to keep the screenshots."""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import signal
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from app.cli import main
from tests.report_fixtures import SEQ, make_runs


def chromium_path() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.fixture(scope="module")
def browser():
    exe = chromium_path()
    if exe is None:
        pytest.skip("no Chromium (apt-get install -y chromium): browser tests skipped")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright not installed (pip install -e '.[dev]'): browser tests skipped")
    with sync_playwright() as pw:
        b = pw.chromium.launch(
            executable_path=exe,
            # the web viewer needs WebGL: Chromium's software renderer, explicitly allowed
            args=["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"],
        )
        yield b
        b.close()


def _keep_screenshot(path: Path) -> None:
    keep = os.environ.get("MCTRACK_REPORT_SCREENSHOT")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, Path(keep) / path.name)


def check_page(browser, index: Path, screenshot: Path) -> dict:
    """Open ``index`` from disk; every image loaded, no console error; a full-page screenshot.
    Returns what the page shows: event rows, images."""
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("requestfailed", lambda r: errors.append(f"request failed: {r.url}"))
    page.goto(index.resolve().as_uri())
    page.wait_for_load_state("load")
    images = page.eval_on_selector_all(
        "img", "els => els.map(e => [e.getAttribute('src'), e.complete, e.naturalWidth])"
    )
    rows = page.eval_on_selector_all(
        "#events-table tbody tr", "els => els.map(r => Array.from(r.cells, c => c.innerText))"
    )
    headers = page.eval_on_selector_all(
        "#events-table thead th", "els => els.map(e => e.innerText)"
    )
    # sorting: a click on "frame" orders the rows by frame, a second one reverses them
    sorted_frames = []
    if rows:
        col = headers.index("frame")
        for _ in range(2):
            page.click(f"#events-table thead th:nth-child({col + 1})")
            sorted_frames.append(
                page.eval_on_selector_all(
                    "#events-table tbody tr",
                    f"els => els.map(r => parseInt(r.cells[{col}].innerText))",
                )
            )
    page.screenshot(path=str(screenshot), full_page=True)
    _keep_screenshot(screenshot)
    page.close()
    assert not errors, errors
    assert images, "no images on the page"
    bad = [src for src, complete, width in images if not complete or width <= 0]
    assert not bad, f"images not loaded: {bad}"
    assert screenshot.stat().st_size > 20_000
    return {"rows": rows, "headers": headers, "images": images, "sorted": sorted_frames}


def test_report_hand_made_compare(tmp_path: Path, browser) -> None:
    a, b, _ = make_runs(tmp_path)
    out = tmp_path / "report"
    assert main(["report", str(a), "--compare", str(b), "--out", str(out)]) == 0
    assert (out / "index.html").is_file() and (out / "compare.json").is_file()
    assert (out / "plots" / "idsw_per_sequence.svg").is_file()
    seen = check_page(browser, out / "index.html", tmp_path / "report_hand_made.png")
    rows, headers = seen["rows"], seen["headers"]
    assert len(rows) == 3
    status, gt, frame = headers.index("status"), headers.index("GT"), headers.index("frame")
    got = sorted((r[status], r[gt], r[frame]) for r in rows)
    # the kept switch is shown as in B (frame 4; A had it at 3)
    assert got == [("fixed", "1", "5"), ("introduced", "3", "6"), ("kept", "2", "4")]
    asc, desc = seen["sorted"]
    assert asc == sorted(asc) and desc == sorted(asc, reverse=True)


def test_report_shows_names_from_the_runs_as_text(tmp_path: Path) -> None:
    """A sequence and a class named with HTML and a matplotlib "$": escaped in the page, and
    plotted as they are (a "$\\frac{$" tick label was matplotlib's mathtext parse error, exit 1
    with the report half-written)."""
    from tracker.io.fileio import safe_filename

    seq, cls = "<script>alert(1)</script>$\\frac{$", "<img src=x onerror=alert(2)>$\\frac{$"
    a, b, labels = make_runs(tmp_path)
    shutil.copy(labels / f"{SEQ}.txt", labels / f"{safe_filename(seq)}.txt")
    for run in (a, b):
        (run / "data" / f"{SEQ}.txt").rename(run / "data" / f"{safe_filename(seq)}.txt")
        summary = json.loads((run / "summary.json").read_text())
        summary["sequences"] = [seq]
        summary["per_sequence"] = {seq: summary["per_sequence"][SEQ]}
        summary["metrics"][cls] = summary["metrics"]["car"]
        (run / "summary.json").write_text(json.dumps(summary))
    out = tmp_path / "report"
    assert main(["report", str(a), "--compare", str(b), "--out", str(out)]) == 0
    page = (out / "index.html").read_text()
    assert "<script>alert" not in page and "<img src=x" not in page
    assert html.escape(seq) in page and html.escape(cls) in page
    # the plots name them as they are (matplotlib's SVG keeps each text in a comment)
    assert html.escape(cls) in (out / "plots" / "hota.svg").read_text()
    assert html.escape(seq) in (out / "plots" / "idsw_per_sequence.svg").read_text()


def _svg_texts(path: Path) -> list[str]:
    """The texts of a matplotlib SVG (each kept in a comment beside its glyphs)."""
    return re.findall(r"<!-- (.*?) -->", path.read_text())


def test_report_plots_compare_what_the_tables_compare(tmp_path: Path) -> None:
    """A over two sequences, B over one: the plots show the shared sequence only (A's switches
    on 0002 were plotted against B's 0 there, and A's HOTA over both against B's over one), as
    the metrics table does, and say so; the motion plots, which compare leaves out, are not
    drawn. Runs of the same sequences keep them."""
    from tests.test_compare import _with_second_sequence

    motion = {"metrics": {"kalman": {"car": {"vae_deg": 3.0, "vne_mps": 0.25}}}}
    a, b, labels = make_runs(tmp_path)
    for run in (a, b):
        summary = json.loads((run / "summary.json").read_text())
        (run / "summary.json").write_text(json.dumps({**summary, "motion": motion}))
    out = tmp_path / "same"
    assert main(["report", str(a), "--compare", str(b), "--out", str(out)]) == 0
    assert (out / "plots" / "motion_vae_deg.svg").is_file()
    assert "3" in _svg_texts(out / "plots" / "motion_vae_deg.svg")
    assert "90" in _svg_texts(out / "plots" / "hota.svg")  # (A's summary: over SEQ exactly)

    _with_second_sequence(a, labels)
    out = tmp_path / "report"
    assert main(["report", str(a), "--compare", str(b), "--out", str(out)]) == 0
    result = json.loads((out / "compare.json").read_text())
    assert result["sequences_compared"] == [SEQ]
    idsw = _svg_texts(out / "plots" / "idsw_per_sequence.svg")
    assert SEQ in idsw and "0002" not in idsw
    assert "IDSW per sequence, the 1 compared sequence(s)" in idsw
    hota = _svg_texts(out / "plots" / "hota.svg")
    rescored = result["metrics"]["car"]["HOTA"]["a"]
    assert f"{rescored:.4g}" in hota and "90" not in hota  # (90: A's summary, both sequences)
    assert not list((out / "plots").glob("motion_*.svg"))
    page = (out / "index.html").read_text()
    assert f"HOTA per class, on the 1 sequence(s) both runs scored ({SEQ})" in page
    assert "No motion plots: the runs&#x27; motion metrics cover different sequences" in page


def test_report_into_an_earlier_report_removes_what_it_does_not_write(tmp_path: Path) -> None:
    """A report without --compare into an earlier --compare report's folder leaves no
    compare.json of the earlier pair, nor its shots, nor a killed one's temporary files
    (app/outputs.py's list for report, as for every command); other files stay."""
    from app.outputs import outputs_of

    a, b, _ = make_runs(tmp_path)
    out = tmp_path / "report"
    assert main(["report", str(a), "--compare", str(b), "--out", str(out)]) == 0
    assert (out / "compare.json").is_file()
    for shot in (out / "shots" / SEQ / "event0_f3_focus.png", out / "b" / "shots" / SEQ / "x.png"):
        shot.parent.mkdir(parents=True)
        shot.write_bytes(b"an earlier --shots'")
    stranded = out / "shots" / SEQ / ".event0_f4_focus.png.999999.x1y2.tmp"
    stranded.write_bytes(b"a killed report's")
    assert {"compare.json", "shots/*/*.png", "shots/*/.*.png.*.tmp"} <= set(outputs_of("report"))
    (out / "kitti_0016").mkdir()  # another report, linked with --link: not this one's
    (out / "kitti_0016" / "compare.json").write_text("{}")
    # a refused report (runs without a shared sequence) keeps the earlier one
    summary = json.loads((b / "summary.json").read_text())
    (b / "summary.json").write_text(json.dumps({**summary, "failed": {SEQ: "boom"}}))
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert main(["report", str(a), "--compare", str(b), "--out", str(out)]) == 2
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert main(["report", str(a), "--out", str(out)]) == 0
    files = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    assert files == {
        "index.html",
        "plots/hota.svg",
        "plots/idsw_per_sequence.svg",
        "kitti_0016/compare.json",
    }


def test_report_into_a_folder_with_plots_of_its_own_keeps_them(tmp_path: Path) -> None:
    """--out a folder that holds someone's plots/ (not a report's folder): the report writes its
    plots beside them; it removed the whole plots/ folder."""
    a, _, _ = make_runs(tmp_path)
    out = tmp_path / "mine"
    (out / "plots").mkdir(parents=True)
    (out / "plots" / "figure.pdf").write_bytes(b"a paper's figure")
    assert main(["report", str(a), "--out", str(out)]) == 0
    assert (out / "plots" / "figure.pdf").read_bytes() == b"a paper's figure"
    assert (out / "plots" / "hota.svg").is_file()
    # and a report into its own earlier folder still replaces its plots (none stale)
    stale = out / "plots" / "mota_per_sequence.svg"
    stale.write_text("<svg/>")
    assert main(["report", str(a), "--out", str(out)]) == 0
    assert not stale.exists() and (out / "plots" / "figure.pdf").is_file()


def test_report_refuses_a_run_folder_as_out(tmp_path: Path, capsys) -> None:
    """A report written into a run's folder outlived the run: a later run into the folder
    removes the run's files (of any command), not index.html and plots/, which then described
    the old run. Refused in one line, the run folder untouched (its own or another run's)."""
    a, b, _ = make_runs(tmp_path)
    before = sorted(p.relative_to(a) for p in a.rglob("*"))
    for args in ([str(a)], [str(b), "--compare", str(a)]):
        assert main(["report", *args, "--out", str(a)]) == 2
        assert capsys.readouterr().err.strip() == (
            f"mctrack report: error: {a}: --out is a run folder (a run's summary.json): a report "
            "there would outlive the run, describing it after a new run into the folder; give "
            "another --out"
        )
        assert sorted(p.relative_to(a) for p in a.rglob("*")) == before
    assert main(["report", str(a), "--out", str(tmp_path / "r")]) == 0


def test_report_of_a_tracks_file_says_it_reads_run_folders(tmp_path: Path, capsys) -> None:
    """(was "pass --gt GT.json", an option mctrack report does not have)"""
    a, _, _ = make_runs(tmp_path)
    tracks = tmp_path / "tracks.json"
    tracks.write_text("{}")
    for argv in ([str(tracks)], [str(a), "--compare", str(tracks)]):
        assert main(["report", *argv, "--out", str(tmp_path / "r")]) == 2
        assert capsys.readouterr().err.strip() == (
            f"mctrack report: error: {tracks}: a file; mctrack report reads `mctrack kitti --out` "
            "folders (compare two tracks files with mctrack compare A B --gt GT.json --out DIR)"
        )


PNG = b"\x89PNG\r\n\x1a\n" + b"\0" * 32  # (the signature is what the report checks)


@pytest.mark.parametrize("kind", ["link to a PNG", "link to a secret", "FIFO", "not a PNG", "PNG"])
def test_report_copies_a_runs_motion_png_only_as_a_png_file(
    kind: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The run folder is input, the report's plots/ may be served: motion_velocity.png that is
    a link (the reviewer's, to /etc/hostname, was copied as what it points to), a FIFO or a
    file that is not a PNG is skipped with a line naming it; a PNG file is copied."""
    a, _, _ = make_runs(tmp_path)
    png = a / "motion_velocity.png"
    (tmp_path / "secret").write_bytes(b"secret")
    (tmp_path / "elsewhere.png").write_bytes(PNG)
    if kind == "link to a PNG":
        png.symlink_to(tmp_path / "elsewhere.png")
    elif kind == "link to a secret":
        png.symlink_to(tmp_path / "secret")
    elif kind == "FIFO":
        os.mkfifo(png)
    else:
        png.write_bytes(b"secret" if kind == "not a PNG" else PNG)
    out = tmp_path / "report"
    assert main(["report", str(a), "--out", str(out)]) == 0
    copied = out / "plots" / "motion_velocity.png"
    if kind == "PNG":
        assert (
            copied.read_bytes() == PNG
            and "plots/motion_velocity.png" in (out / "index.html").read_text()
        )
        return
    assert not copied.exists() and "motion_velocity.png" not in (out / "index.html").read_text()
    why = {"FIFO": "not a regular file", "not a PNG": "not a PNG"}.get(kind, "a symbolic link")
    assert f"{png}: {why}, not copied into the report" in caplog.text


def test_report_of_one_run_is_self_contained(tmp_path: Path) -> None:
    a, _, _ = make_runs(tmp_path)
    out = tmp_path / "report"
    assert main(["report", str(a), "--out", str(out), "--tolerance", "0"]) == 0
    html = (out / "index.html").read_text()
    # the command that made it, every option that changes it included
    assert f"mctrack report {a} --out {out} --tolerance 0</code>" in html
    assert "http://" not in html and "https://" not in html  # no network
    assert html.count("<tr>") >= 2 + 1  # two events (header rows aside)
    assert "mctrack kitti --record" in html  # says how to get recordings, causes and links
    files = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    assert files == {"index.html", "plots/hota.svg", "plots/idsw_per_sequence.svg"}


def test_report_real_runs_in_browser(real_runs, tmp_path: Path, browser) -> None:
    root, _, _ = real_runs
    out = tmp_path / "report"
    t0 = time.perf_counter()
    assert (
        main(
            ["report", str(root / "kitti"), "--compare", str(root / "reference"), "--out", str(out)]
        )
        == 0
    )
    assert time.perf_counter() - t0 < 30
    result = json.loads((out / "compare.json").read_text())
    seen = check_page(browser, out / "index.html", tmp_path / "report_0016.png")
    assert len(seen["rows"]) == len(result["events"]) > 20
    srcs = {src for src, _, _ in seen["images"]}
    assert {"plots/hota.svg", "plots/idsw_per_sequence.svg", "plots/motion_velocity.png"} <= srcs
    # A (the tuned run) was recorded: each of its events has the command that opens it
    headers = seen["headers"]
    cmd = headers.index("open at the event")
    a_rows = [r for r in seen["rows"] if r[headers.index("run")].startswith("A")]
    assert a_rows and all("mctrack inspect" in r[cmd] and "--event" in r[cmd] for r in a_rows)


# ---------------------------------------------------------------------------------------------
# --serve


def _tiny_recording(path: Path, frames: int = 20) -> Path:
    import rerun as rr

    rec = rr.RecordingStream("mctrack_studio", recording_id="tiny")
    rec.save(str(path))
    for f in range(frames):
        rec.set_time("frame", sequence=f)
        rec.log("world/box", rr.Boxes3D(centers=[[f, 0, 0]], half_sizes=[[1, 1, 1]]))
    rec.flush()
    rec.disconnect()
    return path


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=60) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, b""


@pytest.fixture
def served_report(tmp_path: Path):
    from app.runs import load_run
    from app.serve import report_server

    a, _, _ = make_runs(tmp_path)
    (a / "recordings").mkdir()
    rec = _tiny_recording(a / "recordings" / f"{SEQ}.rrd")
    out = tmp_path / "report"
    assert main(["report", str(a), "--out", str(out)]) == 0
    run = load_run(a)
    assert run.recordings == {SEQ: rec}
    with report_server(out, {f"a/{SEQ}": rec}) as (server, url):
        yield server, url, rec, out


def test_serve_answers_on_loopback(served_report) -> None:
    server, url, rec, _ = served_report
    assert url.startswith("http://127.0.0.1:")
    assert server.server_address[0] == "127.0.0.1"
    status, page = _get(url)
    assert status == 200 and b"MCTrack report" in page
    status, info = _get(url + "serve.json")
    assert status == 200 and json.loads(info)["recordings"] == [f"a/{SEQ}"]
    status, data = _get(f"{url}recordings/a/{SEQ}.rrd")
    assert status == 200 and data == rec.read_bytes()
    status, viewer = _get(url + "viewer/")
    assert status == 200 and b"re_viewer.js" in viewer and b"set_time_cursor" in viewer
    assert b"fonts.googleapis" not in viewer  # no network
    status, js = _get(url + "viewer/re_viewer.js")
    assert status == 200 and b"WebHandle" in js
    status, wasm = _get(url + "viewer/re_viewer_bg.wasm")
    assert status == 200 and wasm[:4] == b"\0asm"
    # nothing outside the report folder and the listed recordings
    for bad in (
        "../../etc/passwd",
        "%2e%2e/%2e%2e/etc/passwd",
        f"recordings/a/..%2f{SEQ}.rrd",
        "recordings/b/0001.rrd",
        "viewer/..%2f..%2fetc%2fpasswd",
    ):
        assert _get(url + bad)[0] == 404, bad


def test_serve_event_link_opens_the_viewer_at_the_frame(served_report, browser) -> None:
    _, url, _, _ = served_report
    page = browser.new_page(viewport={"width": 1200, "height": 800})
    page.goto(url)
    link = page.wait_for_selector("a.live:not([hidden])", timeout=10_000)
    frame = int(link.get_attribute("data-frame"))
    assert frame == 3  # the first event: GT2's switch at frame 3 (rows in frame order)
    link.click()
    page.wait_for_function("window.mctrackSeeked !== undefined", timeout=150_000)
    assert page.evaluate("window.mctrackSeeked") == frame
    # the viewer's own state (GetStateResponse protobuf): timeline "frame" with the cursor at
    # the frame (TimelineTime{time: frame} = 0x08 varint)
    state = bytes(page.evaluate("Array.from(window._handle.viewer_state())"))
    assert b"\n\x05frame" in state and bytes([0x08, frame]) in state
    page.close()


#: a sequence name with every character that ends or changes a URL path
ODD_SEQ = "a?b#c%41 d"


def _odd_run(root: Path) -> tuple[Path, Path]:
    """(run A with its sequence renamed ODD_SEQ, that sequence's recording)."""
    from tracker.io.fileio import safe_filename

    a, _, labels = make_runs(root)
    shutil.copy(labels / f"{SEQ}.txt", labels / f"{safe_filename(ODD_SEQ)}.txt")
    (a / "data" / f"{SEQ}.txt").rename(a / "data" / f"{safe_filename(ODD_SEQ)}.txt")
    summary = json.loads((a / "summary.json").read_text())
    summary["sequences"] = [ODD_SEQ]
    summary["per_sequence"] = {ODD_SEQ: summary["per_sequence"][SEQ]}
    (a / "summary.json").write_text(json.dumps(summary))
    (a / "recordings").mkdir()
    return a, _tiny_recording(a / "recordings" / f"{safe_filename(ODD_SEQ)}.rrd")


@pytest.fixture
def odd_served_report(tmp_path: Path):
    """A run whose sequence (with a recording) is named ODD_SEQ, its report served (without
    the viewer: the links are what is tested)."""
    from app.serve import report_server

    a, rec = _odd_run(tmp_path)
    out = tmp_path / "report"
    assert main(["report", str(a), "--out", str(out)]) == 0
    with report_server(out, {f"a/{ODD_SEQ}": rec}, with_viewer=False) as (_, url):
        yield url, rec, out


def test_serve_event_link_encodes_the_sequence_name(odd_served_report) -> None:
    """A sequence named with '?', '#', '%' and a space: the event link's recording path is
    URL-encoded, so the page's URL of it fetches that recording (the name went in as it was:
    the path ended at '?', a 404)."""
    import re
    import urllib.parse

    url, rec, out = odd_served_report
    found = re.findall(
        r'<a class="live" hidden data-rec="([^"]*)"', (out / "index.html").read_text()
    )
    assert found and set(found) == {"a/" + urllib.parse.quote(ODD_SEQ, safe="")}
    status, data = _get(url + "recordings/" + html.unescape(found[0]) + ".rrd")  # as the script
    assert status == 200 and data == rec.read_bytes()


def test_serve_event_link_of_an_odd_name_in_the_browser(odd_served_report, browser) -> None:
    """The same through the page's own script: the viewer link's ?url= is the recording."""
    import urllib.parse

    url, rec, _ = odd_served_report
    page = browser.new_page()
    page.goto(url)
    link = page.wait_for_selector("a.live:not([hidden])", timeout=10_000)
    query = urllib.parse.parse_qs(urllib.parse.urlsplit(link.get_attribute("href")).query)
    page.close()
    status, data = _get(query["url"][0])
    assert status == 200 and data == rec.read_bytes()


def test_shot_links_of_an_odd_name_lead_to_the_file(tmp_path: Path, monkeypatch) -> None:
    """A shot lives in shots/<the sequence name escaped>/ ('%3F' for '?'): its src and href
    are URL-encoded, so that a browser, decoding them, finds the file (it decoded the escape
    itself: shots/a?b#c... does not exist, a broken image)."""
    import re
    import urllib.parse

    from app import report
    from app.runs import load_run
    from tracker.io.fileio import path_in

    a, _ = _odd_run(tmp_path)
    out = tmp_path / "report"

    def fake_shots(run, folder: Path, per_sequence: int) -> dict[tuple[str, int], str]:
        shot = path_in(folder / "shots", ODD_SEQ, "") / "1.png"
        shot.parent.mkdir(parents=True)
        shot.write_bytes(b"\x89PNG\r\n\x1a\n")
        return {(ODD_SEQ, 1): str(shot.relative_to(folder))}

    monkeypatch.setattr(report, "take_event_shots", fake_shots)
    assert main(["report", str(a), "--shots", "1", "--out", str(out)]) == 0
    page = (out / "index.html").read_text()
    run = load_run(a)  # an event of a recording with an index has its number: its shot cell
    event = {**run.events[0], "event": 1}
    cell = report._event_cells(run, "a", event, fake_shots(None, tmp_path / "x", 1))
    srcs = re.findall(r'(?:src|href)="(shots/[^"]*)"', page + "".join(cell))
    assert len(srcs) == 3  # the gallery's image, the event cell's link and image
    for src in srcs:  # what a browser reads: the path with its escapes decoded
        assert "%25" in src and (out / urllib.parse.unquote(html.unescape(src))).is_file(), src


def test_serve_stops_cleanly(tmp_path: Path, monkeypatch) -> None:
    """After the ``with``: the port refuses connections and the viewer process has ended."""
    from app import serve

    made: list = []
    original = serve.ViewerAssets.__init__

    def spy(self, *args, **kwargs):
        original(self, *args, **kwargs)
        made.append(self)

    monkeypatch.setattr(serve.ViewerAssets, "__init__", spy)
    a, _, _ = make_runs(tmp_path)
    out = tmp_path / "report"
    assert main(["report", str(a), "--out", str(out)]) == 0
    with serve.report_server(out, {}) as (_, url):
        assert _get(url)[0] == 200 and _get(url + "viewer/")[0] == 200
        assert made[0].process.poll() is None
    with pytest.raises(urllib.error.URLError):
        urllib.request.urlopen(url, timeout=5)
    assert len(made) == 1 and made[0].process.poll() is not None


def _children(pid: int) -> list[int]:
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        found += [int(c) for c in (task / "children").read_text().split()]
    return found


def _running(pid: int) -> bool:
    """Alive and not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, IndexError):
        return False


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads /proc (Linux)")
def test_serve_stops_the_viewer_on_sigterm(tmp_path: Path) -> None:
    """`kill` (SIGTERM) of `mctrack report --serve` stops the server and the rerun web viewer
    it started, as Ctrl-C does (the viewer process was left running, holding its port)."""
    import sys

    from viz.rerun_process import rerun_executable

    if rerun_executable() is None:
        pytest.skip("the rerun binary of rerun-sdk is not installed")
    a, _, _ = make_runs(tmp_path)
    root = Path(__file__).resolve().parents[1]
    argv = ["report", str(a), "--out", str(tmp_path / "r"), "--serve", "--port", "0"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", *argv],
        cwd=root,
        env={**os.environ, "PYTHONPATH": str(root), "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # the report line, then the server's
            if line.startswith("serving the report at "):
                break
        else:
            pytest.fail(f"not served: {proc.stderr.read() if proc.stderr else ''}")
        viewers = _children(proc.pid)
        assert viewers and all(_running(v) for v in viewers)
    finally:
        out = stopped_by_sigterm(proc)
    deadline = time.monotonic() + 10  # (an orphan would be re-parented and keep running)
    while any(_running(v) for v in viewers) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [v for v in viewers if _running(v)]
    for v in left:  # (not left behind by a failing test either)
        os.kill(v, signal.SIGKILL)
    assert not left
    assert proc.returncode == 0 and out.strip().endswith("stopped")


def stopped_by_sigterm(proc: subprocess.Popen[str]) -> str:
    """SIGTERM to a server run, then its remaining stdout; killed if it does not stop (a failing
    test leaves nothing running)."""
    try:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return out


def test_the_pages_inspect_commands_name_the_recording_from_any_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A report made with a relative run folder (`mctrack report krec`) printed `mctrack inspect
    krec/recordings/0001.rrd --event K`, which works only from the folder it was made in."""
    import shlex

    from app.report import _inspect_cmd, _recordings_section
    from app.runs import Run

    monkeypatch.chdir(tmp_path)
    rec = Path("krec") / "recordings" / "0001.rrd"
    run = Run("A", Path("krec"), {}, [], recordings={"0001": rec})
    absolute = shlex.quote(str(tmp_path / rec))
    event = {"sequence": "0001", "event": 3, "frame": 7}
    assert _inspect_cmd(run, event) == f"mctrack inspect {absolute} --event 3"
    assert f"mctrack inspect {absolute} --event K" in _recordings_section(run, None)
