"""Render a report in headless Chromium and check what a reader sees (used by the test suite and for the docs'
screenshots): every image loads, no JavaScript or console error, and the visible text holds no raw Markdown or JSON.

Chromium (Debian package ``chromium``) is driven from its command line only, no extra Python package: a copy of the
page gets a small probe script that records load errors (``error`` events, ``console.error``) and, on ``load``,
writes the image states and the visible text (``document.body.innerText``, which omits collapsed ``<details>``)
into the DOM, which ``--dump-dom`` returns. ``--screenshot`` renders the original page.
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["chromium", "BrowserCheck", "check_report", "screenshot", "raw_markup"]

_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
          "--disable-background-networking", "--disable-component-update", "--disable-sync",
          "--hide-scrollbars", "--virtual-time-budget=10000"]

_PROBE = """<script>
window.__selfsense_errors = [];
window.addEventListener('error', function (e) {
  var t = e.target;
  window.__selfsense_errors.push(t && t.tagName ? t.tagName + ' failed to load: ' + String(t.src || t.href).slice(0, 80)
                                                 : 'error: ' + e.message);
}, true);
window.addEventListener('unhandledrejection', function (e) { window.__selfsense_errors.push('rejection: ' + e.reason); });
var __ce = console.error;
console.error = function () { window.__selfsense_errors.push('console.error: ' + Array.from(arguments).join(' '));
                              __ce.apply(console, arguments); };
window.addEventListener('load', function () {
  var imgs = Array.from(document.images);
  var r = {n_images: imgs.length,
           broken: imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); })
                       .map(function (i) { return (i.alt || i.src).slice(0, 80); }),
           sizes: imgs.map(function (i) { return [i.naturalWidth, i.naturalHeight]; }),
           errors: window.__selfsense_errors, text: document.body.innerText, title: document.title};
  var p = document.createElement('pre'); p.id = 'selfsense-probe'; p.hidden = true;
  p.textContent = JSON.stringify(r); document.body.appendChild(p);
});
</script>"""


def chromium() -> str | None:
    """Path of a Chromium executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        p = shutil.which(name)
        if p:
            return p
    return None


@dataclass
class BrowserCheck:
    """What headless Chromium saw of a page."""

    n_images: int
    broken_images: list[str]
    errors: list[str]
    text: str
    title: str
    console: list[str] = field(default_factory=list)  # console messages Chromium logged on stderr

    @property
    def raw_markup(self) -> list[str]:
        return raw_markup(self.text)


#: patterns of raw Markdown / JSON in visible text (one per line)
_RAW = [
    (re.compile(r"^#{1,6}\s"), "Markdown heading"),
    (re.compile(r"^\|.*\|\s*$"), "Markdown table row"),
    (re.compile(r"^\s*\|?\s*:?-{3,}:?\s*\|"), "Markdown table rule"),
    (re.compile(r"\*\*[^*]+\*\*"), "Markdown bold"),
    (re.compile(r"`[^`]+`"), "Markdown code span"),
    (re.compile(r"^```"), "Markdown code fence"),
    (re.compile(r"^\s*[\[{]\s*\"[^\"]+\"\s*:"), "JSON object"),
    (re.compile(r"\"[A-Za-z_]+\"\s*:\s*[\[{\"0-9tfn-]"), "JSON key"),
]


def raw_markup(text: str) -> list[str]:
    """Lines of visible text that look like raw Markdown or JSON, with what they look like."""
    found = []
    for line in text.splitlines():
        for pat, what in _RAW:
            if pat.search(line):
                found.append(f"{what}: {line.strip()[:120]}")
                break
    return found


def _run(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    exe = chromium()
    if exe is None:
        raise FileNotFoundError(2, "Chromium not found (Debian: apt-get install -y chromium)", "chromium")
    with tempfile.TemporaryDirectory(prefix="selfsense-chromium-") as ud:
        return subprocess.run([exe, *_FLAGS, f"--user-data-dir={ud}", "--enable-logging=stderr", "--v=0", *args],
                              capture_output=True, text=True, timeout=timeout)


def check_report(html_path: str | Path, timeout: float = 120.0) -> BrowserCheck:
    """Load ``html_path`` (a copy with the probe script) in headless Chromium; return what it saw."""
    src = Path(html_path).read_text(encoding="utf-8")
    probe = re.sub(r"(<head[^>]*>)", lambda m: m.group(1) + _PROBE, src, count=1, flags=re.I)
    if probe == src:
        probe = _PROBE + src
    with tempfile.TemporaryDirectory(prefix="selfsense-probe-") as tmp:
        page = Path(tmp) / "probe.html"
        page.write_text(probe, encoding="utf-8")
        proc = _run(["--dump-dom", page.as_uri()], timeout)
    m = re.search(r'<pre id="selfsense-probe"[^>]*>(.*?)</pre>', proc.stdout, flags=re.S)
    if m is None:
        raise RuntimeError(f"Chromium did not finish loading {html_path} (exit {proc.returncode}): "
                           + " ".join(proc.stderr.split()[-30:]))
    import html as _html

    r = json.loads(_html.unescape(m.group(1)))
    console = [ln for ln in proc.stderr.splitlines() if "CONSOLE" in ln]
    return BrowserCheck(r["n_images"], r["broken"], r["errors"], r["text"], r["title"], console)


def screenshot(html_path: str | Path, png: str | Path, width: int = 1200, height: int = 2400,
               timeout: float = 120.0) -> Path:
    """Render ``html_path`` in headless Chromium into ``png`` (``width`` x ``height`` CSS pixels from the top)."""
    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    proc = _run([f"--window-size={width},{height}", f"--screenshot={png.resolve()}", Path(html_path).resolve().as_uri()],
                timeout)
    if not png.exists() or png.stat().st_size == 0:
        raise RuntimeError(f"Chromium wrote no screenshot of {html_path} (exit {proc.returncode})")
    return png
