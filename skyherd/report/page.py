"""report.html: one self-contained page per `skyherd fly` run folder, the flight at a glance.

The page is summary.md (the verdict, why it ended, the mission's table, the judge's checks
with their figures, how it ended) rendered to HTML, the run's facts from config.json and
companion.json, and every figure of the folder embedded as a data: URI (no file beside it, no
network: the page can be mailed or attached to an issue). summary.md stays the one source of
the words; this module only lays them out. Written after the flight's ending is known
(report.ending.append_ending), so a failed or interrupted flight has its page too.
"""

from __future__ import annotations

import base64
import html
import json
import re
from pathlib import Path

from skyherd.runio import try_write_text

REPORT = "report.html"
# the figures, in the page's order, and what each one shows
FIGURES = {
    "groundair.png": "the flight on one time axis: phases, altitude with the envelope's ceiling "
    "and floor, features, the safety net's verdict per decision; the track over the UGV team "
    "and inside the fence",
    "track.png": "the track inside the fence (exclusion zones filled) and the flight on one time "
    "axis",
    "shepherd.png": "the flock, its centre and the UAV over the goal; spread and distance to goal",
    "formation.png": "the formation's tracks",
    "frames.png": "camera frames as the companion received them, annotated by the detector "
    "(time, altitude above home and phase on each)",
}
STYLE = """
body{font:15px/1.45 system-ui,sans-serif;margin:1.5em auto;max-width:1200px;color:#222;padding:0 1em}
h1{font-size:1.5em;margin:.2em 0}h2{font-size:1.15em;border-bottom:1px solid #ccc;margin-top:1.6em}
.verdict{padding:.6em 1em;border-radius:6px;font-weight:600;font-size:1.1em}
.ok{background:#e3f4e1;border:1px solid #2ca02c}.bad{background:#fbe3e3;border:1px solid #d62728}
.stop{background:#fff3d6;border:1px solid #e0a000}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:left;vertical-align:top}
th{background:#f2f2f2}td.pass{color:#1d6b1d;font-weight:600}td.fail{color:#b00;font-weight:700}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.9em;color:#555}code{background:#f4f4f4;padding:0 .2em}
dl{display:grid;grid-template-columns:max-content auto;gap:.2em 1em}dt{font-weight:600}dd{margin:0}
"""


def _inline(text: str) -> str:
    """Markdown's inline marks of summary.md (**bold**, `code`) on escaped text."""
    s = html.escape(text)
    s = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", s)
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", s)


def _cells(line: str) -> list[str]:
    """A markdown table row's cells (a pipe escaped as \\| stays in its cell)."""
    inner = line.strip()[1:-1] if line.strip().endswith("|") else line.strip()[1:]
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", inner)]


