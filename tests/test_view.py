"""``staggered view`` without a browser: the data the page plays (points in
metres with Y up, the same numbers as forward kinematics; the staggered
timing as the dope sheet has it), the page's make-up (no network address
it could ask for, the motion as packed float32), the vendored three.js
against its record, and bad input.  tests/browser/ opens the pages."""

from __future__ import annotations

import base64
import hashlib
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import staggered_cli as st
from staggered_cli.cli.main import cli
from staggered_cli.io.gltf import unit_scale_for, up_turn
from staggered_cli.io.page import BLOB_PIECE, asset
from staggered_cli.viewer import figure, page_data, timing
from tests.browser import chrome
from tests.conftest import BVH_FILES, C3D_FILES, dev_document, dev_motion

ROOT = Path(__file__).resolve().parents[1]
VENDOR = ROOT / "staggered_cli" / "viewer" / "vendor"
TOOLS = ROOT / "tools" / "view"
SAMPLE = ROOT / "data" / "samples" / "march.bvh"


def _meta(html: str) -> dict:
    return json.loads(re.search(r'id="staggered-meta">(.*?)</script>', html, re.S).group(1))


def _blob(html: str, i: int) -> np.ndarray:
    text = "".join(re.findall(rf'<script type="application/octet-stream" data-figure="{i}">(.*?)</script>', html, re.S))
    return np.frombuffer(base64.b64decode(text), dtype="<f4")


# --------------------------------------------------------------------------- the figures


@pytest.mark.parametrize("name", BVH_FILES)
def test_bvh_points_are_forward_kinematics_in_metres_y_up(name):
    clip = dev_motion(name)
    fig = figure(clip, name)
    T = clip.n_frames
    assert fig.points.dtype == np.float32 and fig.points.shape[0] == T and fig.kind == "skeleton"
    # the first point is the body's root joint: its world position, scaled and turned
    scale = unit_scale_for(clip)[0]
    wp = clip.world_positions()
    body_root = fig.labels[0]
    j = clip.skeleton.names.index(body_root)
    turn = up_turn(np.array([0.0, 1.0, 0.0]))  # every dev BVH is Y up
    np.testing.assert_allclose(fig.points[:, 0], (wp[:, j] @ turn.T) * scale, rtol=1e-6, atol=1e-5)
    # a person's height in metres, standing on the floor the page draws
    top = np.nanmax(fig.points[..., 1], axis=1) - fig.floor
    assert 1.0 < np.median(top) < 2.2, np.median(top)
    low = np.nanmin(fig.points[..., 1], axis=1)
    assert np.percentile(low, 50) - fig.floor < 0.25  # the lowest point rests near the floor most of the time
    # every bone joins two points of the figure, and none is longer than a body
    assert fig.bones.min() >= 0 and fig.bones.max() < fig.points.shape[1]
    length = np.linalg.norm(fig.points[:, fig.bones[:, 0]] - fig.points[:, fig.bones[:, 1]], axis=-1)
    assert np.nanmax(length) < 1.0


@pytest.mark.parametrize("name", C3D_FILES)
def test_c3d_markers_turn_z_up_millimetres_into_y_up_metres(name):
    clip = dev_motion(name)
    fig = figure(clip, name)
    assert fig.kind == "markers" and fig.labels == tuple(clip.labels)
    assert clip.units.strip().lower() == "mm"
    seen = np.isfinite(clip.points).all(axis=2)
    assert (np.isnan(fig.points).any(axis=2) == ~seen).all()  # gaps stay gaps (the page hides them)
    most = seen.sum(axis=1) >= 0.8 * seen.sum(axis=1).max()  # frames with most markers seen
    pts, page = clip.points[most], fig.points[most]
    height = np.nanmax(page[..., 1], axis=1) - fig.floor
    assert 0.8 < np.median(height) < 2.2  # metres (c3d.org's walker is 0.9 m tall)
    # the file's up axis became Y: the page's vertical extent is the file's largest
    ext_file = np.median(np.nanmax(pts, axis=1) - np.nanmin(pts, axis=1), axis=0)
    ext_page = np.median(np.nanmax(page, axis=1) - np.nanmin(page, axis=1), axis=0)
    assert ext_page[1] == pytest.approx(ext_file.max() / 1000.0, rel=1e-4)
    assert len(fig.bones) >= len(clip.labels) // 2  # joined by the rigid tree


