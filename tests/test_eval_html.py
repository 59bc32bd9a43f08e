"""report.html: self-contained, offline, and rendered by a real browser (headless Chromium)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_file

from cloudsieve.cli import main
from cloudsieve.evaluate.html import VIEW_POINTS, markdown_html, page, view_sample
from cloudsieve.io import open_writer, read_cloud

CHROMIUM = Path("/usr/bin/chromium")
needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(),
                                    reason="headless tests need Debian's chromium at /usr/bin/chromium (setup.sh)")
_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
          "--disable-component-update", "--disable-sync", "--no-first-run", "--hide-scrollbars"]


def _chromium(tmp: Path, url: str, *args: str) -> subprocess.CompletedProcess:
    profile = tmp / f"profile{len(list(tmp.glob('profile*')))}"
    return subprocess.run([str(CHROMIUM), *_FLAGS, f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
                           *args, url], capture_output=True, text=True, timeout=120, check=False)


def _js_errors(stderr: str) -> list[str]:
    """Console lines of uncaught JavaScript errors or failed loads (Chromium's own warnings are not)."""
    return [line for line in stderr.splitlines() if ":CONSOLE" in line
            and re.search(r"Uncaught|Error:|ERR_|Failed to load", line) and "WebGL" not in line]


def _write(path: Path, xyz: np.ndarray) -> Path:
    with open_writer(path, header={}, dtypes={"xyz": (np.dtype("float64"), (3,))}, format="ply") as w:
        w.write({"xyz": xyz})
    return path


@pytest.fixture(scope="module")
def bunny_report(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("html")
    xyz, _ = read_cloud(shared_file("bun_zipper.ply"))
    simp = _write(tmp / "s.ply", xyz[::5])
    out = tmp / "rep"
    assert main(["evaluate", str(shared_file("bun_zipper.ply")), str(simp), "--no-surface", "--no-progress",
                 "--report", str(out)]) == 0
    return out / "report.html"


def test_the_page_is_self_contained(bunny_report):
    text = bunny_report.read_text()
    assert not re.search(r"(src|href)\s*=\s*['\"]?(https?:)?//", text), "the page fetches something"
    assert "http://" not in text.replace("http://www.w3.org", "") and "https://" not in text
    assert "id='cloudsieve-data'" in text and text.count("<canvas id=") == 2
    assert "data:image/png;base64," in text and "| D1 |" not in text and "<th>forward PSNR (dB)</th>" in text
    assert bunny_report.stat().st_size < 2_000_000


@needs_chromium
def test_chromium_renders_the_views_without_errors(bunny_report, tmp_path):
    url = bunny_report.as_uri()
    dom = _chromium(tmp_path, url, "--dump-dom", "--virtual-time-budget=5000")
    assert dom.returncode == 0, dom.stderr[-2000:]
    body = re.search(r"<body[^>]*>", dom.stdout).group(0)
    assert re.search(r'data-rendered="(webgl|2d)"', body), body
    assert "data-errors" not in body, body
    assert dom.stdout.count("<canvas id=") == 2
    assert _js_errors(dom.stderr) == []
    shot = tmp_path / "shot.png"
    run = _chromium(tmp_path, url, f"--screenshot={shot}", "--window-size=1200,800", "--virtual-time-budget=5000")
    assert run.returncode == 0 and shot.exists(), run.stderr[-2000:]
    assert _js_errors(run.stderr) == []
    colours, coloured = _canvas_pixels(shot)
    assert len(colours) > 20 and coloured > 0.01, (len(colours), coloured)
    # the same page without the viewer: the same region holds no coloured pixel (the points came from the viewer)
    text = bunny_report.read_text()
    start = text.rindex("<script>")
    bare = tmp_path / "bare.html"
    bare.write_text(text[:start] + text[text.index("</script>", start) + len("</script>"):])
    blank = tmp_path / "blank.png"
    _chromium(tmp_path, bare.as_uri(), f"--screenshot={blank}", "--window-size=1200,800")
    assert _canvas_pixels(blank)[1] < 0.001


def _canvas_pixels(png: Path) -> tuple[np.ndarray, float]:
    """Distinct colours and share of saturated pixels in the first canvas's area (left half, y 260-560 of 800)."""
    import matplotlib.image

    img = matplotlib.image.imread(png)[..., :3]
    region = (img[260:560, 40:560] * 255).astype(np.uint8).reshape(-1, 3)
    saturated = region.max(axis=1).astype(int) - region.min(axis=1) > 60
    return np.unique(region, axis=0), float(saturated.mean())


def test_markdown_tables_become_html():
    out = markdown_html("# T\n\ntext `a<b`\n\n| x | y |\n|---|---:|\n| 1 | 2 |\n\n> note\n\n- one\n- two\n")
    assert out == ("<h2>T</h2>\n<p>text <code>a&lt;b</code></p>\n<table><tr><th>x</th><th>y</th></tr><tr><td>1</td>"
                   "<td>2</td></tr></table>\n<blockquote>note</blockquote>\n<ul><li>one</li><li>two</li></ul>")


def test_views_are_bounded_and_compare_shares_the_positions():
    rng = np.random.default_rng(0)
    big = rng.random((VIEW_POINTS + 5000, 3))
    idx = view_sample(len(big))
    assert len(idx) == VIEW_POINTS and np.all(np.diff(idx) > 0)
    orig = big[idx]
    html = page("t", "# t\n", original=orig, errors={"a": rng.random(len(orig)), "b": rng.random(len(orig))},
                kept={"a": orig[:1000], "b": orig[:2000]})
    assert html.count("<canvas id=") == 4
    assert len(html) < 2.2e6  # one position array for both methods' error views: ~1.6 MB + 2 x 0.27 MB


@needs_chromium
def test_the_check_sees_a_javascript_error(bunny_report, tmp_path):
    broken = tmp_path / "broken.html"
    broken.write_text(bunny_report.read_text().replace('"use strict";', '"use strict"; null.x;', 1))
    dom = _chromium(tmp_path, broken.as_uri(), "--dump-dom", "--virtual-time-budget=5000")
    assert _js_errors(dom.stderr), dom.stderr[-2000:]
    assert "data-rendered" not in re.search(r"<body[^>]*>", dom.stdout).group(0)


@needs_chromium
def test_compare_report_shows_the_methods_side_by_side(tmp_path):
    from cloudsieve.evaluate import compare

    xyz, _ = read_cloud(shared_file("bun_zipper.ply"))
    res = compare(xyz[::3], methods=["random", "voxel"], ratio=0.2, surface=False, report_dir=tmp_path / "cmp")
    page_path = Path(res["files"]["html"])
    text = page_path.read_text()
    assert text.count("<canvas id=") == 4 and "coloured by the error to voxel" in text and "voxel: kept points" in text
    assert "<th>D1 PSNR</th>" in text
    dom = _chromium(tmp_path, page_path.as_uri(), "--dump-dom", "--virtual-time-budget=5000")
    body = re.search(r"<body[^>]*>", dom.stdout).group(0)
    assert re.search(r'data-rendered="(webgl|2d)"', body) and "data-errors" not in body, body
    assert _js_errors(dom.stderr) == []


def test_a_page_at_the_view_limit_stays_small():
    rng = np.random.default_rng(1)
    pts = rng.random((VIEW_POINTS, 3)) * [100, 100, 5] + 4e5  # survey-like coordinates
    text = page("t", "# t\n", original=pts, errors={"s": rng.random(VIEW_POINTS)}, kept={"s": pts})
    assert len(text) < 3_600_000  # 2 x 200 k points x 6 bytes + 200 k error bytes, base64: 3.5 MB


_INTERACT = """<script>
// waits (polling timers, which the virtual time budget runs) for the first frame, drags, then wheels
function poll(test, then, tries) {
  if (test() || tries <= 0) then(test()); else setTimeout(function () { poll(test, then, tries - 1); }, 50);
}
poll(function () { return !!document.body.dataset.rendered; }, function () {
  var c = document.getElementById("v0"), before = c.toDataURL(), r = c.getBoundingClientRect();
  function at(type, dx, dy) {
    var e = new MouseEvent(type, {clientX: r.left + 100 + dx, clientY: r.top + 100 + dy, bubbles: true, button: 0});
    (type === "mousedown" ? c : window).dispatchEvent(e);
  }
  at("mousedown", 0, 0); at("mousemove", 60, 20); at("mouseup", 60, 20);
  poll(function () { return c.toDataURL() !== before; }, function (rotated) {
    document.body.dataset.rotated = String(rotated);
    var turned = c.toDataURL();
    c.dispatchEvent(new WheelEvent("wheel", {deltaY: -400, bubbles: true, cancelable: true}));
    poll(function () { return c.toDataURL() !== turned; }, function (zoomed) {
      document.body.dataset.zoomed = String(zoomed);
    }, 100);
  }, 100);
}, 100);
</script></body>"""


@needs_chromium
def test_dragging_rotates_and_the_wheel_zooms(bunny_report, tmp_path):
    probe = tmp_path / "probe.html"
    probe.write_text(bunny_report.read_text().replace("</body>", _INTERACT))
    dom = _chromium(tmp_path, probe.as_uri(), "--dump-dom", "--virtual-time-budget=30000")
    body = re.search(r"<body[^>]*>", dom.stdout).group(0)
    assert 'data-rotated="true"' in body and 'data-zoomed="true"' in body, body
    assert "data-errors" not in body and _js_errors(dom.stderr) == []