def _table(lines: list[str]) -> str:
    rows = [_cells(ln) for ln in lines if not re.fullmatch(r"\|[\s|:-]+\|", ln.strip())]
    if not rows:
        return ""
    head = "".join(f"<th>{_inline(c)}</th>" for c in rows[0])
    body = []
    for r in rows[1:]:
        tds = []
        for c in r:
            cls = {"pass": ' class="pass"', "FAIL": ' class="fail"'}.get(c, "")
            tds.append(f"<td{cls}>{_inline(c)}</td>")
        body.append("<tr>" + "".join(tds) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def markdown_to_html(md: str) -> str:
    """The markdown summary.md is written in: headings, paragraphs, tables, "- " lists."""
    out, para, table, items = [], [], [], []

    def flush() -> None:
        if para:
            out.append(f"<p>{_inline(' '.join(para))}</p>")
            para.clear()
        if table:
            out.append(_table(table))
            table.clear()
        if items:
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
            items.clear()

    for line in md.splitlines():
        s = line.strip()
        if s.startswith("|"):
            if not table:
                flush()
            table.append(s)
            continue
        if table:
            flush()
        if not s:
            flush()
        elif m := re.match(r"(#{1,3}) (.*)", s):
            flush()
            level = len(m.group(1)) + 1  # the page's own title is the h1
            out.append(f"<h{level}>{_inline(m.group(2))}</h{level}>")
        elif s.startswith("- "):
            if para:
                flush()
            items.append(s[2:])
        elif items and line.startswith("  "):  # a list item's continuation
            items[-1] += " " + s
        else:
            para.append(s)
    flush()
    return "\n".join(out)


def _verdict(md: str) -> tuple[str, str]:
    """(css class, text) of summary.md's first heading ("# skyherd fly: completed" …)."""
    m = re.search(r"^# (.*)$", md, re.M)
    text = m.group(1) if m else "skyherd fly: no summary (the report was not written)"
    low = text.lower()
    kind = "ok" if low.endswith(": completed") else "stop" if "interrupted" in low else "bad"
    return kind, text


def _facts(run_dir: Path) -> str:
    """The run's facts: the command line, seed, envelope, signing, decisions and latency."""

    def read(name: str) -> dict:
        try:
            doc = json.loads((run_dir / name).read_text())
        except (OSError, ValueError):
            return {}
        return doc if isinstance(doc, dict) else {}

    cfg, comp = read("config.json"), read("companion.json")
    args = cfg.get("args") or {}
    env = cfg.get("envelope") or {}
    rows = [
        ("run folder", run_dir.name),
        ("command", _command(cfg.get("argv") or [])),
        ("seed", args.get("seed")),
        ("envelope", f"{env['name']} {env.get('version', '')}" if env.get("name") else None),
        ("decision latency (wall) p50 / p95",
         f"{1e3 * comp['decide_wall_p50_s']:.2f} / {1e3 * comp['decide_wall_p95_s']:.2f} ms"
         if comp.get("decide_wall_p50_s") is not None and comp.get("decide_wall_p95_s") is not None
         else None),
    ]  # fmt: skip
    items = "".join(f"<dt>{html.escape(k)}</dt><dd>{html.escape(str(v))}</dd>" for k, v in rows
                    if v not in (None, ""))  # fmt: skip
    return f"<dl>{items}</dl>"


def _command(argv: list) -> str | None:
    """The command line as typed (None when `fly` ran inside another program, e.g. a test)."""
    words = [str(a) for a in argv]
    if not words or not re.search(r"(skyherd|cli\.py)$", words[0]):
        return None
    return " ".join(["skyherd", *words[1:]])


def _figures(run_dir: Path) -> str:
    out = []
    for name, caption in FIGURES.items():
        path = run_dir / name
        try:
            data = path.read_bytes()
        except OSError:
            continue
        if not data.startswith(b"\x89PNG"):
            continue
        b64 = base64.b64encode(data).decode("ascii")
        out.append(f'<figure id="{html.escape(name)}"><img alt="{html.escape(name)}" '
                   f'src="data:image/png;base64,{b64}"><figcaption><code>{html.escape(name)}'
                   f"</code>: {html.escape(caption)}</figcaption></figure>")  # fmt: skip
    return "\n".join(out) or "<p>No figure was drawn (nothing was recorded to draw).</p>"


def render(run_dir: Path) -> str:
    """The page's text (module docstring)."""
    try:
        md = (run_dir / "summary.md").read_text(encoding="utf-8")
    except OSError:
        md = ""
    kind, verdict = _verdict(md)
    body = re.sub(r"^# .*\n?", "", md, count=1, flags=re.M)  # the verdict is the banner
    files = sorted(p.name for p in run_dir.iterdir() if p.name != REPORT)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(verdict)} ({html.escape(run_dir.name)})</title>"
        f"<style>{STYLE}</style></head><body>\n"
        f"<h1>skyherd flight report</h1>\n"
        f'<p class="verdict {kind}" id="verdict">{_inline(verdict)}</p>\n'
        f"{_facts(run_dir)}\n{markdown_to_html(body)}\n"
        f"<h2>Figures</h2>\n{_figures(run_dir)}\n"
        f"<h2>Files</h2>\n<p>{', '.join(f'<code>{html.escape(f)}</code>' for f in files)}</p>\n"
        "</body></html>\n"
    )


def write_report_html(run_dir: Path) -> str | None:
    """report.html in the run folder; None, or why it could not be written (never raises)."""
    try:
        text = render(run_dir)
    except (OSError, ValueError) as e:
        return f"report.html not written ({type(e).__name__}: {e})"
    return try_write_text(run_dir / REPORT, text)
