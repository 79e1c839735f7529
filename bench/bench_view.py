"""Size and load time of ``staggered view`` pages (issue 35).

1. Every dev file of ../shared/mocap (and the biggest one's document
   compared with its source): page bytes, bytes per minute of motion,
   seconds to write the page, and seconds from opening it in chromium to
   ``document.body.dataset.ready == "1"``.
2. A one-hour clip at 120 Hz of a 31-joint skeleton: CMU 01_01 (31 joints,
   7 End Sites, 120 Hz) tiled to 3600 s; the same numbers.

The browser is Debian's chromium through Playwright with WebGL in
SwiftShader (see tests/browser/chrome.py); without it the load times are
left out.

    python bench/bench_view.py [--hours 1.0] [--no-browser]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MOCAP = ROOT.parent / "shared" / "mocap"
sys.path.insert(0, str(ROOT))

LONG_SOURCE = "cmu_01_01_forward_jumps.bvh"


def _load_seconds(path: Path, browser) -> float:
    from tests.browser import chrome

    page = browser.new_page(viewport=chrome.VIEWPORT)
    try:
        visit = chrome.open_page(page, path, "t=1", timeout=300.0)
        if visit.errors:
            raise RuntimeError(f"{path.name}: {visit.errors}")
        return visit.seconds_to_ready
    finally:
        page.close()


def _row(label: str, html: str, seconds_write: float, minutes: float, path: Path, browser) -> None:
    size = len(html.encode("utf-8"))
    path.write_text(html, encoding="utf-8")
    load = f"{_load_seconds(path, browser):8.2f}" if browser is not None else "     n/a"
    print(f"{label:44s} {size / 1e6:9.2f} {size / max(minutes, 1e-9) / 1e6:9.2f} {seconds_write:8.2f} {load}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0, help="length of the generated clip [1.0]")
    ap.add_argument("--no-browser", action="store_true", help="sizes only")
    args = ap.parse_args()

    import staggered_cli as st
    from tests.browser import chrome

    why = None if not args.no_browser else "--no-browser"
    why = why or chrome.why_not()
    if why:
        print(f"(no load times: {why})")
    print(f"{'page':44s} {'MB':>9s} {'MB/min':>9s} {'write s':>8s} {'ready s':>8s}")
    with tempfile.TemporaryDirectory() as tmp:
        ctx = chrome.browser() if why is None else None
        browser = ctx.__enter__() if ctx is not None else None
        try:
            for path in sorted(MOCAP.glob("*.bvh")) + sorted(MOCAP.glob("*.c3d")):
                clip = st.read(path)
                t = time.perf_counter()
                html = st.view(clip)
                minutes = clip.n_frames * clip.frame_time / 60
                _row(path.name, html, time.perf_counter() - t, minutes, Path(tmp) / "p.html", browser)
            long_clip = st.read(MOCAP / LONG_SOURCE)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", st.StaggeredWarning)
                doc = st.extract(long_clip)
                t = time.perf_counter()
                html = st.view(doc, compare=long_clip)
            minutes = long_clip.n_frames * long_clip.frame_time / 60
            seconds = time.perf_counter() - t
            _row(f"{LONG_SOURCE} document --compare", html, seconds, minutes, Path(tmp) / "d.html", browser)
            # the one-hour clip: the jumps tiled (a jump in the root's path at each seam; it is the size that counts)
            frames = int(round(args.hours * 3600 / long_clip.frame_time))
            reps = -(-frames // long_clip.n_frames)
            channels = np.tile(long_clip.channels, (reps, 1))[:frames]
            hour = long_clip.with_channels(channels, same_text=False)
            del channels
            t = time.perf_counter()
            html = st.view(hour, name=f"{args.hours:g} h at 120 Hz, 31 joints")
            label = f"{args.hours:g} h, 120 Hz, {hour.skeleton.n_joints} joints ({frames} frames)"
            _row(label, html, time.perf_counter() - t, frames * hour.frame_time / 60, Path(tmp) / "h.html", browser)
        finally:
            if ctx is not None:
                ctx.__exit__(None, None, None)


if __name__ == "__main__":
    main()
