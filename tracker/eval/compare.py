"""A/B comparison of two tracking runs: which ID events one run fixed, introduced or kept, and
the metric deltas per class and per sequence.

An *event* is one ID switch or fragmentation as counted by TrackEval's CLEAR
(:mod:`tracker.eval.id_switches`), as a plain dict (see :func:`event_record`) so that the
comparison is JSON in, JSON out. Two events of runs A and B are *the same* when they have the
same sequence, kind, class and GT id and their frames differ by at most ``tolerance`` frames:
track ids are not compared, because two configs number their tracks differently. Within one
(sequence, kind, class, GT id) group the pairs are matched closest first, so each event is
used once. A is the baseline: *fixed* = in A only, *introduced* = in B only, *kept* = in both.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from tracker.eval.id_switches import IdEvent, IdEventKind

#: Frames two runs' events may differ by and still be the same event (a config change often
#: moves a switch by a frame or two: a track deleted one frame later, a birth one frame earlier).
DEFAULT_TOLERANCE = 2
STATUSES = ("fixed", "introduced", "kept")
#: The run-level metrics compared per class (summary.json "metrics"), in table order.
CLASS_METRICS = ("HOTA", "DetA", "AssA", "MOTA", "IDF1", "IDSW", "Frag", "FP", "FN")
#: Lower is better for these; the others are higher-is-better.
LOWER_IS_BETTER = frozenset({"IDSW", "Frag", "FP", "FN"})

Event = dict[str, Any]


def event_record(
    sequence: str, e: IdEvent, *, cause: str | None = None, index: int | None = None
) -> Event:
    """An event as plain data. ``index``: its ``#K`` in the sequence's recording (where one
    exists, for ``mctrack inspect REC --event K``); ``cause``: its cause category, where known."""
    return {
        "sequence": sequence,
        "kind": "IDSW" if e.kind is IdEventKind.ID_SWITCH else "Frag",
        "frame": e.frame_id,
        "class": e.category,
        "gt_id": e.gt_id,
        "old_track": e.old_track_id,
        "new_track": e.new_track_id,
        "last_frame": e.last_frame_id,
        "cause": cause,
        "event": index,
    }


def _group_key(e: Event) -> tuple[str, str, str, int]:
    return (str(e["sequence"]), str(e["kind"]), str(e["class"]), int(e["gt_id"]))


def _sort_key(e: Event) -> tuple[Any, ...]:
    return (*_group_key(e), int(e["frame"]))


def match_events(
    a: Iterable[Event], b: Iterable[Event], *, tolerance: int = DEFAULT_TOLERANCE
) -> list[dict[str, Any]]:
    """Pairs ``{"status", "a", "b"}`` (``a`` or ``b`` None for fixed / introduced), sorted by
    sequence, frame, class and GT id. Deterministic: ties go to the earlier frames."""
    if tolerance < 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance}")
    groups: dict[tuple[str, str, str, int], tuple[list[Event], list[Event]]] = {}
    for side, events in enumerate((a, b)):
        for e in events:
            groups.setdefault(_group_key(e), ([], []))[side].append(e)
    out: list[dict[str, Any]] = []
    for ea, eb in groups.values():
        ea.sort(key=_sort_key)
        eb.sort(key=_sort_key)
        pairs = sorted(
            (abs(x["frame"] - y["frame"]), x["frame"], y["frame"], i, j)
            for i, x in enumerate(ea)
            for j, y in enumerate(eb)
            if abs(x["frame"] - y["frame"]) <= tolerance
        )
        used_a: set[int] = set()
        used_b: set[int] = set()
        for *_, i, j in pairs:
            if i not in used_a and j not in used_b:
                used_a.add(i)
                used_b.add(j)
                out.append({"status": "kept", "a": ea[i], "b": eb[j]})
        out += [{"status": "fixed", "a": x, "b": None} for i, x in enumerate(ea) if i not in used_a]
        out += [
            {"status": "introduced", "a": None, "b": y} for j, y in enumerate(eb) if j not in used_b
        ]

    def order(p: dict[str, Any]) -> tuple[Any, ...]:
        e = p["a"] or p["b"]
        return (e["sequence"], e["frame"], e["class"], e["gt_id"], e["kind"], p["status"])

    return sorted(out, key=order)


def _delta(a: Any, b: Any) -> float | int | None:
    if isinstance(a, int) and isinstance(b, int) and not isinstance(a | b, bool):
        return b - a  # counts stay integers
    if isinstance(a, int | float) and isinstance(b, int | float):
        return round(float(b) - float(a), 3)
    return None


def metric_deltas(
    a: Mapping[str, Mapping[str, Any]], b: Mapping[str, Mapping[str, Any]], keys: Sequence[str]
) -> dict[str, dict[str, dict[str, Any]]]:
    """{class: {metric: {"a", "b", "delta"}}} over the classes of either side (None: absent)."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for cls in sorted(set(a) | set(b)):
        ma, mb = a.get(cls, {}), b.get(cls, {})
        out[cls] = {
            k: {"a": ma.get(k), "b": mb.get(k), "delta": _delta(ma.get(k), mb.get(k))}
            for k in keys
            if k in ma or k in mb
        }
    return out


