"""The report's HTML: one self-contained page (inline CSS and JS, no network), tables sortable
by a click on a column header and filterable, images from the report folder."""

from __future__ import annotations

import html
import urllib.parse
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

CSS = """
:root { --fg:#1d2327; --muted:#5f6b73; --line:#d9dee2; --head:#eef1f4; --a:#3c78f0; --b:#f08c1e;
  --fixed:#1f9d55; --introduced:#d43c3c; --kept:#8a6d00; }
* { box-sizing: border-box; }
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: var(--fg);
  margin: 0; background: #fafbfc; }
header { background: #1d2327; color: #fff; padding: 14px 24px; }
header h1 { margin: 0; font-size: 20px; font-weight: 600; }
header p { margin: 4px 0 0; color: #c5ccd2; font-size: 13px; }
nav { padding: 8px 24px; background: #fff; border-bottom: 1px solid var(--line); }
nav a { margin-right: 16px; color: var(--a); text-decoration: none; font-weight: 500; }
main { padding: 8px 24px 40px; max-width: 1500px; }
section { margin-top: 22px; }
h2 { font-size: 17px; margin: 0 0 8px; border-bottom: 1px solid var(--line); padding-bottom: 4px; }
p.note { color: var(--muted); margin: 4px 0 8px; font-size: 13px; }
.scroll { max-height: 560px; overflow: auto; border: 1px solid var(--line); background: #fff; }
table { border-collapse: collapse; font-variant-numeric: tabular-nums; background: #fff; }
th, td { padding: 4px 10px; border-bottom: 1px solid var(--line); text-align: left;
  white-space: nowrap; }
td.num, th.num { text-align: right; }
thead th { background: var(--head); cursor: pointer; user-select: none; }
.scroll thead th { position: sticky; top: 0; z-index: 1; }
thead th.sorted-asc::after { content: " \\25B2"; font-size: 10px; }
thead th.sorted-desc::after { content: " \\25BC"; font-size: 10px; }
tbody tr:nth-child(even) { background: #f7f9fa; }
tbody tr:hover { background: #eaf2ff; }
.better { color: var(--fixed); font-weight: 600; }
.worse { color: var(--introduced); font-weight: 600; }
.badge { display: inline-block; padding: 0 7px; border-radius: 9px; font-size: 12px;
  font-weight: 600; color: #fff; }
.badge.fixed { background: var(--fixed); } .badge.introduced { background: var(--introduced); }
.badge.kept { background: var(--kept); } .badge.run { background: #6b7780; }
code { font: 12px ui-monospace, SFMono-Regular, Menlo, monospace; background: #f0f2f4;
  padding: 1px 4px; border-radius: 3px; }
td code { user-select: all; }
.plots { display: flex; flex-wrap: wrap; gap: 16px; }
.plots figure { margin: 0; background: #fff; border: 1px solid var(--line); padding: 6px; }
.plots img { display: block; max-width: 100%; height: auto; }
figcaption { color: var(--muted); font-size: 12px; margin-top: 4px; }
.gallery { display: grid; grid-template-columns: repeat(auto-fill, minmax(300px, 1fr)); gap: 12px; }
.gallery figure { margin: 0; background: #fff; border: 1px solid var(--line); padding: 6px; }
.gallery img { width: 100%; height: auto; display: block; }
input[type=search] { padding: 4px 8px; width: 320px; margin: 4px 0 8px;
  border: 1px solid var(--line); border-radius: 4px; }
a.live { font-weight: 600; color: var(--a); }
"""

# Sort a table by the clicked header (numbers numerically), filter rows by a search box. No
# network, no library: the page must open from the file system in any browser.
JS = """
function cellValue(tr, i) {
  const td = tr.children[i]; if (!td) return "";
  const v = td.dataset.sort !== undefined ? td.dataset.sort : td.textContent.trim();
  const n = parseFloat(v); return (v !== "" && !isNaN(n) && /^[-+]?[0-9.]/.test(v)) ? n : v;
}
document.querySelectorAll("table.sortable").forEach(function (table) {
  table.querySelectorAll("thead th").forEach(function (th, i) {
    th.addEventListener("click", function () {
      const asc = !th.classList.contains("sorted-asc");
      table.querySelectorAll("thead th")
        .forEach(h => h.classList.remove("sorted-asc", "sorted-desc"));
      th.classList.add(asc ? "sorted-asc" : "sorted-desc");
      const body = table.tBodies[0];
      const rows = Array.from(body.rows);
      rows.sort(function (a, b) {
        const x = cellValue(a, i), y = cellValue(b, i);
        if (typeof x === "number" && typeof y === "number") return asc ? x - y : y - x;
        return asc ? String(x).localeCompare(String(y)) : String(y).localeCompare(String(x));
      });
      rows.forEach(r => body.appendChild(r));
    });
  });
});
document.querySelectorAll("input[data-filter]").forEach(function (input) {
  const table = document.getElementById(input.dataset.filter);
  input.addEventListener("input", function () {
    const q = input.value.toLowerCase();
    Array.from(table.tBodies[0].rows).forEach(function (r) {
      r.style.display = r.textContent.toLowerCase().includes(q) ? "" : "none";
    });
  });
});
// Served by `mctrack report --serve`: event links open Rerun's web viewer at the event's frame.
if (location.protocol === "http:" || location.protocol === "https:") {
  fetch("serve.json").then(r => r.ok ? r.json() : null).then(function (info) {
    if (!info) return;
    document.querySelectorAll("a.live").forEach(function (a) {
      const rec = location.origin + "/recordings/" + a.dataset.rec + ".rrd";
      a.href = info.viewer + "?url=" + encodeURIComponent(rec) + "&frame=" + a.dataset.frame;
      a.hidden = false;
    });
    document.querySelectorAll(".live-only").forEach(e => { e.hidden = false; });
  }).catch(function () {});
}
"""


