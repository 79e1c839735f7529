"""Debian's chromium driven by Playwright for Python, for the pages of
``staggered view`` (tests/browser, ``make screenshots``, bench/bench_view.py).

No browser is downloaded: Playwright launches the system chromium
(``apt-get install -y chromium``) with SwiftShader for WebGL, so that the
page draws the same without a GPU.  :func:`why_not` says why no browser
can run here (the tests skip with it, or fail under ``make test-browser``,
which sets ``STAGGERED_BROWSER_REQUIRED=1``).
"""

from __future__ import annotations

import io
import os
import shutil
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

#: Flags for WebGL in software (no GPU here, nor in CI).
ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
#: ``make test-browser`` sets it: a missing browser fails the tests instead of skipping them.
REQUIRED = os.environ.get("STAGGERED_BROWSER_REQUIRED") == "1"
#: Size of the window the pages are opened in (CSS pixels).
VIEWPORT = {"width": 1200, "height": 800}


def chromium_path() -> str | None:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    return found or next((p for p in ("/usr/bin/chromium", "/usr/lib/chromium/chromium") if Path(p).exists()), None)


def why_not() -> str | None:
    """Why no browser can run the tests here, or None."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "Playwright for Python is not installed (make test-browser installs it)"
    if chromium_path() is None:
        return "no chromium found (make test-browser installs it: apt-get install -y chromium)"
    return None


@contextmanager
def browser():
    """A headless chromium (closed on exit)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium_path(), args=ARGS)
        try:
            yield b
        finally:
            b.close()


@dataclass
class Visit:
    """What a page did: its console errors, uncaught errors and every URL it asked for."""

    errors: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)
    seconds_to_ready: float = float("nan")

    @property
    def foreign(self) -> list[str]:
        """Requests that are neither ``file:`` nor ``data:``."""
        return [u for u in self.requests if not u.startswith(("file:", "data:"))]


def open_page(page, path: Path, fragment: str = "", timeout: float = 10.0) -> Visit:
    """Open ``path`` (with ``#fragment``) in ``page`` and wait until the page
    says it drew (``document.body.dataset.ready == "1"``)."""
    visit = Visit()
    page.remove_listener("console", getattr(page, "_staggered_console", lambda m: None))
    page.remove_listener("pageerror", getattr(page, "_staggered_error", lambda e: None))
    page.remove_listener("request", getattr(page, "_staggered_request", lambda r: None))

    def console(m):
        if m.type == "error":
            visit.errors.append(m.text)

    page._staggered_console = console
    page._staggered_error = lambda e: visit.errors.append(str(e))
    page._staggered_request = lambda r: visit.requests.append(r.url)
    page.on("console", page._staggered_console)
    page.on("pageerror", page._staggered_error)
    page.on("request", page._staggered_request)
    url = Path(path).resolve().as_uri() + (f"#{fragment}" if fragment else "")
    start = time.perf_counter()
    page.goto(url, wait_until="commit", timeout=timeout * 1000 * 6)
    page.wait_for_function("document.body && document.body.dataset.ready === '1'", timeout=timeout * 1000)
    visit.seconds_to_ready = time.perf_counter() - start
    return visit


def scene_pixels(page):
    """The 3D view as an (H, W, 3) uint8 array."""
    import numpy as np
    from PIL import Image

    png = page.locator("#scene").screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def colour_mask(rgb, colour: str):
    """Pixels drawn in ``colour`` (a figure's: '#1f5fbf' blue, '#e0701a'
    orange, or their lighter left side), not the grey grid or background."""
    px = rgb.astype(int)
    r, g, b = px[..., 0], px[..., 1], px[..., 2]
    if colour == "#1f5fbf":
        return (b - r > 45) & (b - g > 25)
    if colour == "#e0701a":
        return (r - b > 60) & (r - g > 25)
    raise ValueError(colour)