def test_document_figure_is_its_bake_and_its_timing_the_dope_sheet():
    name = "cmu_02_01_walk.bvh"
    if name not in BVH_FILES:
        pytest.skip("no dev mocap")
    doc = dev_document(name)
    fig = figure(doc, "doc")
    baked = st.bake(doc)
    assert fig.points.shape[0] == baked.n_frames
    np.testing.assert_allclose(fig.points, figure(baked, "baked").points, atol=1e-6)
    tm = timing(doc)
    assert tm["pose_t"] == pytest.approx(list(doc.pose_t), abs=1e-6)
    n_ext = n_edit = 0
    for tr in doc.tracks:
        n_edit += int(tr.knot_editing.sum())
        n_ext += int((~tr.knot_editing).sum())
    rows = [r for r in tm["rows"] if not r["name"].endswith("(contact)")]
    # every moving variable's knots (a dev walk: all of its variables but the still ones)
    assert 0 < sum(len(r["ext"]) for r in rows) <= n_ext and sum(len(r["edit"]) for r in rows) <= n_edit
    pose_set = {round(t, 6) for t in tm["pose_t"]}
    for r in rows:
        for tk, te in r["ext"]:
            assert round(tk, 6) in pose_set and abs(te - tk) < 0.5  # an extreme knot about its pose
    assert len(tm["contacts"]) == len({c.joint for c in doc.constraints})
    spans = sorted(s for c in tm["contacts"] for s in c["spans"])
    want = sorted([c.start, max(c.end, c.start + doc.frame_time)] for c in doc.constraints)
    np.testing.assert_allclose(spans, want, atol=1e-6)


def test_layers_show_their_poses():
    doc = st.extract(st.read(SAMPLE))
    layered = st.add_layer(doc, keep=4)
    tm = timing(layered)
    assert len(tm["layers"]) == 1 and tm["layers"][0] == pytest.approx(list(layered.layer_pose_t[0]), abs=1e-6)


# --------------------------------------------------------------------------- the page


def test_page_carries_packed_float32_and_asks_for_nothing():
    clip = st.read(SAMPLE)
    doc = st.extract(clip)
    html = st.view(doc, compare=clip)
    meta = _meta(html)
    assert [f["kind"] for f in meta["figures"]] == ["skeleton", "skeleton"]
    for i, f in enumerate(meta["figures"]):
        pts = _blob(html, i)
        assert pts.size == f["frames"] * f["points"] * 3
    np.testing.assert_array_equal(_blob(html, 1).reshape(-1, meta["figures"][1]["points"], 3), figure(clip, "x").points)
    # the page's own code and three.js are in it; nothing it would fetch
    assert not re.search(r"<(script|link|img|iframe)[^>]+(src|href)=", html, re.I)
    for own in ("page.html", "page.js", "page.css"):
        text = asset(own)
        assert not re.search(r"https?:|//[a-z]|fetch\(|XMLHttpRequest|import\(|url\(", text), own
    # motion as packed binary: far smaller than its numbers as JSON text would be
    assert len(html) < 1.4 * 4 * sum(f["frames"] * f["points"] * 3 for f in meta["figures"]) + 1_200_000


