"""Pictures (staggered_cli.pictures) and the plot / preview commands, on real motion capture
from ../shared/mocap: every kind renders for every file, pictures of
different documents differ, GIFs animate, and errors are one line."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from staggered_cli import pictures
from staggered_cli.cli.main import cli
from staggered_cli.cli.options import load_input
from staggered_cli.cli.preview import join_at
from staggered_cli.errors import UsageError
from staggered_cli.io.bvh import parse_bvh
from staggered_cli.io.container import document_bytes
from staggered_cli.io.schema import to_parts
from staggered_cli.model import document as D
from staggered_cli.model import variables as V
from staggered_cli.pictures import common, gif_durations, sticks

from .conftest import BVH_FILES, C3D_FILES, SAMPLES, dev_document, mocap, one_line_error

ALL_FILES = BVH_FILES + C3D_FILES
TEST_DPI = 60  # small pictures keep the tests quick
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MIN_PLOT_BYTES = 20_000  # a 720 x 420 picture with real content; a blank one is ~5 kB
MIN_PREVIEW_BYTES = 10_000


def _extract():
    try:
        from staggered_cli.ops.extract import extract
    except ImportError:  # extraction not there yet: poses every 0.25 s, no signals
        return None
    return extract


def make_document(name: str) -> D.Document:
    """The document of a mocap file: extracted, or poses every 0.25 s."""
    extract = _extract()
    if extract is not None:
        return dev_document(name)  # extracted once per session (conftest)
    motion = load_input(str(mocap(name)))
    return V.from_motion(motion, np.arange(0.0, (motion.n_frames - 1) * motion.frame_time, 0.25), source_name=name)


@pytest.fixture(scope="module")
def documents():
    """Documents by file name, each extracted once for the module."""
    cache: dict[str, D.Document] = {}

    def get(name: str) -> D.Document:
        if name not in cache:
            cache[name] = make_document(name)
        return cache[name]

    return get


def pixels(png: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB"), dtype=np.int16)


def check_png(data: bytes, minimum: int, size: tuple[int, int] | None = None) -> None:
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > minimum, len(data)
    with Image.open(io.BytesIO(data)) as im:
        im.verify()
    if size is not None:
        assert pixels(data).shape[:2] == (size[1], size[0])


def differing(a: bytes, b: bytes) -> float:
    """Fraction of pixels that differ between two pictures (over the part
    they share when their sizes differ: a preview's height follows the figure)."""
    pa, pb = pixels(a), pixels(b)
    h, w = min(pa.shape[0], pb.shape[0]), min(pa.shape[1], pb.shape[1])
    return float(np.mean(np.any(np.abs(pa[:h, :w] - pb[:h, :w]) > 8, axis=-1)))


def write_doc(doc: D.Document, path) -> None:
    manifest, arrays = to_parts(doc)
    path.write_bytes(document_bytes(manifest, arrays, "npz"))


def run(args):
    return CliRunner().invoke(cli, [str(a) for a in args])


# ------------------------------------------------------------- every file, every kind


@pytest.mark.parametrize("kind", pictures.KINDS)
@pytest.mark.parametrize("name", ALL_FILES)
def test_every_kind_renders(documents, name, kind):
    doc = documents(name)
    data = pictures.png_bytes(pictures.plot_figure(doc, kind, name=name), TEST_DPI)
    check_png(data, MIN_PLOT_BYTES, (int(pictures.FIGSIZE[0] * TEST_DPI), int(pictures.FIGSIZE[1] * TEST_DPI)))


@pytest.mark.parametrize("name", ALL_FILES)
def test_preview_renders(documents, name):
    doc = documents(name)
    data = pictures.png_bytes(pictures.preview_figure(doc, name=name), TEST_DPI)
    check_png(data, MIN_PREVIEW_BYTES)


@pytest.mark.parametrize("kind", pictures.KINDS + ("preview",))
def test_pictures_of_different_documents_differ(documents, kind):
    a, b = documents("cmu_02_01_walk.bvh"), documents("bandai2_run_normal_001.bvh")

    def draw(doc):
        if kind == "preview":
            return pictures.png_bytes(pictures.preview_figure(doc, at="frames", count=8), TEST_DPI)
        fig = pictures.plot_figure(doc, kind)
        return pictures.png_bytes(fig, TEST_DPI)

    assert differing(draw(a), draw(b)) > 0.02


def test_an_edit_shows_in_timing_and_curves(documents):
    from staggered_cli.ops.timing import succession

    doc = documents("cmu_02_01_walk.bvh")
    loose = succession(doc, 0.03, 1.0, joint="LeftArm", clamp=True)
    for kind in ("timing", "curves"):
        opts = {"joints": ["LeftArm", "LeftForeArm", "LeftHand"]}
        a = pictures.png_bytes(pictures.plot_figure(doc, kind, **opts), TEST_DPI)
        b = pictures.png_bytes(pictures.plot_figure(loose, kind, **opts), TEST_DPI)
        assert differing(a, b) > 0.002, kind


def test_signals_without_stored_signals_say_so():
    motion = load_input(str(mocap("bandai2_run_normal_001.bvh")))
    doc = V.from_motion(motion, np.arange(0.0, 2.0, 0.25))
    fig = pictures.signals_figure(doc)
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert any("no signals" in t for t in texts), texts
    check_png(pictures.png_bytes(fig, TEST_DPI), 10_000)


# ------------------------------------------------------------- rows, windows, views


def test_rows_follow_the_hierarchy_and_skip_what_never_moves(documents):
    doc = documents("bandai1_walk_normal_001.bvh")
    rows = common._rows(doc, None)
    names = [v.name for v in rows]
    # Bandai has position channels on every joint, constant but the hips'; its root is a static placeholder
    assert names[:3] == ["Hips.position", "Hips", "Spine"]
    assert "joint_Root" not in names and "Spine.position" not in names
    assert len(names) == 22
    targets = [v.target for v in rows]
    assert targets == sorted(targets)


def test_c3d_rows_run_from_head_to_feet(documents):
    doc = documents("c3dorg_sample01_Eb015pi_walk.c3d")
    rows = common._rows(doc, None)
    pts = doc.source.points
    height = np.array([np.nanmedian(pts[:, v.target, 2]) for v in rows])  # Z up
    assert np.all(np.diff(height) <= 1e-9)


def test_joint_names_select_rows(documents):
    doc = documents("cmu_02_01_walk.bvh")
    rows = common._rows(doc, ["LeftArm", "Hips"])
    assert [v.name for v in rows] == ["Hips.position", "Hips", "LeftArm"]
    assert [v.name for v in common._rows(doc, ["Hips"], rotation_only=True)] == ["Hips"]
    with pytest.raises(UsageError, match="unknown joint 'Nope'"):
        common._rows(doc, ["LeftArm", "Nope"])


def test_time_window_must_meet_the_clip(documents):
    doc = documents("bandai2_run_normal_001.bvh")
    assert common._window(doc, (-1.0, 1.0)) == (0.0, 1.0)
    assert common._window(doc, (1.0, np.inf)) == (1.0, doc.duration)
    for bad in [(5.0, 6.0), (-2.0, -1.0), (1.0, 1.0)]:
        with pytest.raises(UsageError, match="outside the clip"):
            common._window(doc, bad)


def test_long_documents_show_their_first_poses_in_the_dope_sheet(documents):
    doc = documents("cmu_85_12_breakdance_long.c3d")
    if doc.n_poses <= pictures.MAX_TIMING_POSES:
        pytest.skip("not enough poses")
    fig = pictures.timing_figure(doc)
    lo, hi = fig.axes[0].get_xlim()
    assert hi < doc.duration / 2
    assert "--time" in fig.get_suptitle()


@pytest.mark.parametrize(
    "name, up",
    [
        ("cmu_02_01_walk.bvh", (0, 1, 0)),
        ("bandai1_dance-short_normal_001.bvh", (0, 1, 0)),
        ("games105_idle.bvh", (0, 1, 0)),
        ("c3dorg_sample01_Eb015pi_walk.c3d", (0, 0, 1)),
        ("cmu_85_12_breakdance_long.c3d", (0, 0, 1)),
        ("ezc3d_BTS_walk_gaps.c3d", (0, 1, 0)),
    ],
)
def test_preview_finds_the_up_axis(name, up):
    motion = load_input(str(mocap(name)))
    pts = sticks._figure_points(motion)[0]
    view = pictures.view_axes(pts)
    np.testing.assert_allclose(view.up, up, atol=1e-12)
    basis = np.stack([view.up, view.forward, view.lateral])
    np.testing.assert_allclose(basis @ basis.T, np.eye(3), atol=1e-9)
    assert view.top - view.floor > 0.5 * view.size


def test_walks_are_seen_from_the_side(documents):
    """The side view looks across the direction of travel."""
    motion = load_input(str(mocap("cmu_02_01_walk.bvh")))
    pts = sticks._figure_points(motion)[0]
    view = pictures.view_axes(pts)
    root = pts[:, 0]
    travel = root[-1] - root[0]
    travel -= (travel @ view.up) * view.up
    assert abs(travel @ view.forward) > 0.99 * np.linalg.norm(travel)


# ------------------------------------------------------------- preview


def test_preview_strip_has_at_most_twelve_panels(documents):
    doc = documents("cmu_01_01_forward_jumps.bvh")
    assert doc.n_poses > pictures.MAX_PANELS
    fig = pictures.preview_figure(doc)
    assert len(fig.axes) == 2 * pictures.MAX_PANELS
    fig = pictures.preview_figure(doc, at="frames", count=5)
    assert len(fig.axes) == 10


def test_preview_compares_two_clips():
    motion = load_input(str(mocap("cmu_02_01_walk.bvh")))
    doc = make_document("cmu_02_01_walk.bvh")
    fig = pictures.preview_figure(doc, compare=motion, name="walk.stag", compare_name="walk.bvh")
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert labels == ["walk.stag", "walk.bvh"]
    alone = pictures.png_bytes(pictures.preview_figure(doc, name="walk.stag", compare_name="walk.bvh"), TEST_DPI)
    both = pictures.png_bytes(fig, TEST_DPI)
    assert alone != both


def gif_frames(data: bytes) -> tuple[int, list[int]]:
    assert data[:6] in (b"GIF87a", b"GIF89a")
    with Image.open(io.BytesIO(data)) as im:
        durations = []
        for n in range(im.n_frames):
            im.seek(n)
            durations.append(im.info.get("duration", 0))
        return im.n_frames, durations


def test_gif_animates_the_clip():
    motion = load_input(str(mocap("bandai2_run_normal_001.bvh")))  # 68 frames at 30 Hz
    n, durations = gif_frames(pictures.preview_gif(motion, dpi=40))
    assert n == 34  # every other frame: 15 per second, real time
    assert all(60 <= d <= 70 for d in durations)
    n, _ = gif_frames(pictures.preview_gif(motion, count=6, dpi=40))
    assert n == 6


def test_gif_of_poses_holds_each_pose(documents):
    doc = documents("c3dorg_sample01_Eb015pi_walk.c3d")
    n, durations = gif_frames(pictures.preview_gif(doc, at="poses", dpi=40))
    assert n == doc.n_poses
    assert all(100 <= d <= 1000 for d in durations)


# ------------------------------------------------------------- demo pictures


def test_demo_pictures_are_small(tmp_path):
    motion = load_input(str(SAMPLES / "march.bvh"))
    extract = _extract()
    doc = extract(motion, source_name="march.bvh") if extract else V.from_motion(motion, np.arange(0, 3.9, 0.25))
    paths = pictures.demo_pictures(doc, tmp_path, name="march.bvh")
    assert [p.name for p in paths] == ["signals.png", "timing.png", "curves.png", "preview.png"]
    for p in paths:
        check_png(p.read_bytes(), 10_000)
        with Image.open(p) as im:  # the default 100 dpi (was 72): a plot is 1200 x 700
            assert im.info["dpi"] == pytest.approx((100, 100), abs=0.01), p.name
            assert im.size[1] >= 700, (p.name, im.size)
        assert p.stat().st_size < 250_000, (p.name, p.stat().st_size)  # curves 183 kB, the others < 110 kB


# ------------------------------------------------------------- the commands


@pytest.fixture(scope="module")
def doc_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("plots") / "walk.stag"
    write_doc(make_document("cmu_02_01_walk.bvh"), path)
    return path


def test_plot_command_writes_a_png(doc_file, tmp_path):
    out = tmp_path / "timing.png"
    args = ["--kind", "timing", "--joints", "LeftArm,LeftForeArm", "--time", "0.5:2", "--dpi", TEST_DPI]
    result = run(["plot", doc_file, *args, "-o", out])
    assert result.exit_code == 0, result.stderr
    check_png(out.read_bytes(), 10_000, (720, 420))
    one_line_error(run(["plot", doc_file, "-o", out]), 2, "exists", "--force")
    assert run(["plot", doc_file, "--dpi", TEST_DPI, "-o", out, "--force"]).exit_code == 0


def test_plot_to_stdout(doc_file):
    result = run(["plot", doc_file, "--kind", "curves", "--dpi", TEST_DPI, "-o", "-"])
    assert result.exit_code == 0, result.stderr
    check_png(result.stdout_bytes, MIN_PLOT_BYTES)


NINE_JOINTS = "LeftArm,LeftForeArm,LeftHand,RightArm,RightForeArm,RightHand,LeftUpLeg,LeftLeg,RightLeg"


@pytest.mark.parametrize(
    "args, needles",
    [
        (["--joints", "LeftArm,NoSuchJoint"], ["walk.stag", "unknown joint 'NoSuchJoint'"]),
        (["--time", "10:20"], ["walk.stag", "outside the clip"]),
        (["--time", "2:1"], ["--time"]),
        (["--time", "abc"], ["--time"]),
        (["--kind", "pie"], ["--kind"]),
        (["--kind", "curves", "--joints", NINE_JOINTS], ["at most 8"]),
    ],
)
def test_plot_usage_errors(doc_file, tmp_path, args, needles):
    out = tmp_path / "x.png"
    one_line_error(run(["plot", doc_file, *args, "-o", out]), 2, *needles)
    assert not out.exists()


def test_plot_needs_a_document(tmp_path):
    one_line_error(run(["plot", mocap("cmu_02_01_walk.bvh"), "-o", tmp_path / "x.png"]), 2, "staggered extract")


def test_preview_command_png_and_gif(doc_file, tmp_path):
    bvh = mocap("cmu_02_01_walk.bvh")
    png = tmp_path / "p.png"
    result = run(["preview", bvh, "--at", "frames", "5", "--dpi", TEST_DPI, "-o", png])
    assert result.exit_code == 0, result.stderr
    check_png(png.read_bytes(), 5_000)
    gif = tmp_path / "p.gif"
    result = run(["preview", doc_file, "--compare", bvh, "--at", "frames:4", "--dpi", 40, "-o", gif])
    assert result.exit_code == 0, result.stderr
    assert gif_frames(gif.read_bytes())[0] == 4
    one_line_error(run(["preview", bvh, "-o", gif]), 2, "exists")
    result = run(["preview", bvh, "--format", "gif", "--at", "frames", "3", "--dpi", 40, "-o", "-"])
    assert result.exit_code == 0, result.stderr
    assert gif_frames(result.stdout_bytes)[0] == 3


@pytest.mark.parametrize("at", ["bob", "frames:0", "poses:3", "frames:x"])
def test_preview_at_errors(tmp_path, at):
    one_line_error(run(["preview", mocap("cmu_02_01_walk.bvh"), "--at", at, "-o", tmp_path / "x.png"]), 2, "--at")


def test_preview_of_c3d_markers(tmp_path):
    out = tmp_path / "c.png"
    result = run(["preview", mocap("ezc3d_BTS_walk_gaps.c3d"), "--dpi", TEST_DPI, "-o", out])
    assert result.exit_code == 0, result.stderr
    check_png(out.read_bytes(), 5_000)


def test_join_at():
    assert join_at(["x", "--at", "frames", "6", "-o", "y"]) == ["x", "--at", "frames:6", "-o", "y"]
    assert join_at(["--at=frames", "6"]) == ["--at", "frames:6"]
    assert join_at(["--at", "poses", "6"]) == ["--at", "poses", "6"]
    assert join_at(["--", "--at", "frames", "6"]) == ["--", "--at", "frames", "6"]


def test_commands_import_no_matplotlib_or_numpy():
    code = (
        "import sys; import staggered_cli.cli.plot, staggered_cli.cli.preview; "
        "print(sorted(m for m in ('numpy', 'matplotlib') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def _gif_frames(data: bytes) -> list[int]:
    im = Image.open(io.BytesIO(data))
    out = []
    for i in range(im.n_frames):
        im.seek(i)
        out.append(int(im.info["duration"]))
    return out


def test_gif_durations_spread_the_centisecond_rounding():
    # the case: 133 frames of 8/120 s each (8.87 s) played in 7.98 s
    d = gif_durations(np.full(133, 8 / 120))
    assert all(x % 10 == 0 for x in d) and set(d) == {60, 70}
    assert sum(d) / 1000 == pytest.approx(133 * 8 / 120, rel=1e-3)


def test_gif_preview_lasts_as_long_as_the_clip():
    path = mocap("bandai2_run_normal_001.bvh")
    m = parse_bvh(path.read_bytes())
    r = run(["preview", str(path), "--dpi", "20", "-o", "-", "--format", "gif"])
    assert r.exit_code == 0, r.stderr
    durations = _gif_frames(r.stdout_bytes)
    clip = m.n_frames * m.frame_time  # 2.27 s, as `info` reports it
    assert len(durations) == 34  # every second frame of 68: about 15 a second
    assert abs(sum(durations) / 1000 - clip) <= 0.01 * clip, (sum(durations), clip)  # was 2.04 s (10 % fast)


def test_preview_compare_warns_about_another_skeleton():
    run_, walk, idle = (
        str(mocap(n)) for n in ("bandai2_run_normal_001.bvh", "bandai1_walk_normal_001.bvh", "games105_idle.bvh")
    )
    r = run(["preview", run_, "--compare", walk, "--dpi", "20", "-o", "-"])
    assert r.exit_code == 0 and r.stderr == "", r.stderr  # the same skeleton: no word
    r = run(["preview", run_, "--compare", idle, "--dpi", "20", "-o", "-"])
    assert r.exit_code == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("staggered: WARNING: --compare games105_idle.bvh"), r.stderr
    assert "20 joints against 22, no joint joint_Root" in lines[0]
    assert r.stdout_bytes.startswith(b"\x89PNG")


def _panel_spreads(fig, stick, pairs):
    """For each panel column of a preview figure: the left-to-right spread
    of ``pairs`` (index pairs into the drawn points) along the side and the
    front panel's horizontal axis, as drawn (the dots' x data)."""
    axes = np.array(fig.axes).reshape(2, -1)
    out = []
    for col in range(axes.shape[1]):
        row = []
        for r in (0, 1):
            x = np.asarray(axes[r, col].lines[0].get_xdata(), dtype=float)
            row.append(np.nanmean([abs(x[a] - x[b]) for a, b in pairs]))
        out.append(row)
    return np.array(out)  # (panels, 2): side, front


@pytest.mark.parametrize(
    "name, pairs, most_side",
    [
        # turns around three times: hips and shoulders
        ("cmu_01_01_forward_jumps.bvh", [("LeftUpLeg", "RightUpLeg"), ("LeftArm", "RightArm")], 0.25),
        # walks a curve
        ("cmu3dsmax_131_02_start_walk_stop.bvh", [("LeftHip", "RightHip"), ("LeftShoulder", "RightShoulder")], 0.25),
        # spins on the floor: the pelvis markers, at the panels where it stands
        ("cmu_85_12_breakdance_long.c3d", [("Male:LFWT", "Male:RFWT"), ("Male:LBWT", "Male:RBWT")], 0.25),
    ],
)
def test_preview_cameras_turn_with_the_heading(name, pairs, most_side):
    """Each panel looks across the figure's heading (side) and along it
    (front): the figure's left-to-right spread (hips, shoulders, pelvis
    markers) drawn in a side panel is small against the front panel's, at
    every panel where the figure stands, before, during and after the
    turns.  Measured on the drawn dots: with one camera for the clip (as
    before) cmu_01_01's side panels showed the hips and shoulders 2.36
    times as wide as the front ones mid-turn (rows swapped) and 0.40 at the
    end, the 131_02 walk's 0.11-0.38, the breakdance's 0.59-13.8 at 9 of 12
    panels; turned with the heading, at most 0.11, 0.13 and 0.16."""
    motion = load_input(str(mocap(name)))
    fig = pictures.preview_figure(motion, at="frames", count=12)
    stick = sticks._stick(motion, "clip")
    idx = [(stick.names.index(a), stick.names.index(b)) for a, b in pairs]
    spread = _panel_spreads(fig, stick, idx)
    frames = stick.at(np.linspace(0, len(stick.points) - 1, 12) * stick.frame_time)
    assert len(frames) == len(spread)
    view = pictures.view_axes(stick.points)
    d = np.stack([stick.points[frames, a] - stick.points[frames, b] for a, b in idx], axis=1)  # (12, P, 3)
    level = np.linalg.norm(d - (d @ view.up)[..., None] * view.up, axis=2) / np.linalg.norm(d, axis=2)
    upright = level.mean(axis=1) > 0.8  # the pairs lie level: not lying on the floor or upside down
    assert upright.sum() >= 6
    ratio = spread[upright, 0] / spread[upright, 1]
    assert np.median(ratio) < 0.1, ratio
    assert ratio.max() < most_side, ratio
    # the figure really turns: its hips face directions at least 150 degrees apart
    a, b = idx[0]
    lr = stick.points[frames, a] - stick.points[frames, b]
    ang = np.degrees(np.arctan2(lr @ view.lateral, lr @ view.forward))
    spread_deg = np.ptp(np.unwrap(np.radians(ang)) * 180 / np.pi)
    assert spread_deg > (150 if "131_02" not in name else 20), spread_deg


def test_c3d_preview_joins_markers_and_keeps_them_in_their_panels():
    """A marker set is drawn with lines along its rigid tree (no line longer
    than the body's segments), and on the breakdance's flips every marker
    stays inside its panel: centred on the median marker (as before), 2 of
    the 24 panels cut markers off, by up to 0.1 figure heights."""
    from matplotlib.collections import LineCollection

    motion = load_input(str(mocap("cmu_85_12_breakdance_long.c3d")))
    fig = pictures.preview_figure(motion, at="frames", count=12)
    size = pictures.view_axes(motion.points).size
    bones, _ = pictures.marker_bones(motion.labels, motion.points)
    assert len(bones) >= len(motion.labels) - 3  # nearly every marker joined (40 edges join 41)
    cut_before = 0
    for ax in fig.axes:
        lines = [c for c in ax.collections if isinstance(c, LineCollection)]
        assert len(lines) == 1 and len(lines[0].get_segments()) == len(bones)
        seg = np.array(lines[0].get_segments())  # (B, 2, 2) as drawn: side or front
        assert np.nanmax(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)) <= 0.55 * size  # a limb, not a leap
        x = np.asarray(ax.lines[0].get_xdata(), dtype=float)
        lo, hi = ax.get_xlim()
        assert x.min() - lo >= 0.05 * size and hi - x.max() >= 0.05 * size, (x.min() - lo, hi - x.max())
        cut_before += np.max(np.abs(x - np.median(x))) > 0.6 * size
    assert cut_before >= 1  # the flips this checks are there


def _drawn_panels(fig, labels):
    """What each panel of a drawn preview shows, read back from its artists:
    the dots (x, y), the limits, and the lines as pairs of dot indices with
    their lengths (a line's ends are dots' coordinates, exactly)."""
    from matplotlib.collections import LineCollection

    fig.canvas.draw()  # the limits and the layout as written
    out = []
    for ax in fig.axes:
        dots = [ln for ln in ax.lines if ln.get_marker() == "o"]
        assert len(dots) == 1
        x, y = (np.asarray(v, dtype=float) for v in dots[0].get_data())
        at = {(a, b): i for i, (a, b) in enumerate(zip(x.tolist(), y.tolist(), strict=True)) if np.isfinite(a + b)}
        pairs, lengths = [], []
        for coll in ax.collections:
            if isinstance(coll, LineCollection):
                for seg in coll.get_segments():
                    seg = np.asarray(seg, dtype=float)
                    if len(seg) == 2 and np.isfinite(seg).all():
                        pairs.append((at[tuple(seg[0])], at[tuple(seg[1])]))
                        lengths.append(float(np.linalg.norm(seg[1] - seg[0])))
        out.append({"x": x, "y": y, "xlim": ax.get_xlim(), "ylim": ax.get_ylim(), "pairs": pairs, "lengths": lengths})
    return out


def _pieces(n: int, seen: np.ndarray, pairs) -> int:
    """Separate parts of a panel's drawing: its seen dots joined by its lines."""
    group = list(range(n))

    def root(i):
        while group[i] != i:
            i = group[i]
        return i

    for a, b in pairs:
        group[root(a)] = root(b)
    return len({root(i) for i in np.flatnonzero(seen)})


@pytest.mark.parametrize("what", ["clip", "document"])
@pytest.mark.parametrize("name", C3D_FILES)
def test_c3d_preview_draws_one_figure_inside_each_panel(documents, name, what):
    """On every dev C3D, a clip at 12 frames and its document at its poses:
    every marker drawn lies inside its panel's limits (flips, the BTS walk's
    gaps); each panel is one figure, its markers joined by lines (at most 2
    parts where a gap cuts a limb off); no line is longer than 0.6 figure
    heights or joins a marker on the left to one on the right other than a
    mirrored pair (hips, shoulders); a clip shows no empty panel.
    Before (the rigid tree, its long lines dropped, frames over the whole
    clip): the c3d.org walk 2.4 parts a panel (up to 5), the BTS walk 4.5
    (up to 10) and 8 of 24 panels empty, the breakdance 72 lines across the
    body; now at most 1.2, 1.0 and 0."""
    clip = load_input(str(mocap(name)))
    subject = documents(name) if what == "document" else clip
    at = {} if what == "document" else {"at": "frames", "count": 12}
    fig = pictures.preview_figure(subject, **at)
    size = clip.figure_height()
    sides = sticks._sides(clip.labels)
    mirrored = {frozenset(p) for p in sticks.side_pairs(clip.labels)}
    panels = _drawn_panels(fig, clip.labels)
    parts, lines, empty = [], 0, 0
    for p in panels:
        (x0, x1), (y0, y1) = p["xlim"], p["ylim"]
        assert np.isfinite([x0, x1, y0, y1]).all() and x1 > x0 and y1 > y0
        seen = np.isfinite(p["x"]) & np.isfinite(p["y"])
        x, y = p["x"][seen], p["y"][seen]
        assert np.all((x >= x0) & (x <= x1)), (name, x.min() - x0, x1 - x.max())
        assert np.all((y >= y0) & (y <= y1)), (name, y.min() - y0, y1 - y.max())
        if not seen.any():
            empty += 1
            continue
        lines += len(p["pairs"])
        assert max(p["lengths"], default=0.0) <= 0.6 * size, (name, max(p["lengths"]) / size)
        across = [
            (clip.labels[a], clip.labels[b])
            for a, b in p["pairs"]
            if {sides[a], sides[b]} == {"left", "right"} and frozenset((a, b)) not in mirrored
        ]
        assert not across, (name, across)
        parts.append(_pieces(len(p["x"]), seen, p["pairs"]))
    assert lines > 0
    assert max(parts) <= 2 and np.mean(parts) <= 1.3, (name, parts)
    if what == "clip":
        assert empty == 0, name


def test_c3d_document_preview_draws_its_marker_tree(documents):
    """A document's marker tree (from ``succession --chain`` or randomize,
    :func:`~staggered_cli.ops.marker_chain.document_tree`) is what its
    preview joins: the chain shoulder, elbow, forearm, wrist, finger, whose
    forearm-to-wrist-A link the rigid tree of the clip does not have."""
    from dataclasses import replace

    name = "cmu_85_12_breakdance_long.c3d"
    doc = documents(name)
    chain = ["Male:RSHO", "Male:RUPA", "Male:RELB", "Male:RFRM", "Male:RWRA", "Male:RFIN"]
    tree = {b: a for a, b in zip(chain[:-1], chain[1:], strict=True)}
    labels = list(doc.target_names)
    link = frozenset((labels.index("Male:RFRM"), labels.index("Male:RWRA")))
    plain = sticks._stick(doc, "doc")
    assert link not in {frozenset(map(int, b)) for b in plain.bones}
    chained = replace(doc, parameters={**doc.parameters, "marker_tree": tree})
    edited = sticks._stick(chained, "doc")
    bones = {frozenset(map(int, b)) for b in edited.bones}
    assert {frozenset((labels.index(a), labels.index(b))) for b, a in tree.items()} <= bones
    assert len(edited.bones) == len(labels) - 1  # the rest joined as before: one figure
    panels = _drawn_panels(pictures.preview_figure(chained), labels)
    a, b = sorted(link)
    assert all((a, b) in p["pairs"] or (b, a) in p["pairs"] for p in panels)


@pytest.mark.parametrize("name", ["cmu_02_01_walk.bvh", "ezc3d_BTS_walk_gaps.c3d", "cmu_85_12_breakdance_long.c3d"])
def test_preview_panels_are_readable(tmp_path, name):
    """``staggered preview`` without --dpi: 100 dpi, every panel at least
    3.5 inches (350 pixels) tall, rows at most 18 inches wide, in a palette
    PNG.  Before: panels 0.86 to 1.8 inches tall, 12 across 12 inches."""
    motion = load_input(str(mocap(name)))
    for count in (8, 12):
        fig = pictures.preview_figure(motion, at="frames", count=count)
        fig.canvas.draw()
        w, h = fig.get_size_inches()
        assert w <= 18.5
        assert min(ax.get_position().height for ax in fig.axes) * h >= 3.5
    out = tmp_path / "p.png"
    result = run(["preview", mocap(name), "--at", "frames", "12", "-o", out])
    assert result.exit_code == 0, result.stderr
    with Image.open(out) as im:
        assert im.mode == "P" and im.info["dpi"] == pytest.approx((100, 100), abs=0.01)
        assert im.size[1] >= 2 * 350 and im.size[0] <= 1850, im.size
    assert 40_000 < out.stat().st_size < 250_000, out.stat().st_size
