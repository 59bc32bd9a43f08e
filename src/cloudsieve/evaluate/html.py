"""report.html: one self-contained page (no network access) with the tables, the plots and 3D views.

Everything is inline: tables, PNG plots as ``data:`` URIs, the vendored WebGL viewer (:file:`viewer.js`), and
at most ``VIEW_POINTS`` points a view, quantised to 16 bits over the original's box with one byte of error.
Original points are coloured by forward error, red = 0 to blue = the shown 99th percentile (one scale for every
method); kept points in one colour.
"""

from __future__ import annotations

import base64
import html
import json
import os
import re
from importlib import resources
from pathlib import Path

import numpy as np

from ..atomic import write_text

__all__ = ["VIEW_POINTS", "view_sample", "markdown_html", "page", "write_html"]

#: at most this many points in a 3D view (a uniform seeded sample)
VIEW_POINTS = 200_000
#: the colour scale's top: this percentile of the errors shown
TOP_PERCENTILE = 99.0

_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em auto;max-width:1400px;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.5em 0}th,td{border:1px solid #ccc;padding:.25em .6em}
td{text-align:right}td:first-child{text-align:left}th{background:#f3f3f3}
blockquote{border-left:4px solid #e0a000;margin:.5em 0;padding:.2em .8em;background:#fff8e0}
.views{display:flex;flex-wrap:wrap;gap:1em}.view{flex:1 1 420px}
.view canvas{width:100%;height:420px;border:1px solid #ccc;display:block;cursor:grab}
.scale{height:12px;background:linear-gradient(to right,#800000,#ff0000,#ffff00,#00ffff,#0000ff,#000080)}
img{max-width:100%}
"""


def view_sample(n: int, size: int = VIEW_POINTS, seed: int = 0) -> np.ndarray:
    """Sorted indices of a uniform seeded sample of at most *size* of *n* points (all when n <= size)."""
    if n <= size:
        return np.arange(n)
    return np.sort(np.random.default_rng([seed, 30]).choice(n, size=size, replace=False))


def _b64(a: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(a).tobytes()).decode("ascii")


def _quantise(xyz: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    span = np.where(hi > lo, hi - lo, 1.0)
    q = np.rint((np.asarray(xyz, dtype=np.float64) - lo) / span * 65535.0)
    return np.clip(q, 0, 65535).astype("<u2")


def _inline(text: str) -> str:
    text = html.escape(text, quote=False)
    text = re.sub(r"`([^`]+)`", r"<code>\1</code>", text)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", text)


def markdown_html(md: str) -> str:
    """HTML of the Markdown that :func:`.report.markdown` and :func:`.compare.compare_markdown` write.
    Handles what they use: ``#`` headings, pipe tables, ``>`` quotes, ``-`` lists and paragraphs (text escaped,
    inline code and bold)."""
    out: list[str] = []
    lines = md.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if not line.strip():
            i += 1
        elif line.startswith("#"):
            level = min(len(line) - len(line.lstrip("#")) + 1, 6)  # the page's title is the h1
            out.append(f"<h{level}>{_inline(line.lstrip('#').strip())}</h{level}>")
            i += 1
        elif line.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].startswith("|"):
                rows.append([c.strip() for c in lines[i].strip().strip("|").split("|")])
                i += 1
            body = [r for r in rows[1:] if not all(re.fullmatch(r":?-+:?", c) for c in r if c)]
            out.append("<table><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in rows[0]) + "</tr>"
                       + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body)
                       + "</table>")
        elif line.startswith(">"):
            out.append(f"<blockquote>{_inline(line.lstrip('> ').strip())}</blockquote>")
            i += 1
        elif line.startswith("- "):
            items = []
            while i < len(lines) and lines[i].startswith("- "):
                items.append(f"<li>{_inline(lines[i][2:])}</li>")
                i += 1
            out.append("<ul>" + "".join(items) + "</ul>")
        else:
            para = []
            while i < len(lines) and lines[i].strip() and not lines[i].startswith(("#", "|", ">", "- ")):
                para.append(lines[i])
                i += 1
            out.append(f"<p>{_inline(' '.join(para))}</p>")
    return "\n".join(out)


def _png(path: str | os.PathLike) -> str:
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def page(title: str, md: str, *, images: dict[str, str] | None = None, original: np.ndarray | None = None,
         errors: dict[str, np.ndarray] | None = None, kept: dict[str, np.ndarray] | None = None,
         bounds: np.ndarray | None = None) -> str:
    """The report page's HTML text.
    *title* (replaced by the Markdown's own ``# `` title line when there is one); *md* the report's Markdown;
    *images* PNG paths by caption; *original* (s, 3) the original's points shown; *errors* per label (a method in
    compare) their forward errors (s,), one view each; *kept* per label the kept points (k, 3), one view each;
    *bounds* (2, 3) the quantisation box (default: the original's)."""
    images, errors, kept = images or {}, errors or {}, kept or {}
    lines = md.splitlines()
    if lines and lines[0].startswith("# "):  # the Markdown's title: the page's
        title, md = lines[0][2:].strip(), "\n".join(lines[1:])
    parts = [f"<h1>{html.escape(title)}</h1>"]
    if original is not None and len(original):
        lo = np.asarray(bounds[0] if bounds is not None else original.min(0), dtype=np.float64)
        hi = np.asarray(bounds[1] if bounds is not None else original.max(0), dtype=np.float64)
        clouds, values, views = [{"n": len(original), "xyz": _b64(_quantise(original, lo, hi))}], [], []
        shown = [np.asarray(e, dtype=np.float64) for e in errors.values() if len(e)]
        top = max((float(np.percentile(e, TOP_PERCENTILE)) for e in shown), default=0.0)
        cells = []
        for label in dict.fromkeys([*errors, *kept]):  # per label (method): its error view, then its kept points
            if label in errors:
                err = np.asarray(errors[label], dtype=np.float64)
                t = np.clip(err / top, 0, 1) if top > 0 else np.zeros(len(err))
                values.append(_b64(np.rint(t * 255).astype(np.uint8)))
                views.append({"canvas": f"v{len(views)}", "cloud": 0, "values": len(values) - 1})
                cells.append(f"original ({len(original):,} points shown), coloured by the error to {label}")
            if label in kept:
                pts = kept[label]
                clouds.append({"n": len(pts), "xyz": _b64(_quantise(pts, lo, hi))})
                views.append({"canvas": f"v{len(views)}", "cloud": len(clouds) - 1, "values": None,
                              "colour": [0.1, 0.3, 0.6]})
                cells.append(f"{label}: kept points ({len(pts):,} shown)")
        data = {"bounds": [lo.tolist(), hi.tolist()], "clouds": clouds, "values": values, "views": views}
        parts.append("<h2>3D views</h2><p>Drag to rotate, wheel to zoom, shift-drag (or right-drag) to pan, "
                     "double click to reset; every view follows the same camera. Colour: the distance from each "
                     f"original point to the nearest kept point, red = 0 to blue = {top:.4g} (the "
                     f"{TOP_PERCENTILE:g}th percentile of the errors shown; larger errors are blue too).</p>"
                     "<div class='scale'></div><div class='views'>")
        for view, caption in zip(views, cells):
            parts.append(f"<div class='view'><canvas id='{view['canvas']}'></canvas>"
                         f"<div>{html.escape(caption)}</div></div>")
        parts.append("</div>")
        blob = json.dumps(data, separators=(",", ":")).replace("</", "<\\/")
        parts.append(f"<script type='application/json' id='cloudsieve-data'>{blob}</script>")
    parts.append(markdown_html(md))
    for caption, path in images.items():
        parts.append(f"<figure><img alt='{html.escape(caption)}' src='{_png(path)}'>"
                     f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    script = resources.files("cloudsieve.evaluate").joinpath("viewer.js").read_text(encoding="utf-8")
    body = "\n".join(parts)
    return (f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body>\n{body}\n<script>{script}</script>\n</body></html>\n")


def write_html(path: str | os.PathLike, title: str, md: str, **views) -> str:
    """Write :func:`page` to *path*; returns the path."""
    write_text(path, page(title, md, **views))
    return str(path)