def test_long_blobs_are_cut_in_pieces(monkeypatch):
    from staggered_cli.io import page

    assert BLOB_PIECE % 4 == 0  # each piece decodes on its own
    monkeypatch.setattr(page, "BLOB_PIECE", 1 << 14)
    meta, blobs = page_data(st.read(SAMPLE))
    html = b"".join(page.page_pieces(meta, blobs)).decode()
    pieces = re.findall(r'data-figure="0">(.*?)</script>', html, re.S)
    assert len(pieces) == -(-len(base64.b64encode(blobs[0])) // (1 << 14)) >= 2
    assert all(len(p) == 1 << 14 for p in pieces[:-1])
    assert np.array_equal(_blob(html, 0), np.frombuffer(blobs[0], "<f4"), equal_nan=True)


# --------------------------------------------------------------------------- the command


def _run(args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


def test_view_writes_a_page(tmp_path):
    out = tmp_path / "march.html"
    r = _run(["view", SAMPLE, "--compare", SAMPLE, "-o", out])
    assert r.exit_code == 0, r.output
    html = out.read_text(encoding="utf-8")
    assert html.startswith("<!doctype html>") and len(_meta(html)["figures"]) == 2


@pytest.mark.parametrize(
    "case, expect",
    [
        ("missing", "cannot read"),
        ("malformed", "bad.bvh: has no MOTION section"),
        ("exists", "output exists"),
        ("bvh-name", "name it .html (the name says BVH)"),
        ("png-name", "name it .html"),
    ],
)
def test_bad_input_is_one_line_and_no_file(tmp_path, case, expect):
    src, out = SAMPLE, tmp_path / "v.html"
    if case == "missing":
        src = tmp_path / "nope.bvh"
    elif case == "malformed":
        src = tmp_path / "bad.bvh"
        src.write_text("HIERARCHY\nROOT Hips\n{\n")
    elif case == "exists":
        out.write_text("keep me")
    elif case == "bvh-name":
        out = tmp_path / "x.bvh"
    elif case == "png-name":
        out = tmp_path / "x.png"
    before = sorted(p.name for p in tmp_path.iterdir())
    result = subprocess.run(
        [sys.executable, "-m", "staggered_cli", "view", str(src), "-o", str(out)],
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and expect in lines[0] and "Traceback" not in result.stderr, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no partial output
    if case == "exists":
        assert out.read_text() == "keep me"


def test_api_refuses_what_is_not_a_motion():
    with pytest.raises(st.UsageError, match="compare"):
        st.view(st.read(SAMPLE), compare=[42])


# --------------------------------------------------------------------------- the vendored three.js


def test_bundle_matches_its_record_and_the_pins():
    record = json.loads((VENDOR / "three.version.json").read_text())
    data = (VENDOR / "three.min.js").read_bytes()
    assert hashlib.sha256(data).hexdigest() == record["sha256"]
    pins = json.loads((TOOLS / "package.json").read_text())["dependencies"]
    assert pins == {"three": record["three"], "esbuild": record["esbuild"]}
    lock = json.loads((TOOLS / "package-lock.json").read_text())["packages"]
    assert lock["node_modules/three"]["version"] == record["three"]
    assert lock["node_modules/esbuild"]["version"] == record["esbuild"]
    assert "Permission is hereby granted" in (VENDOR / "LICENSE.three.txt").read_text()  # MIT
    assert f'revision:"{record["three"].split(".")[1]}"' in data.decode()  # three's r187 is 0.187.0


@pytest.mark.browser
def test_bundle_rebuilds_byte_for_byte(tmp_path):
    """``make view-bundle`` (npm ci of the pinned versions, then esbuild with
    fixed options) gives the committed bytes."""
    node = shutil.which("node")
    if node is None or not (TOOLS / "node_modules" / "esbuild").is_dir():
        if chrome.REQUIRED:
            pytest.fail("node or tools/view/node_modules missing (make test-browser runs npm ci)")
        pytest.skip("node or tools/view/node_modules missing (make test-browser installs them)")
    subprocess.run([node, str(TOOLS / "build.mjs"), str(tmp_path)], check=True, capture_output=True, timeout=300)
    assert (tmp_path / "three.min.js").read_bytes() == (VENDOR / "three.min.js").read_bytes()
    assert json.loads((tmp_path / "three.version.json").read_text()) == json.loads(
        (VENDOR / "three.version.json").read_text()
    )


def test_partial_poses_are_marked_and_own_only_their_parts_rows():
    doc = st.cull(dev_document("cmu_02_01_walk.bvh"), add_time=0.5, part="@left-arm")
    tm = timing(doc)
    k = doc.pose_part.index("@left-arm")
    assert tm["pose_part"][k] == "@left-arm" and sum(p is not None for p in tm["pose_part"]) == 1
    targets = np.concatenate([tr.targets for tr in doc.tracks])
    arm = {doc.source.skeleton.names[j] for j in targets[doc.part_mask("@left-arm")]}
    t_k = round(float(doc.pose_t[k]), 6)
    rows_with_k = {r["name"] for r in tm["rows"] for tk, _ in r["ext"] if round(tk, 6) == t_k}
    assert len(rows_with_k) >= 4 and rows_with_k <= arm, (rows_with_k, arm)
