"""``make screenshots``: the README's picture of ``staggered view``,
docs/pictures/view.png, taken in the browser the tests use (regenerated on
purpose only: review it before committing).

The CMU walk (cmu_02_01, ../shared/mocap) extracted, its arms loosened
with succession and one pose exaggerated, compared with the capture,
opened at that pose.

    .venv/bin/python -m tests.browser.screenshot [OUT.png]
"""

from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path

import staggered_cli as st
from tests.browser import chrome
from tests.conftest import dev_motion

NAME = "cmu_02_01_walk.bvh"


def main(out: str = "docs/pictures/view.png") -> None:
    why = chrome.why_not()
    if why:
        raise SystemExit(f"screenshot: {why}")
    clip = dev_motion(NAME)
    k = 6
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", st.StaggeredWarning)  # (notes on the steep time warp, the contact layer)
        doc = st.extract(clip)
        for arm in ("LeftArm", "RightArm"):
            doc = st.succession(doc, offset=0.04, power=1.5, joint=arm, clamp=True)
        doc = st.edit_pose(doc, k, exaggerate=1.8, relative_to="average")
        html = st.view(doc, compare=clip, name="walk_edited.stag", compare_names=[NAME])
    with tempfile.TemporaryDirectory() as tmp, chrome.browser() as b:
        page = Path(tmp) / "view.html"
        page.write_text(html, encoding="utf-8")
        p = b.new_page(viewport={"width": 1100, "height": 700})
        chrome.open_page(p, page, f"pose={k}")
        p.evaluate("new Promise((ok) => requestAnimationFrame(() => requestAnimationFrame(ok)))")
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        p.screenshot(path=out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(*sys.argv[1:2])