def status_counts(pairs: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, dict[str, int]]]:
    """{sequence: {"<class> <IDSW|Frag>": {status: n}}} plus a "total" sequence."""
    out: dict[str, dict[str, Counter[str]]] = {}
    for p in pairs:
        e = p["a"] or p["b"]
        key = f"{e['class']} {e['kind']}"
        for seq in (e["sequence"], "total"):
            out.setdefault(seq, {}).setdefault(key, Counter())[p["status"]] += 1
    return {
        seq: {k: {s: c[s] for s in STATUSES} for k, c in sorted(per.items())}
        for seq, per in sorted(out.items(), key=lambda kv: (kv[0] == "total", kv[0]))
    }


def cause_counts_by_status(pairs: Iterable[Mapping[str, Any]]) -> dict[str, dict[str, int]]:
    """{status: {cause: n}}: fixed events by their cause in A, introduced by their cause in B,
    kept by their cause in B, else in A ("unknown" where no run has a recording with causes)."""
    out: dict[str, Counter[str]] = {s: Counter() for s in STATUSES}
    for p in pairs:
        cause = (p["b"] or {}).get("cause") or (p["a"] or {}).get("cause")
        out[p["status"]][cause or "unknown"] += 1
    return {s: dict(sorted(c.items())) for s, c in out.items()}


def compare_runs(
    summary_a: Mapping[str, Any],
    summary_b: Mapping[str, Any],
    events_a: Sequence[Event],
    events_b: Sequence[Event],
    *,
    tolerance: int = DEFAULT_TOLERANCE,
    names: tuple[str, str] = ("A", "B"),
) -> dict[str, Any]:
    """The content of ``compare.json``: runs, metric deltas (per class; per sequence and class
    where the summaries have them), the matched events and their counts."""
    pairs = match_events(events_a, events_b, tolerance=tolerance)
    per_seq_a = summary_a.get("per_sequence_metrics") or summary_a.get("per_sequence") or {}
    per_seq_b = summary_b.get("per_sequence_metrics") or summary_b.get("per_sequence") or {}
    seq_keys = ("HOTA", "AssA", "MOTA", "IDF1", "IDSW", "Frag")
    return {
        "runs": {
            "a": {"name": names[0], **_run_info(summary_a)},
            "b": {"name": names[1], **_run_info(summary_b)},
        },
        "tolerance_frames": tolerance,
        "matching": "same sequence, kind, class and GT id; frames within the tolerance; "
        "closest first. fixed = in A only, introduced = in B only, kept = in both.",
        "metrics": metric_deltas(
            summary_a.get("metrics") or {}, summary_b.get("metrics") or {}, CLASS_METRICS
        ),
        "per_sequence": {
            seq: metric_deltas(per_seq_a.get(seq, {}), per_seq_b.get(seq, {}), seq_keys)
            for seq in sorted(set(per_seq_a) | set(per_seq_b))
        },
        "motion": _motion_deltas(summary_a.get("motion"), summary_b.get("motion")),
        "counts": status_counts(pairs),
        "causes": cause_counts_by_status(pairs),
        "events": pairs,
    }


def _run_info(summary: Mapping[str, Any]) -> dict[str, Any]:
    config = summary.get("config") or {}
    return {
        "path": summary.get("path"),
        "detector": summary.get("detector"),
        "mode": summary.get("mode"),
        "config_name": summary.get("config_name"),
        "classes": summary.get("classes"),
        "sequences": summary.get("sequences"),
        "categories": config.get("categories"),
    }


MOTION_KEYS = ("vae_deg", "vne_mps", "vir_ratio", "vse_mps", "vde_secs")


def _motion_deltas(a: Any, b: Any) -> dict[str, Any] | str:
    """Kalman-estimator motion metrics per class, A vs B; a reason string when either lacks
    them (run without --motion)."""
    if not isinstance(a, Mapping) or not isinstance(b, Mapping):
        return "absent: both runs need mctrack kitti --motion"
    ma = a.get("metrics", {}).get("kalman", {})
    mb = b.get("metrics", {}).get("kalman", {})
    return metric_deltas(ma, mb, MOTION_KEYS)


def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.3f}"
    return str(v)


def _fmt_delta(v: Any) -> str:
    if v is None:
        return "–"
    return f"{v:+d}" if isinstance(v, int) else f"{v:+.3f}"


def event_text(e: Mapping[str, Any]) -> str:
    """``0016 f123 pedestrian GT7 T3->T9 IDSW (deleted_reborn)``."""
    cause = f" ({e['cause']})" if e.get("cause") else ""
    return (
        f"{e['sequence']} f{e['frame']} {e['class']} GT{e['gt_id']} "
        f"T{e['old_track']}->T{e['new_track']} {e['kind']}{cause}"
    )


