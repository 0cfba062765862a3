"""`mctrack report RUN_DIR [--compare OTHER_RUN] --out DIR`: a static HTML report of a run.

``DIR/index.html`` opens from the file system in any browser, with no server and no network:
the metrics per class and per sequence, the ID switches and fragmentations with their causes
(and, with ``--compare``, whether OTHER_RUN fixed, introduced or kept each), the motion
metrics, plots (matplotlib SVG), a gallery of each event's focused screenshot (``--shots``:
taken now with the headless viewer) and, for each recording, the command that opens it at
each event. One folder (``index.html``, ``plots/``, ``shots/``, ``compare.json``), small
enough for a CI artifact; the recordings stay in the run folders.

``--serve`` then serves the report, the recordings and Rerun's web viewer (from the rerun-sdk
wheel) on 127.0.0.1: a click on an event opens the web viewer on that recording at that frame.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shlex
import stat
import sys
import time
import urllib.parse
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from app import report_html as h
from app.common import command_line, remove_earlier_outputs
from app.compare import compare_result
from app.inputs import host_address, port_or_any, refuse_unused_option
from app.outputs import holds_a_run, outputs_of
from app.runs import Run, load_run, run_names
from tracker.errors import InputError
from tracker.eval.compare import (
    CLASS_METRICS,
    DEFAULT_TOLERANCE,
    LOWER_IS_BETTER,
    MOTION_KEYS,
    left_out_note,
)
from tracker.io.fileio import check_output_folder, path_in, write_bytes_atomic, write_text_atomic
from viz.rerun_process import LOOPBACK

LOG = logging.getLogger(__name__)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
RGB_A = "#3c78f0"
RGB_B = "#f08c1e"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", metavar="RUN_DIR", help="a `mctrack kitti --out` folder")
    parser.add_argument(
        "--compare", default=None, metavar="OTHER_RUN", help="a second run (B) compared to RUN_DIR"
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="report folder")
    parser.add_argument(
        "--labels", default=None, metavar="DIR", help="KITTI label_02 (default: the runs')"
    )
    parser.add_argument(
        "--tolerance", type=int, default=DEFAULT_TOLERANCE, help="frames (see mctrack compare)"
    )
    parser.add_argument(
        "--shots",
        type=int,
        default=0,
        metavar="N",
        help="take the focused screenshot of up to N ID switches per recorded sequence "
        "(headless viewer; needs a Vulkan driver). 0: no shots",
    )
    parser.add_argument(
        "--link",
        nargs=2,
        action="append",
        default=None,
        metavar=("HREF", "TEXT"),
        help="a link to another report (a relative path, e.g. kitti_0016/index.html); repeatable",
    )
    parser.add_argument(
        "--serve", action="store_true", help="then serve the report, recordings and web viewer"
    )
    parser.add_argument(
        "--host",
        type=host_address,
        default=None,
        help="IP address --serve listens on (default 127.0.0.1; only with --serve); 0.0.0.0 "
        "exposes the report (and the recordings) to the network: do it deliberately",
    )
    parser.add_argument(
        "--port",
        type=port_or_any,
        default=None,
        help="port --serve listens on (default 8765, 0: any free; only with --serve)",
    )


def run(args: argparse.Namespace) -> int:
    if not args.serve:  # else ignored unsaid
        for option, value in (("--host", args.host), ("--port", args.port)):
            refuse_unused_option(option, value, "--serve", "without it report writes the folder")
    if args.tolerance < 0:
        raise InputError(f"--tolerance {args.tolerance}: must be >= 0")
    out = check_output_folder(args.out)
    if holds_a_run(out):  # (a new run there removes the run's files, not a report's)
        raise InputError(
            f"{out}: --out is a run folder (a run's summary.json): a report there would outlive "
            "the run, describing it after a new run into the folder; give another --out"
        )
    labels = Path(args.labels) if args.labels else None
    path_a = Path(args.run)
    for given in (args.run, args.compare):
        # (load_run's own line says "pass --gt", an option report does not have)
        if given and Path(given).is_file():
            raise InputError(
                f"{given}: a file; mctrack report reads `mctrack kitti --out` folders (compare "
                "two tracks files with mctrack compare A B --gt GT.json --out DIR)"
            )
    if args.compare:
        path_b = Path(args.compare)
        na, nb = run_names(path_a, path_b)
        run_a = load_run(path_a, labels=labels, name=na, command="report")
        run_b: Run | None = load_run(path_b, labels=labels, name=nb, command="report")
    else:
        run_a, run_b = load_run(path_a, labels=labels, command="report"), None
    # every option that changes the report, quoted: the line makes it again (--serve and its
    # address only show it)
    words = [
        args.run,
        *(["--compare", args.compare] if args.compare else []),
        "--out",
        args.out,
        *(["--labels", args.labels] if args.labels else []),
        "--tolerance",
        str(args.tolerance),
        *(["--shots", str(args.shots)] if args.shots else []),
        *(w for href, text in args.link or [] for w in ("--link", href, text)),
    ]
    command = command_line(["report", *words])
    links = [tuple(x) for x in args.link or []]
    for href, _ in links:
        if "://" in href or href.startswith(("/", "\\")) or ".." in Path(href).parts:
            raise InputError(f"--link {href}: a relative path inside the report folder, please")
    t0 = time.perf_counter()
    info = build_report(
        run_a,
        run_b,
        out,
        tolerance=args.tolerance,
        shots=args.shots,
        command=command,
        links=links,
    )
    print(f"report: {out / 'index.html'} ({time.perf_counter() - t0:.1f} s; {info['summary']})")
    if args.serve:
        from app.serve import serve_report

        host, port = args.host or LOOPBACK, 8765 if args.port is None else args.port
        return serve_report(out, _recordings(run_a, run_b), host=host, port=port)
    return 0


def _recordings(run_a: Run, run_b: Run | None) -> dict[str, Path]:
    """{"a/<seq>" | "b/<seq>": recording} (the URL names under /recordings/ when served)."""
    out = {f"a/{s}": p for s, p in run_a.recordings.items()}
    if run_b is not None:
        out.update({f"b/{s}": p for s, p in run_b.recordings.items()})
    return out


# ---------------------------------------------------------------------------------------------
# Plots (matplotlib, SVG: small, sharp at any zoom, reproducible with a fixed hash salt)


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    matplotlib.rcParams["svg.hashsalt"] = "mctrack-report"
    matplotlib.rcParams["font.size"] = 9
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> None:
    import io

    buf = io.StringIO()
    fig.savefig(buf, format="svg", metadata={"Date": None}, bbox_inches="tight")
    write_text_atomic(path, [buf.getvalue()])


def _bars(
    path: Path,
    groups: Sequence[str],
    series: Sequence[tuple[str, Sequence[float], str]],
    *,
    title: str,
    ylabel: str,
) -> None:
    """Grouped bars: one group per label, one bar per series (name, values, colour)."""
    import numpy as np

    plt = _pyplot()
    # names from the input: a "$" would start matplotlib's mathtext (a "$\frac{$": an error)
    groups = [_literal(g) for g in groups]
    series = [(_literal(name), values, color) for name, values, color in series]
    width = max(4.5, 0.55 * len(groups) * max(1, len(series)) + 1.5)
    fig, ax = plt.subplots(figsize=(min(width, 14.0), 3.0))
    x = np.arange(len(groups))
    w = 0.8 / max(1, len(series))
    for k, (name, values, color) in enumerate(series):
        bars = ax.bar(x + (k - (len(series) - 1) / 2) * w, values, w, label=name, color=color)
        ax.bar_label(bars, fmt="%.4g", fontsize=7, padding=1)
    ax.set_xticks(x, groups)
    ax.set_title(title)
    ax.set_ylabel(ylabel)
    ax.spines[["top", "right"]].set_visible(False)
    if len(series) > 1:  # beside the axes: never over a bar
        ax.legend(frameon=False, fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    _save(fig, path)
    plt.close(fig)


def _literal(text: str) -> str:
    """``text`` shown as it is by matplotlib (no mathtext)."""
    return str(text).replace("$", r"\$")


def _num(v: Any) -> float:
    return float(v) if isinstance(v, int | float) else 0.0


def make_plots(
    run_a: Run, run_b: Run | None, out: Path, result: Mapping[str, Any] | None = None
) -> list[tuple[str, str]]:
    """The report's plots: [(file relative to out, caption)]. With a comparison (``result``,
    :func:`app.compare.compare_result`) they show what its tables compare: its metrics and
    events, on the sequences both runs scored (a run's own figures over other sequences would
    be set against the other's over fewer, or against 0 where it never ran), and no motion
    plots where it leaves the motion metrics out."""
    plots: list[tuple[str, str]] = []
    runs = [(run_a, RGB_A)] + ([(run_b, RGB_B)] if run_b is not None else [])
    if result is None:
        metrics = [r.summary.get("metrics") or {} for r, _ in runs]
        events = [r.events for r, _ in runs]
        seqs = list(run_a.summary["sequences"])
        motion = [r.summary.get("motion") for r, _ in runs]
        per = [m.get("metrics", {}).get("kalman", {}) if isinstance(m, Mapping) else None
               for m in motion]  # fmt: skip
        scope = ""
    else:
        metrics = [_one_side(result["metrics"], side) for side in ("a", "b")]
        events = [[p[side] for p in result["events"] if p[side]] for side in ("a", "b")]
        shared = result.get("sequences_compared")
        seqs = list(shared or run_a.summary["sequences"])
        if isinstance(result.get("motion"), Mapping):
            per = [_one_side(result["motion"], side) for side in ("a", "b")]
        else:
            per = [None, None]
        scope = f", the {len(seqs)} compared sequence(s)" if shared else ""
    order = {c: k for k, c in enumerate(run_a.summary.get("classes") or ())}  # (A's order)
    classes = [c for c in (metrics[0] or {}) if isinstance(metrics[0][c], Mapping)]
    classes.sort(key=lambda c: order.get(c, len(order)))
    if classes and all("HOTA" in metrics[0][c] for c in classes):
        _bars(
            out / "plots" / "hota.svg",
            classes,
            [
                (r.name, [_num(m.get(c, {}).get("HOTA")) for c in classes], col)
                for (r, col), m in zip(runs, metrics, strict=True)
            ],
            title=f"HOTA per class{scope}",
            ylabel="HOTA (%)",
        )
        plots.append(("plots/hota.svg", f"HOTA per class{_scope_caption(seqs, scope)}"))
    for kind in ("IDSW", "Frag"):
        series = []
        for (r, col), evs in zip(runs, events, strict=True):
            counts = {s: 0 for s in seqs}
            for e in evs:
                if e["kind"] == kind and e["sequence"] in counts:
                    counts[e["sequence"]] += 1
            series.append((r.name, [counts[s] for s in seqs], col))
        if any(any(v) for _, v, _ in series):
            name = f"plots/{kind.lower()}_per_sequence.svg"
            _bars(out / name, seqs, series, title=f"{kind} per sequence{scope}", ylabel=kind)
            plots.append((name, f"{kind} per sequence (all classes){_scope_caption(seqs, scope)}"))
    if all(p is not None for p in per):
        mclasses = [c for c in per[0] if isinstance(per[0][c], Mapping)]
        for key, label in (("vae_deg", "VAE (deg)"), ("vne_mps", "VNE (m/s)")):
            _bars(
                out / "plots" / f"motion_{key}.svg",
                mclasses,
                [
                    (r.name, [_num(p.get(c, {}).get(key)) for c in mclasses], col)
                    for (r, col), p in zip(runs, per, strict=True)
                ],
                title=f"Kalman velocity: {label} per class (lower is better)",
                ylabel=label,
            )
            plots.append((f"plots/motion_{key}.svg", f"motion: {label}"))
    return plots


def _one_side(table: Mapping[str, Mapping[str, Mapping[str, Any]]], side: str) -> dict:
    """One run's figures of a comparison's ``{class: {metric: {"a": .., "b": ..}}}`` table."""
    return {c: {k: d[side] for k, d in m.items()} for c, m in table.items()}


def _scope_caption(seqs: Sequence[str], scope: str) -> str:
    """A caption's note of the sequences a comparison's plot covers ("": all of both runs')."""
    if not scope:
        return ""
    return f", on the {len(seqs)} sequence(s) both runs scored ({', '.join(seqs)})"


def _plots_section(
    plots: Sequence[tuple[str, str]],
    run_a: Run,
    run_b: Run | None,
    result: Mapping[str, Any] | None,
) -> str:
    notes = ""
    if result is not None and result.get("sequences_left_out"):
        notes += (
            '<p class="note">Plots of A against B show what the tables compare: the sequences '
            "both runs scored.</p>"
        )
    both_motion = run_b is not None and all(
        isinstance(r.summary.get("motion"), Mapping) for r in (run_a, run_b)
    )
    if result is not None and both_motion and isinstance(result.get("motion"), str):
        notes += (
            f'<p class="note">No motion plots: {h.esc(result["motion"].removeprefix("absent: "))}'
            " (each run's own are under Motion metrics).</p>"
        )
    if not plots:
        return notes + '<p class="note">No plots: the runs have no metrics.</p>'
    figures = "".join(h.figure(src, cap) for src, cap in plots)
    return notes + '<div class="plots">' + figures + "</div>"


# ---------------------------------------------------------------------------------------------
# Shots


def take_event_shots(run: Run, out: Path, per_sequence: int) -> dict[tuple[str, int], str]:
    """Focused screenshots of the first ``per_sequence`` ID switches (else fragmentations) of
    each recorded sequence; {(sequence, #K): PNG path relative to out}. Nothing (with a note on
    stderr) without a Vulkan driver."""
    from viz.layout import VIEW_FOCUS
    from viz.shots import PlannedShot, RendererMissing, take_shots

    found: dict[tuple[str, int], str] = {}
    for seq, rec in sorted(run.recordings.items()):
        evs = [e for e in run.events if e["sequence"] == seq and e["event"] is not None]
        chosen = [e for e in evs if e["kind"] == "IDSW"][:per_sequence] or evs[:per_sequence]
        if not chosen:
            continue
        plan = [
            PlannedShot(
                e["frame"], "id_switch" if e["kind"] == "IDSW" else "fragmentation", e["event"]
            )
            for e in chosen
        ]
        folder = path_in(out / "shots", seq, "")
        try:
            # the focused 3D view only: the gallery's one picture per event
            shots = take_shots(rec, folder, plan=plan, full_viewer=False, views=(VIEW_FOCUS,))
        except RendererMissing as exc:
            print(f"report: no shots ({exc})", file=sys.stderr)
            return found
        except (RuntimeError, TimeoutError, OSError) as exc:
            print(f"report: shots of {seq} failed: {exc}", file=sys.stderr)
            continue
        for s in shots:
            if s.event is not None:
                found.setdefault((seq, s.event), str(s.path.relative_to(out)))
    return found


# ---------------------------------------------------------------------------------------------
# The page


def build_report(
    run_a: Run,
    run_b: Run | None,
    out: Path,
    *,
    tolerance: int = DEFAULT_TOLERANCE,
    shots: int = 0,
    command: str | None = None,
    links: Sequence[tuple[str, str]] = (),
) -> dict[str, Any]:
    """Write ``out/index.html`` and its files; returns {"events": n, "summary": text}.
    ``links``: (relative href, text) of other reports, listed under "Runs"."""
    # (first: runs that share no sequence are refused before anything is removed)
    result = compare_result(run_a, run_b, tolerance=tolerance) if run_b is not None else None
    if (out / "index.html").is_file():  # an earlier report's folder: its files go
        remove_earlier_outputs(out, outputs_of("report"))
    (out / "plots").mkdir(parents=True, exist_ok=True)  # (files of anyone else's stay)
    if result is not None:
        write_text_atomic(out / "compare.json", [json.dumps(result, indent=1)])
    plots = make_plots(run_a, run_b, out, result)
    motion_png = _run_png(run_a.folder / "motion_velocity.png")
    if motion_png is not None:
        write_bytes_atomic(out / "plots" / "motion_velocity.png", motion_png)
        # (A's own picture: over all its sequences, also where fewer are compared)
        whose = run_a.name + (
            f", all its {len(run_a.summary['sequences'])} sequence(s)"
            if result is not None and result.get("sequences_left_out")
            else ""
        )
        plots.append(
            ("plots/motion_velocity.png", f"velocity curves of the largest lags ({whose})")
        )
    shot_files = take_event_shots(run_a, out, shots) if shots > 0 else {}
    if run_b is not None and shots > 0:
        shot_files_b = take_event_shots(run_b, out / "b", shots)
        shot_files.update({("b/" + s, k): "b/" + p for (s, k), p in shot_files_b.items()})

    title = f"MCTrack report: {run_a.name}" + (f" vs {run_b.name}" if run_b else "")
    s = run_a.summary
    scored = s.get("evaluated_sequences", s["sequences"])
    subtitle = (
        f"{len(s['sequences'])} sequence(s)"
        + (f" ({len(scored)} scored)" if len(scored) != len(s["sequences"]) else "")
        + f", classes {', '.join(s['classes'])}, detector "
        f"{s.get('detector')}, mode {s.get('mode')}, config {s.get('config_name', 'n/a')}"
        + (f"; B: config {run_b.summary.get('config_name', 'n/a')}" if run_b else "")
    )
    sections = [
        ("runs", "Runs", _runs_section(run_a, run_b, command) + _links(links)),
        ("metrics", "Metrics per class", _metrics_section(run_a, run_b, result)),
        ("sequences", "Per sequence", _sequence_section(run_a, run_b, result)),
        ("plots", "Plots", _plots_section(plots, run_a, run_b, result)),
        (
            "events",
            "ID switches and fragmentations",
            _events_section(run_a, run_b, result, shot_files),
        ),
        ("causes", "Causes", _causes_section(run_a, run_b, result)),
        ("motion", "Motion metrics", _motion_section(run_a, run_b, result)),
        ("shots", "Shots", _shots_section(shot_files, shots, (run_a, run_b))),
        ("recordings", "Recordings", _recordings_section(run_a, run_b)),
    ]
    write_text_atomic(out / "index.html", [h.page(title, subtitle, sections)])
    n = len(result["events"]) if result else len(run_a.events)
    summary = f"{n} events, {len(plots)} plots, {len(shot_files)} shots"
    return {"events": n, "summary": summary}


def _run_png(path: Path) -> bytes | None:
    """The content of a run folder's PNG that the report copies, or None: absent (the report
    goes without it), or skipped with a logged line. The run folder is input and the report may
    be served: a symbolic link (to any file the user can read), a FIFO or device, or a file that
    is not a PNG is not copied."""
    if path.is_symlink():
        why = "a symbolic link"
    elif not path.exists():
        return None
    else:
        try:  # (O_NOFOLLOW: not a link put there since; O_NONBLOCK: a FIFO does not hang)
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
        except OSError as exc:
            why = f"unreadable ({exc.strerror})"
        else:
            with os.fdopen(fd, "rb") as fh:
                if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                    why = "not a regular file"
                elif (data := fh.read()).startswith(PNG_SIGNATURE):
                    return data
                else:
                    why = "not a PNG"
    LOG.warning("%s: %s, not copied into the report", path, why)
    return None


def _links(links: Sequence[tuple[str, str]]) -> str:
    if not links:
        return ""
    items = "".join(f'<li><a href="{h.esc(href)}">{h.esc(text)}</a></li>' for href, text in links)
    return f'<p class="note">Other reports:</p><ul>{items}</ul>'


def _runs_section(run_a: Run, run_b: Run | None, command: str | None) -> str:
    rows = []
    for tag, r in (("A", run_a), ("B", run_b)):
        if r is None:
            continue
        s = r.summary
        rows.append(
            [
                h.td(tag),
                h.td(r.name),
                h.td(str(r.path)),
                h.td(s.get("detector")),
                h.td(s.get("config_name", "n/a")),
                h.td(s.get("mode")),
                h.td(", ".join(s["sequences"])),
                h.td(len(r.events), num=True),
                h.td(len(r.recordings), num=True),
            ]
        )
    text = h.table(
        [
            "run",
            "name",
            "folder",
            "detector",
            "config",
            "mode",
            "sequences",
            "ID events",
            "recordings",
        ],
        rows,
        numeric=[False] * 7 + [True, True],
    )
    if command:
        text += f'<p class="note">Made by <code>{h.esc(command)}</code>.</p>'
    return text


def _metrics_section(run_a: Run, run_b: Run | None, result: Mapping[str, Any] | None) -> str:
    ma = run_a.summary.get("metrics")
    if not isinstance(ma, Mapping) or not ma:
        why = run_a.summary.get("evaluation", "the run was not evaluated")
        return f'<p class="note">No metrics: {h.esc(why)}.</p>'
    keys = [k for k in CLASS_METRICS if any(k in m for m in ma.values())]
    # a run over labelled and unlabelled sequences is scored on the labelled ones (app.kitti)
    partial = "".join(
        f'<p class="note">{h.esc(name)}: {h.esc(run.summary["evaluation"])}.</p>'
        for name, run in (("A", run_a), ("B", run_b))
        if run is not None and "evaluated_sequences" in run.summary and "evaluation" in run.summary
    )
    rows = []
    if result is None:
        for cls, m in ma.items():
            rows.append([h.td(cls), *[h.td(m.get(k), num=True) for k in keys]])
        return partial + h.table(["class", *keys], rows, numeric=[False] + [True] * len(keys))
    # one row per (class, metric): narrow at any number of metrics, sortable by the change
    for cls, m in result["metrics"].items():
        for k in keys:
            d = m.get(k, {})
            rows.append(
                [
                    h.td(cls),
                    h.td(k),
                    h.td(d.get("a"), num=True),
                    h.td(d.get("b"), num=True),
                    h.delta_cell(k, d.get("delta"), k in LOWER_IS_BETTER),
                ]
            )
    note = (
        f'<p class="note">A = {h.esc(run_a.name)}, B = {h.esc(run_b.name if run_b else "")}; '
        'Δ = B − A, <span class="better">green</span> is better, '
        '<span class="worse">red</span> worse.</p>'
    )
    left_out = left_out_note(result)  # runs of different sequences: only the shared compared
    if left_out:
        note += f'<p class="note">{h.esc(left_out[0].upper() + left_out[1:])}.</p>'
    return (
        note
        + partial
        + h.table(
            ["class", "metric", "A", "B", "Δ"], rows, numeric=[False, False, True, True, True]
        )
    )


def _sequence_section(run_a: Run, run_b: Run | None, result: Mapping[str, Any] | None) -> str:
    per_a = run_a.summary.get("per_sequence_metrics") or run_a.summary.get("per_sequence") or {}
    if not per_a:
        return '<p class="note">No per-sequence metrics in the run.</p>'
    classes = sorted({c for per in per_a.values() for c in per})
    keys = [
        k
        for k in ("HOTA", "IDSW", "Frag")
        if any(k in per.get(c, {}) for per in per_a.values() for c in classes)
    ]

    def no_gt(seq: str, c: str) -> bool:
        """No ground-truth object of the class in the sequence: its scores mean nothing."""
        m = per_a.get(seq, {}).get(c, {})
        return (
            isinstance(m.get("TP"), int)
            and isinstance(m.get("FN"), int)
            and not (m["TP"] + m["FN"])
        )

    note = (
        '<p class="note">A class without ground truth in a sequence is left out (its HOTA, 0, '
        "would mean nothing).</p>"
    )
    rows = []
    if result is None:
        for seq, per in per_a.items():
            rows.append(
                [h.td(seq)]
                + [
                    h.td("–" if no_gt(seq, c) else per.get(c, {}).get(k), num=True)
                    for c in classes
                    for k in keys
                ]
            )
        headers = ["sequence"] + [f"{c} {k}" for c in classes for k in keys]
        return h.table(headers, rows, numeric=[False] + [True] * (len(headers) - 1), scroll=True)
    counts = result["counts"]
    for seq, per in result["per_sequence"].items():
        for c in classes:
            if no_gt(seq, c):
                continue
            cells = [h.td(seq), h.td(c)]
            for k in keys:
                d = per.get(c, {}).get(k, {})
                cells += [
                    h.td(d.get("a"), num=True),
                    h.td(d.get("b"), num=True),
                    h.delta_cell(k, d.get("delta"), k in LOWER_IS_BETTER),
                ]
            sc = counts.get(seq, {})
            for st in ("fixed", "introduced", "kept"):
                n = sum(v[st] for key, v in sc.items() if key.startswith(c + " "))
                cells.append(h.td(n, num=True))
            rows.append(cells)
    headers = (
        ["sequence", "class"]
        + [f"{k} {x}" for k in keys for x in ("A", "B", "Δ")]
        + ["fixed", "introduced", "kept"]
    )
    table = h.table(
        headers, rows, numeric=[False, False] + [True] * (len(headers) - 2), scroll=True
    )
    return note + table


def _inspect_cmd(run: Run, e: Mapping[str, Any]) -> str:
    rec = run.recordings.get(e["sequence"])
    if rec is None:
        return ""
    rec = rec.resolve()  # (the page is read, and its command pasted, from any folder)
    if e.get("event") is None:
        return f"mctrack inspect {shlex.quote(str(rec))} --frame {e['frame']}"
    return f"mctrack inspect {shlex.quote(str(rec))} --event {e['event']}"


def _event_cells(
    run: Run, side: str, e: Mapping[str, Any], shot_files: Mapping[tuple[str, int], str]
) -> list[str]:
    cmd = _inspect_cmd(run, e)
    key = (e["sequence"] if side == "a" else "b/" + e["sequence"], e.get("event"))
    shot = shot_files.get(key) if e.get("event") is not None else None
    src = h.esc(h.url_path(shot)) if shot else ""
    shot_cell = (
        f'<a href="{src}"><img src="{src}" alt="event shot" height="48"></a>' if shot else ""
    )
    live = ""
    if e["sequence"] in run.recordings:
        # the recording's URL path under /recordings/ (the page's script adds it as it is): a
        # name's '?', '#', '%' or space would end or change the path
        rec = f"{side}/{urllib.parse.quote(e['sequence'], safe='')}"
        live = (
            f'<a class="live" hidden data-rec="{h.esc(rec)}" '
            f'data-frame="{int(e["frame"])}">view</a>'
        )
    return [
        h.td(e["sequence"]),
        h.td(e["kind"]),
        h.td(e["frame"], num=True),
        h.td(e["class"]),
        h.td(e["gt_id"], num=True),
        h.td(f"T{e['old_track']}→T{e['new_track']}"),
        h.td(e.get("cause") or "–"),
        h.td(f"#{e['event']}" if e.get("event") is not None else "–", sort=e.get("event")),
        h.td(f"<code>{h.esc(cmd)}</code>" if cmd else "–", raw=True),
        h.td(live, raw=True),
        h.td(shot_cell, raw=True),
    ]


EVENT_HEADERS = [  # "web": filled in when served (--serve)
    "sequence",
    "kind",
    "frame",
    "class",
    "GT",
    "tracks",
    "cause",
    "event",
    "open at the event",
    "web",
    "shot",
]
EVENT_NUMERIC = [False, False, True, False, True, False, False, False, False, False, False]


def _events_section(
    run_a: Run,
    run_b: Run | None,
    result: Mapping[str, Any] | None,
    shot_files: Mapping[tuple[str, int], str],
) -> str:
    filt = (
        '<input type="search" placeholder="filter rows (e.g. pedestrian, introduced, 0016)" '
        'data-filter="events-table" aria-label="filter events">'
    )
    if result is None:
        rows = [_event_cells(run_a, "a", e, shot_files) for e in run_a.events]
        if not rows:
            return '<p class="note">No ID switches or fragmentations.</p>'
        return (
            f'<p class="note">{len(rows)} events, as TrackEval\'s CLEAR counts them.</p>'
            + filt
            + h.table(
                EVENT_HEADERS, rows, table_id="events-table", numeric=EVENT_NUMERIC, scroll=True
            )
        )
    rows = []
    for p in result["events"]:
        assert run_b is not None
        seq = (p["a"] or p["b"])["sequence"]
        # a kept event is shown as in B, or as in A where only A has the recording (its cause,
        # #K and the command that opens it)
        use_a = p["status"] == "fixed" or (
            p["status"] == "kept" and seq in run_a.recordings and seq not in run_b.recordings
        )
        side, run, e = ("a", run_a, p["a"]) if use_a else ("b", run_b, p["b"])
        badge = f'<span class="badge {p["status"]}">{p["status"]}</span>'
        where = "A, B" if p["status"] == "kept" else side.upper()
        rows.append(
            [
                h.td(badge, raw=True, sort=p["status"]),
                h.td(where),
                *_event_cells(run, side, e, shot_files),
            ]
        )
    if not rows:
        where = " in what was compared" if left_out_note(result) else ""
        return f'<p class="note">Neither run has ID switches or fragmentations{where}.</p>'
    c = result["counts"].get("total", {})
    n = {st: sum(v[st] for v in c.values()) for st in ("fixed", "introduced", "kept")}
    note = (
        f'<p class="note">{n["fixed"]} fixed (in A only), {n["introduced"]} introduced '
        f"(in B only), {n['kept']} kept; matched on sequence, kind, class and GT id within "
        f"{result['tolerance_frames']} frames. Kept events are shown as in B (as in A where "
        "only A was recorded).</p>"
    )
    return (
        note
        + filt
        + h.table(
            ["status", "run", *EVENT_HEADERS],
            rows,
            table_id="events-table",
            numeric=[False, False, *EVENT_NUMERIC],
            scroll=True,
        )
    )


def _causes_section(run_a: Run, run_b: Run | None, result: Mapping[str, Any] | None) -> str:
    if result is not None:
        causes = result["causes"]
        names = sorted({c for per in causes.values() for c in per})
        rows = [
            [h.td(c)]
            + [h.td(causes[s].get(c, 0), num=True) for s in ("fixed", "introduced", "kept")]
            for c in names
        ]
        if not rows:
            return '<p class="note">No events.</p>'
        return (
            '<p class="note">Fixed events by their cause in A, introduced by their cause in B, '
            'kept by their cause in B, else in A ("unknown": no run recorded the sequence).</p>'
            + h.table(
                ["cause", "fixed", "introduced", "kept"], rows, numeric=[False, True, True, True]
            )
        )
    from collections import Counter

    counts: Counter[tuple[str, str, str]] = Counter(
        (e.get("cause") or "unknown", e["class"], e["kind"]) for e in run_a.events
    )
    cols = sorted({(c, k) for _, c, k in counts})
    names = sorted({x for x, _, _ in counts})
    rows = [[h.td(n)] + [h.td(counts[(n, c, k)], num=True) for c, k in cols] for n in names]
    if not rows:
        return '<p class="note">No events.</p>'
    return h.table(
        ["cause"] + [f"{c} {k}" for c, k in cols], rows, numeric=[False] + [True] * len(cols)
    )


def _motion_section(run_a: Run, run_b: Run | None, result: Mapping[str, Any] | None) -> str:
    runs = [run_a] + ([run_b] if run_b else [])
    blocks = []
    if result is not None and result.get("sequences_left_out"):
        blocks.append(
            '<p class="note">Each run\'s own, over all the sequences it tracked (not only the '
            "compared ones).</p>"
        )
    for r in runs:
        m = r.summary.get("motion")
        if not isinstance(m, Mapping):
            blocks.append(
                f'<p class="note">{h.esc(r.name)}: no motion metrics '
                f"({h.esc(m or 'run mctrack kitti --motion')}).</p>"
            )
            continue
        rows = []
        for est, per in m.get("metrics", {}).items():
            for cls, v in per.items():
                if isinstance(v, Mapping) and any(v.get(k) is not None for k in MOTION_KEYS):
                    rows.append(
                        [h.td(est), h.td(cls)]
                        + [h.td(v.get(k), num=True) for k in (*MOTION_KEYS, "n_samples")]
                    )
        blocks.append(
            f"<h3>{h.esc(r.name)}</h3>"
            + h.table(
                ["estimator", "class", *MOTION_KEYS, "samples"],
                rows,
                numeric=[False, False] + [True] * (len(MOTION_KEYS) + 1),
            )
        )
    return "".join(blocks)


def _shots_section(
    shot_files: Mapping[tuple[str, int], str], asked: int, runs: Sequence[Run | None]
) -> str:
    if not shot_files:
        why = (
            "not asked for (mctrack report --shots N)"
            if asked == 0
            else "none taken (no recordings with events, or no Vulkan driver: see the log)"
        )
        return f'<p class="note">No shots: {h.esc(why)}.</p>'
    from tracker.eval.compare import event_text

    captions = {}
    for prefix, r in zip(("", "b/"), runs, strict=True):
        for e in r.events if r is not None else ():
            if e.get("event") is not None:
                captions[(prefix + e["sequence"], e["event"])] = event_text(e)
    figs = [
        h.figure(
            h.url_path(p),
            ("B " if seq.startswith("b/") else "") + f"#{k}: {captions.get((seq, k), '')}",
        )
        for (seq, k), p in sorted(shot_files.items())
    ]
    return '<div class="gallery">' + "".join(figs) + "</div>"


def _recordings_section(run_a: Run, run_b: Run | None) -> str:
    rows = []
    for tag, r in (("A", run_a), ("B", run_b)):
        if r is None:
            continue
        for seq, rec in sorted(r.recordings.items()):
            n = sum(e["sequence"] == seq for e in r.events)
            rows.append(
                [
                    h.td(tag),
                    h.td(seq),
                    h.td(f"<code>{h.esc(str(rec))}</code>", raw=True),
                    h.td(n, num=True),
                    h.td(  # (absolute: pasted from any folder)
                        "<code>mctrack inspect "
                        f"{h.esc(shlex.quote(str(rec.resolve())))} --event K</code>",
                        raw=True,
                    ),
                ]
            )
    if not rows:
        return (
            '<p class="note">No recordings: record the run with <code>mctrack kitti '
            "--record</code> for causes, shots and viewer links.</p>"
        )
    return (
        '<p class="note">Open a recording at event #K with the command (the native viewer, '
        'focused on the event)<span class="live-only" hidden>, or click "view" in the event '
        "table (the web viewer served with the report, at the event's frame)</span>.</p>"
        + h.table(
            ["run", "sequence", "recording", "events", "command"],
            rows,
            numeric=[False, False, False, True, False],
        )
    )