def esc(v: Any) -> str:
    return html.escape("" if v is None else str(v), quote=True)


def fmt(v: Any, digits: int = 3) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def delta_cell(metric: str, delta: Any, lower_is_better: bool) -> str:
    if delta is None:
        return '<td class="num">–</td>'
    good = delta < 0 if lower_is_better else delta > 0
    cls = "" if delta == 0 else (' class="num better"' if good else ' class="num worse"')
    cls = cls or ' class="num"'
    text = f"{delta:+d}" if isinstance(delta, int) else f"{delta:+.3f}"
    return f'<td{cls} data-sort="{delta}">{text}</td>'


def table(
    headers: Sequence[str],
    rows: Iterable[Sequence[str]],
    *,
    table_id: str | None = None,
    numeric: Sequence[bool] | None = None,
    scroll: bool = False,
) -> str:
    """A sortable table; each row's cells are already HTML (``<td>...</td>``)."""
    numeric = numeric or [False] * len(headers)
    head = "".join(
        f'<th class="num">{esc(h)}</th>' if n else f"<th>{esc(h)}</th>"
        for h, n in zip(headers, numeric, strict=True)
    )
    body = "\n".join("<tr>" + "".join(r) + "</tr>" for r in rows)
    tid = f' id="{esc(table_id)}"' if table_id else ""
    t = (
        f'<table class="sortable"{tid}><thead><tr>{head}</tr></thead>'
        f"<tbody>\n{body}\n</tbody></table>"
    )
    return f'<div class="scroll">{t}</div>' if scroll else t


def td(v: Any, *, num: bool = False, raw: bool = False, sort: Any = None) -> str:
    text = str(v) if raw else esc(fmt(v) if num else v)
    attrs = ' class="num"' if num else ""
    if sort is not None:
        attrs += f' data-sort="{esc(sort)}"'
    elif num and isinstance(v, int | float):
        attrs += f' data-sort="{v}"'
    return f"<td{attrs}>{text}</td>"


def url_path(path: str) -> str:
    """A relative file path as a URL path: a folder named after a sequence holds its escape
    (``%3F`` for '?', :func:`tracker.io.fileio.safe_filename`), which a browser would decode."""
    return urllib.parse.quote(path)


def figure(src: str, caption: str, width: int | None = None) -> str:
    w = f' width="{width}"' if width else ""
    return (
        f'<figure><img src="{esc(src)}" alt="{esc(caption)}"{w}>'
        f"<figcaption>{esc(caption)}</figcaption></figure>"
    )


def page(title: str, subtitle: str, sections: Sequence[tuple[str, str, str]]) -> str:
    """``sections``: (anchor, heading, inner HTML)."""
    nav = "".join(f'<a href="#{esc(a)}">{esc(h)}</a>' for a, h, _ in sections)
    body = "\n".join(
        f'<section id="{esc(a)}"><h2>{esc(h)}</h2>\n{inner}\n</section>' for a, h, inner in sections
    )
    return (
        '<!doctype html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{esc(title)}</title><style>{CSS}</style></head>\n<body>"
        f"<header><h1>{esc(title)}</h1><p>{esc(subtitle)}</p></header>"
        f"<nav>{nav}</nav>\n<main>\n{body}\n</main>\n<script>{JS}</script>\n</body></html>\n"
    )


def kv_list(items: Mapping[str, Any]) -> str:
    return (
        "<ul>" + "".join(f"<li><b>{esc(k)}</b>: {esc(v)}</li>" for k, v in items.items()) + "</ul>"
    )