def left_out_note(result: Mapping[str, Any]) -> str | None:
    """One line: which sequences were compared, which left out and why (None: all were)."""
    left_out = result.get("sequences_left_out")
    classes = result.get("classes_left_out")
    parts = []
    if left_out:
        shared = result["sequences_compared"]
        rescored = result.get("rescored") or []
        parts.append(
            f"compared the {len(shared)} sequence(s) both runs tracked and scored "
            f"({', '.join(shared)}); left out: "
            + "; ".join(f"{seq} ({why})" for seq, why in left_out.items())
            + (f"; metrics of {' and '.join(rescored)} scored again on them" if rescored else "")
        )
    if classes:
        parts.append(
            "events of classes one run did not track are not compared: "
            + "; ".join(f"{c} ({why})" for c, why in classes.items())
        )
    return "; ".join(parts) or None


def compare_markdown(result: Mapping[str, Any], *, command: str | None = None) -> list[str]:
    """``compare.md``: runs, per-class deltas, event counts per sequence, the event lists."""
    ra, rb = result["runs"]["a"], result["runs"]["b"]
    lines = ["# Compare: A vs B", ""]
    if command:
        lines += [f"Made by `{command}`.", ""]
    lines += [
        f"- A: `{ra['name']}` ({ra.get('detector')}, {ra.get('mode')}, config "
        f"{ra.get('config_name') or 'n/a'})",
        f"- B: `{rb['name']}` ({rb.get('detector')}, {rb.get('mode')}, config "
        f"{rb.get('config_name') or 'n/a'})",
        f"- Events matched by {result['matching']} Tolerance {result['tolerance_frames']} frames.",
    ]
    note = left_out_note(result)
    if note:
        lines.append(f"- Scope: {note}.")
    lines += [
        "",
        "## Metrics per class (B − A)",
        "",
    ]
    metrics = result["metrics"]
    if metrics:
        keys = [k for k in CLASS_METRICS if any(k in m for m in metrics.values())]
        lines += ["| class | " + " | ".join(keys) + " |", "|---|" + "---:|" * len(keys)]
        for cls, m in metrics.items():
            cells = [
                f"{_fmt(m[k]['a'])} → {_fmt(m[k]['b'])} ({_fmt_delta(m[k]['delta'])})"
                if k in m
                else "–"
                for k in keys
            ]
            lines.append(f"| {cls} | " + " | ".join(cells) + " |")
    else:
        lines.append("No metrics: a run was not evaluated.")
    lines += ["", "## ID events per sequence: fixed / introduced / kept", ""]
    counts = result["counts"]
    cols = sorted({k for per in counts.values() for k in per})
    if cols:
        lines += ["| sequence | " + " | ".join(cols) + " |", "|---|" + "---:|" * len(cols)]
        for seq, per in counts.items():
            cells = []
            for k in cols:
                c = per.get(k)
                cells.append(f"{c['fixed']} / {c['introduced']} / {c['kept']}" if c else "–")
            name = f"**{seq}**" if seq == "total" else seq
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    else:
        where = " in what was compared" if note else ""
        lines.append(f"Neither run has ID switches or fragmentations{where}.")
    motion = result.get("motion")
    lines += ["", "## Motion metrics (Kalman velocity, B − A)", ""]
    if isinstance(motion, Mapping) and motion:
        lines += ["| class | " + " | ".join(MOTION_KEYS) + " |", "|---|" + "---:|" * 5]
        for cls, m in motion.items():
            cells = [_fmt_delta(m[k]["delta"]) if k in m else "–" for k in MOTION_KEYS]
            lines.append(f"| {cls} | " + " | ".join(cells) + " |")
    else:
        lines.append(str(motion))
    causes = result["causes"]
    lines += ["", "## Causes", ""]
    names = sorted({c for per in causes.values() for c in per})
    if names:
        lines += ["| cause | " + " | ".join(STATUSES) + " |", "|---|---:|---:|---:|"]
        for c in names:
            lines.append(
                f"| {c} | " + " | ".join(str(causes[s].get(c, 0)) for s in STATUSES) + " |"
            )
    for status in ("fixed", "introduced"):
        listed = [p for p in result["events"] if p["status"] == status]
        lines += ["", f"## {status.capitalize()} ({len(listed)})", ""]
        for p in listed:
            e = p["a"] if status == "fixed" else p["b"]
            lines.append(f"- {event_text(e)}")
    kept = sum(p["status"] == "kept" for p in result["events"])
    lines += ["", f"Kept: {kept} events (listed in compare.json).", ""]
    return lines


__all__ = [
    "DEFAULT_TOLERANCE",
    "STATUSES",
    "compare_markdown",
    "compare_runs",
    "event_record",
    "event_text",
    "match_events",
    "metric_deltas",
]
