"""``staggered view`` pages in a real browser (Debian's chromium through
Playwright, WebGL in SwiftShader): every dev BVH and C3D, and documents
compared with their sources.  Skipped, with the reason, where no browser
can run; ``make test-browser`` installs one and makes them required."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import staggered_cli as st
from tests.browser import chrome
from tests.conftest import BVH_FILES, C3D_FILES, dev_document, dev_motion, staggered_warnings

pytestmark = pytest.mark.browser

WHY_NOT = chrome.why_not()
if WHY_NOT and chrome.REQUIRED:
    raise RuntimeError(f"STAGGERED_BROWSER_REQUIRED=1 but {WHY_NOT}")
if WHY_NOT:
    pytest.skip(WHY_NOT, allow_module_level=True)
if not BVH_FILES:
    pytest.skip("no dev mocap in ../shared/mocap", allow_module_level=True)

BLUE, ORANGE = "#1f5fbf", "#e0701a"  # the first and second figures' colours in page.js


@pytest.fixture(scope="module")
def page():
    with chrome.browser() as b:
        p = b.new_page(viewport=chrome.VIEWPORT)
        yield p
        p.close()


@pytest.fixture(scope="module")
def pages(tmp_path_factory):
    return tmp_path_factory.mktemp("view")


def _write(folder, name: str, html: str):
    path = folder / name
    path.write_text(html, encoding="utf-8")
    return path


def _seen_times(motion) -> tuple[float, float]:
    """Two times, 40 % of the clip apart, at which the figure is seen whole
    (a C3D's markers: frames with most of them; a BVH: any)."""
    if hasattr(motion, "skeleton"):
        frames = np.arange(motion.n_frames)
    else:
        seen = np.isfinite(motion.points).all(axis=2).sum(axis=1)
        frames = np.flatnonzero(seen >= 0.8 * seen.max())
    a, b = frames[int(0.3 * (len(frames) - 1))], frames[int(0.7 * (len(frames) - 1))]
    return float(a * motion.frame_time), float(b * motion.frame_time)


def _bbox(mask):
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return rows[0], rows[-1], cols[0], cols[-1]


def _check_figure(rgb, colour=BLUE):
    """The figure's drawn pixels: enough of them, a figure's height of the
    view (not a dot, not filling it), and inside it (framed, not off screen)."""
    mask = chrome.colour_mask(rgb, colour)
    h, w = mask.shape
    assert mask.sum() > 150, f"only {mask.sum()} pixels of the figure drawn"
    top, bottom, left, right = _bbox(mask)
    assert 0.15 * h < bottom - top < 0.95 * h, f"figure {bottom - top} px tall in a {h} px view"
    centre_x, centre_y = (left + right) / 2, (top + bottom) / 2
    assert 0.2 * w < centre_x < 0.8 * w and 0.15 * h < centre_y < 0.85 * h, "figure not framed"
    return mask


def _set_hash(page, fragment: str, expect_t: float):
    page.evaluate(f"location.hash = {fragment!r}")
    page.wait_for_function(f"Math.abs(window.staggeredView.state.t - {expect_t}) < 1e-6")
    page.evaluate("new Promise((ok) => requestAnimationFrame(() => requestAnimationFrame(ok)))")


@pytest.mark.parametrize("name", BVH_FILES + C3D_FILES)
def test_every_dev_file_plays_offline(page, pages, name):
    motion = dev_motion(name)
    path = _write(pages, f"{name}.html", st.view(motion, name=name))
    t1, t2 = _seen_times(motion)
    visit = chrome.open_page(page, path, f"t={t1:.6f}")
    assert visit.seconds_to_ready <= 10.0
    assert not visit.errors, visit.errors
    assert not visit.foreign, visit.foreign
    assert page.evaluate("window.staggeredView.state.playing") is False  # a fragment opens it paused
    first = chrome.scene_pixels(page)
    m1 = _check_figure(first)
    _set_hash(page, f"#t={t2:.6f}", round(t2, 6))
    second = chrome.scene_pixels(page)
    m2 = _check_figure(second)
    top, bottom, left, right = _bbox(m1 | m2)
    region = np.abs(first.astype(int) - second.astype(int)).sum(axis=2)[top : bottom + 1, left : right + 1] > 30
    assert region.sum() > 100, f"the figure at {t1:.2f} s and {t2:.2f} s differs in {region.sum()} pixels"
    assert not visit.errors, visit.errors


DOCS = [n for n in ("cmu_02_01_walk.bvh", "c3dorg_sample01_Eb015pi_walk.c3d") if n in BVH_FILES + C3D_FILES]


def _edited(doc):
    """The document with one pose exaggerated: it differs from its source there."""
    k = doc.n_poses // 2
    return st.edit_pose(doc, k, exaggerate=2.0, relative_to="average"), k


@pytest.mark.parametrize("name", DOCS)
def test_document_compared_with_its_source(page, pages, name):
    doc, k = _edited(dev_document(name))
    with staggered_warnings():  # (the contact layer may hold a foot the edit moved: it says so)
        html = st.view(doc, compare=dev_motion(name), name="edited", compare_names=[name])
    meta = json.loads(re.search(r'id="staggered-meta">(.*?)</script>', html, re.S).group(1))
    pose_t = meta["timing"]["pose_t"]
    path = _write(pages, f"{name}.compare.html", html)
    visit = chrome.open_page(page, path, f"pose={k}")
    assert visit.seconds_to_ready <= 10.0 and not visit.errors and not visit.foreign, (visit.errors, visit.foreign)
    # #pose=K opens paused at pose K's time, and says so
    assert page.evaluate("window.staggeredView.state.t") == pytest.approx(pose_t[k], abs=1e-9)
    assert f"at pose {k} of {len(pose_t)}" in page.locator("#clock").inner_text()
    # two figures in two colours, with a legend
    rgb = chrome.scene_pixels(page)
    at_k = _check_figure(rgb, BLUE)
    orange = chrome.colour_mask(rgb, ORANGE)
    assert orange.sum() > 40, f"the compared figure shows in {orange.sum()} pixels"
    assert page.locator("#legend .swatch").count() == 2
    assert "edited" in page.locator("#legend").inner_text() and name in page.locator("#legend").inner_text()
    # another pose draws another figure, inside the same framing
    _set_hash(page, f"#pose={k + 2}", pose_t[k + 2])
    other = chrome.scene_pixels(page)
    top, bottom, left, right = _bbox(at_k | _check_figure(other, BLUE))
    moved = np.abs(rgb.astype(int) - other.astype(int)).sum(axis=2)[top : bottom + 1, left : right + 1] > 30
    assert moved.sum() > 100
    # a point's name on hover
    labels = meta["figures"][0]["labels"]
    spots = page.evaluate(f"[...Array({len(labels)}).keys()].map((p) => window.staggeredView.screenOf(0, p))")
    xy = np.array([[s["x"], s["y"]] if s else [np.nan, np.nan] for s in spots])
    gap = np.linalg.norm(xy[:, None] - xy[None], axis=-1) + np.diag(np.full(len(xy), np.inf))
    p = int(np.nanargmax(np.where(np.isfinite(xy[:, 0]), np.nanmin(gap, axis=1), -1)))  # the most isolated point
    where = spots[p]
    box = page.locator("#scene").bounding_box()
    page.mouse.move(box["x"] + where["x"], box["y"] + where["y"])
    page.wait_for_function("!document.getElementById('tip').hidden")
    assert page.locator("#tip").inner_text().startswith(labels[p])
    page.mouse.move(0, 0)
    _set_hash(page, f"#pose={k}", pose_t[k])
    # the timing strip is drawn, with the poses of the timeline
    assert page.locator("#strip").is_visible() and page.locator("#strip").bounding_box()["height"] > 60
    # keys: ] and [ step through the poses, arrows a frame, space plays
    page.keyboard.press("]")
    assert page.evaluate("window.staggeredView.state.t") == pytest.approx(pose_t[k + 1], abs=1e-9)
    page.keyboard.press("[")
    page.keyboard.press("[")
    assert page.evaluate("window.staggeredView.state.t") == pytest.approx(pose_t[k - 1], abs=1e-9)
    page.keyboard.press("ArrowRight")
    ft = meta["figures"][0]["frame_time"]
    frame = round(pose_t[k - 1] / ft) + 1
    assert page.evaluate("window.staggeredView.state.t") == pytest.approx(frame * ft, abs=1e-9)
    page.keyboard.press(" ")
    assert page.evaluate("window.staggeredView.state.playing") is True
    page.keyboard.press(" ")
    # a click on a pose of the strip jumps to it
    _set_hash(page, "#t=0", 0.0)
    box = page.locator("#strip").bounding_box()
    x = page.evaluate(f"window.staggeredView.stripX({pose_t[2]})")
    page.mouse.click(box["x"] + x, box["y"] + box["height"] / 2)
    assert page.evaluate("window.staggeredView.state.t") == pytest.approx(pose_t[2], abs=1e-9)
    assert not visit.errors, visit.errors


@pytest.mark.skipif("cmu_02_01_walk.bvh" not in BVH_FILES, reason="no CMU 02_01 in ../shared/mocap")
def test_a_partial_pose_opens_named_and_marked(page, pages):
    doc = st.cull(dev_document("cmu_02_01_walk.bvh"), add_time=0.5, part="@left-arm")
    k = doc.pose_part.index("@left-arm")
    path = _write(pages, "partial.html", st.view(doc, name="partial"))
    visit = chrome.open_page(page, path, f"pose={k}")
    assert not visit.errors, visit.errors
    assert page.evaluate("window.staggeredView.state.t") == pytest.approx(float(doc.pose_t[k]), abs=1e-6)
    assert f"at pose {k} (@left-arm) of {doc.n_poses}" in page.inner_text("#clock")
    _check_figure(chrome.scene_pixels(page))
    # the dope sheet draws the partial pose's line in its own colour (page.js
    # PARTIAL); away from it, so that the current time's line does not cover it
    _set_hash(page, "#t=0", 0.0)
    import io

    from PIL import Image

    strip = np.asarray(Image.open(io.BytesIO(page.locator("#strip").screenshot())).convert("RGB")).astype(int)
    purple = (np.abs(strip - np.array([0x7B, 0x4F, 0xA0])) < 40).all(axis=2)
    assert purple.sum() > 60, f"{purple.sum()} pixels of the partial pose's line"


@pytest.mark.skipif(not chrome.REQUIRED, reason="the one-hour page (263 MB, a minute) runs under make test-browser")
@pytest.mark.skipif("cmu_01_01_forward_jumps.bvh" not in BVH_FILES, reason="no CMU 01_01 in ../shared/mocap")
def test_one_hour_clip_at_120_hz_of_31_joints_loads(page, pages):
    """Issue 35: an hour at 120 Hz of a 31-joint skeleton (CMU 01_01 tiled)
    gives a page that loads and plays (bench/bench_view.py measures it)."""
    from staggered_cli.io.page import page_pieces
    from staggered_cli.viewer import page_data

    clip = dev_motion("cmu_01_01_forward_jumps.bvh")
    frames = round(3600 / clip.frame_time)
    hour = clip.with_channels(np.tile(clip.channels, (-(-frames // clip.n_frames), 1))[:frames], same_text=False)
    assert hour.skeleton.n_joints == 31 and hour.n_frames * hour.frame_time >= 3600
    meta, blobs = page_data(hour, names=("one hour",))
    path = pages / "hour.html"
    with open(path, "wb") as f:
        for piece in page_pieces(meta, blobs):
            f.write(piece)
    del blobs
    assert path.stat().st_size < 4.5e6 * 60 + 2e6  # about 4.4 MB a minute (38 points, float32, base64)
    visit = chrome.open_page(page, path, "t=1800", timeout=60.0)
    assert not visit.errors and not visit.foreign, (visit.errors, visit.foreign)
    assert page.evaluate("window.staggeredView.state.t") == 1800
    _check_figure(chrome.scene_pixels(page))
    path.unlink()
